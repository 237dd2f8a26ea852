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
/// A particle frame is one element "vertex" with a column per channel:
///
///   PlyData frame;
///   PlyElement& v = frame.elements.emplace_back();
///   v.name = "vertex";
///   v.count = n;
///   v.properties.push_back({"x", xs});          // std::vector<float> or std::vector<double>
///   v.properties.push_back({"material", mat});  // std::vector<std::uint16_t>
///   write_ply(dir / "f0001.ply", frame);
///   std::vector<double> x = read_ply(dir / "f0001.ply").element("vertex").column_as_double("x");
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <type_traits>
#include <variant>
#include <vector>

namespace slurry::io {

/// Body encoding used by write_ply. (read_ply also accepts binary_big_endian.)
enum class PlyFormat { BinaryLittleEndian, Ascii };

/// One column of a scalar property, stored in its file type; written without conversion. The
/// alternatives map to char, uchar, short, ushort, int, uint, float, double in that order.
using PlyScalarData =
    std::variant<std::vector<std::int8_t>, std::vector<std::uint8_t>, std::vector<std::int16_t>,
                 std::vector<std::uint16_t>, std::vector<std::int32_t>, std::vector<std::uint32_t>,
                 std::vector<float>, std::vector<double>>;

/// A scalar property: one value per row of its element.
struct PlyProperty {
  std::string name;
  PlyScalarData data;
};

/// A scalar column that write_ply reads where it lies, without a copy: row r's value is the
/// scalar of type `type` at byte offset r * stride from `first`. A stride larger than the type
/// reads one component of an array of structs or vectors (the y of packed xyz positions: first =
/// &x[0][1], stride = sizeof(x[0])); a stride of 0 repeats one value on every row. The memory must
/// stay valid and unchanged until the write returns. Built with PlyColumnRef::of.
struct PlyColumnRef {
  std::string name;
  std::size_t type = 0;  ///< the index of the value's alternative in PlyScalarData
  const void* first = nullptr;
  std::size_t stride = 0;  ///< bytes from one row's value to the next

  template <class T>
  static PlyColumnRef of(std::string name, const T* first, std::size_t stride = sizeof(T)) {
    return {std::move(name), PlyScalarData(std::vector<T>()).index(), first, stride};
  }
};

/// A list property, e.g. a face's vertex_indices: one list of indices per row. Written as
/// `property list uchar int <name>` (so at most 255 items per row); read from any integer count
/// type and any integer item type whose values fit in int32.
struct PlyListProperty {
  std::string name;
  std::vector<std::vector<std::int32_t>> data;
};

/// One element (a table): `count` rows, each with every scalar property and every list property.
/// write_ply writes the scalar properties first, then the borrowed columns (`refs`), then the
/// lists; read_ply keeps the file's order within `properties` and `lists` and fills no `refs`.
struct PlyElement {
  std::string name;
  std::size_t count = 0;
  std::vector<PlyProperty> properties;
  std::vector<PlyListProperty> lists;
  /// The file this element was read from (empty if built in memory); named in error messages.
  std::filesystem::path source;
  /// Scalar columns written from memory the element does not own (see PlyColumnRef). The
  /// look-ups below (find, property, column...) see only `properties`; own() copies these into
  /// it.
  std::vector<PlyColumnRef> refs;

  /// Copies every borrowed column into `properties` (after the ones there, in order) and clears
  /// `refs`: the element then holds its data and writes the same file.
  void own();

  /// The scalar property called `name`, or nullptr.
  const PlyProperty* find(std::string_view name) const;
  /// The list property called `name`, or nullptr.
  const PlyListProperty* find_list(std::string_view name) const;
  /// The scalar property called `name`; throws IoError (naming file, element and the properties
  /// it does have) if there is none.
  const PlyProperty& property(std::string_view name) const;
  /// The list property called `name`; throws IoError if there is none.
  const PlyListProperty& list(std::string_view name) const;

  /// The column `name` converted to double (exact for every PLY scalar type).
  std::vector<double> column_as_double(std::string_view name) const;
  /// The column `name` converted to float (rounds doubles and integers beyond 2^24).
  std::vector<float> column_as_float(std::string_view name) const;
  /// The column `name` in its stored type T, without conversion; throws IoError if it is missing
  /// or stored in another type.
  template <class T>
  const std::vector<T>& column(std::string_view name) const;

 private:
  [[noreturn]] void throw_wrong_type(const PlyProperty& p, std::string_view wanted) const;
  template <class T>
  static std::string_view type_name();
};

/// A whole PLY file: header comments and obj_info lines, and the elements in file order.
struct PlyData {
  std::vector<std::string> comments;
  std::vector<std::string> obj_info;
  std::vector<PlyElement> elements;
  /// The file this was read from (empty if built in memory); named in error messages.
  std::filesystem::path source;

  /// The element called `name`, or nullptr.
  const PlyElement* find(std::string_view name) const;
  PlyElement* find(std::string_view name);
  /// The element called `name`; throws IoError (naming the file and the elements it does have)
  /// if there is none.
  const PlyElement& element(std::string_view name) const;
  /// PlyElement::own() on every element.
  void own();
};

/// Writes `data` to `path` atomically: validates everything first (each column and list has
/// `count` entries, names are non-empty, free of whitespace and unique, lists have at most 255
/// items, comments have no line breaks, borrowed columns of a non-empty element point somewhere), then writes `<path>.tmp-<pid>-<n>` in the same
/// directory, closes it, checks the stream and renames it onto `path`. On any failure the
/// temporary file is removed, an existing file at `path` is left untouched and IoError is
/// thrown. The directory must exist; it is not created.
void write_ply(const std::filesystem::path& path, const PlyData& data,
               PlyFormat format = PlyFormat::BinaryLittleEndian);

/// Reads an ascii, binary_little_endian or binary_big_endian PLY file. Throws IoError for a
/// missing file, a malformed header, unknown types, a truncated body (naming the element and
/// the row where the data ran out), values that do not parse or fit their type, and data left
/// over after the last element.
PlyData read_ply(const std::filesystem::path& path);

// ---------------------------------------------------------------------------------------------

template <class T>
std::string_view PlyElement::type_name() {
  if constexpr (std::is_same_v<T, std::int8_t>)
    return "char";
  else if constexpr (std::is_same_v<T, std::uint8_t>)
    return "uchar";
  else if constexpr (std::is_same_v<T, std::int16_t>)
    return "short";
  else if constexpr (std::is_same_v<T, std::uint16_t>)
    return "ushort";
  else if constexpr (std::is_same_v<T, std::int32_t>)
    return "int";
  else if constexpr (std::is_same_v<T, std::uint32_t>)
    return "uint";
  else if constexpr (std::is_same_v<T, float>)
    return "float";
  else if constexpr (std::is_same_v<T, double>)
    return "double";
  else
    static_assert(sizeof(T) == 0, "PlyElement::column<T>: T is not a PLY scalar type");
}

template <class T>
const std::vector<T>& PlyElement::column(std::string_view name) const {
  const PlyProperty& p = property(name);
  if (const auto* v = std::get_if<std::vector<T>>(&p.data)) return *v;
  throw_wrong_type(p, type_name<T>());
}

}  // namespace slurry::io
