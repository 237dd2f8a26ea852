#pragma once
/// \file ply.h
/// Reading and writing particle and mesh files in the PLY format ("Polygon File Format", also
/// called the Stanford Triangle Format), following Greg Turk's description of the format,
/// "The PLY Polygon File Format" (1994), as published by the Stanford 3D Scanning Repository:
///
///   ply
///   format binary_little_endian 1.0        (or ascii 1.0, binary_big_endian 1.0)
///   comment <free text>                     (any number, anywhere in the header)
///   obj_info <free text>                    (any number, anywhere in the header)
///   element <name> <count>
///   property <type> <name>                  (a scalar column of the element above)
///   property list <count-type> <item-type> <name>
///   end_header
///   <body: element by element, row by row, each row's properties in header order>
///
/// Scalar types are char uchar short ushort int uint float double (1, 1, 2, 2, 4, 4, 4, 8 bytes),
/// also spelled int8 uint8 int16 uint16 int32 uint32 float32 float64. In an ascii body each row
/// is one line of whitespace-separated numbers; a binary body is the packed rows with no padding.
///
/// write_ply writes binary_little_endian (the default: fast, exact) or ascii (exact too: every
/// float and double is printed with the shortest text that reads back to the same bits). The
/// write is atomic: the file appears under its final name complete or not at all.
/// read_ply reads all three formats. Both throw slurry::IoError naming the file and saying what
/// was wrong and what was expected.
///
/// The file's content in memory is a Frame (slurry/engine/frame.h): an element is a Table, a
/// scalar property a Column, a list property a ListColumn. A particle frame is one element
/// "vertex" with a column per channel:
///
///   write_ply(dir / "f0001.ply", simulation.frame(attributes));
///   std::vector<double> x = read_ply(dir / "f0001.ply").table("vertex").column_as_double("x");
#include <filesystem>
#include <string>
#include <vector>

#include "slurry/engine/frame.h"

namespace slurry::io {

/// Body encoding used by write_ply. (read_ply also accepts binary_big_endian.)
enum class PlyFormat { BinaryLittleEndian, Ascii };

/// A PLY file: its frame (header comments, elements as tables) and the header's obj_info lines.
struct PlyData : Frame {
  std::vector<std::string> obj_info;
};

/// Writes `data` to `path` atomically: validates everything first (each column and list has
/// `count` entries, names are non-empty, free of whitespace and unique, lists have at most 255
/// items, comments and obj_info lines have no line breaks, borrowed columns of a non-empty
/// element point somewhere), then writes `<path>.tmp-<pid>-<n>` in the same directory, closes it,
/// checks the stream and renames it onto `path`. A list property is written as `property list
/// uchar int <name>`. On any failure the temporary file is removed, an existing file at `path` is
/// left untouched and IoError is thrown. The directory must exist; it is not created.
void write_ply(const std::filesystem::path& path, const Frame& data,
               PlyFormat format = PlyFormat::BinaryLittleEndian,
               const std::vector<std::string>& obj_info = {});
/// The same, with the file's obj_info lines.
void write_ply(const std::filesystem::path& path, const PlyData& data,
               PlyFormat format = PlyFormat::BinaryLittleEndian);

/// Reads an ascii, binary_little_endian or binary_big_endian PLY file. List properties are read
/// from any integer count type and any integer item type whose values fit in int32. Throws
/// IoError for a missing file, a malformed header, unknown types, a truncated body (naming the
/// element and the row where the data ran out), values that do not parse or fit their type, and
/// data left over after the last element.
PlyData read_ply(const std::filesystem::path& path);

/// Checks that the PLY file at `path` is whole without reading its body where the header
/// allows: a binary body of scalar properties must make the file exactly the header plus each
/// element's count x row size. An ascii body, or one with list properties, is read as read_ply
/// reads it. Throws IoError as read_ply does, or naming the size found and the size expected.
void check_ply(const std::filesystem::path& path);

}  // namespace slurry::io
