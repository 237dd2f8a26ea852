#pragma once
/// \file frame.h
/// A frame: the particles' state at one instant as tables of named, typed columns, free of any
/// file format. Every solver hands its frames out in this form (Solver::frame, frame_view) and
/// every writer takes them from memory: PLY files (slurry/io/ply.h), OpenVDB points and liquid
/// surfaces (slurry/io/surface.h, pipeline.h). A particle frame is one table "vertex" with a
/// column per channel (x, y, z, vx, vy, vz, material, J, plastic, id) and a comment naming the
/// time and the scene it came from.
///
/// A column is owned (`Table::columns`, a std::vector of one scalar type) or borrowed
/// (`Table::refs`, a strided view into memory the table does not own, such as the solver's
/// particle arrays). A table with borrowed columns is valid only while that memory is unchanged;
/// Table::own() copies them in.
///
///   Frame frame;
///   Table& v = frame.tables.emplace_back();
///   v.name = "vertex";
///   v.count = n;
///   v.columns.push_back({"x", xs});          // std::vector<float> or std::vector<double>
///   v.columns.push_back({"material", mat});  // std::vector<std::uint16_t>
///   std::vector<double> x = frame.table("vertex").column_as_double("x");
///
/// Look-ups that fail throw slurry::IoError naming the frame's source (the file it was read from)
/// and what it does hold.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <type_traits>
#include <variant>
#include <vector>

namespace slurry {

/// The values of one scalar column. The alternatives are the 8-, 16- and 32-bit signed and
/// unsigned integers, float and double, in that order; their names in messages are char, uchar,
/// short, ushort, int, uint, float and double.
using ColumnData =
    std::variant<std::vector<std::int8_t>, std::vector<std::uint8_t>, std::vector<std::int16_t>,
                 std::vector<std::uint16_t>, std::vector<std::int32_t>, std::vector<std::uint32_t>,
                 std::vector<float>, std::vector<double>>;

/// The name of a ColumnData alternative (its index): "char" ... "double".
std::string_view column_type_name(std::size_t type);
/// Bytes of one value of a ColumnData alternative.
std::size_t column_type_size(std::size_t type);

/// An owned scalar column: one value per row of its table.
struct Column {
  std::string name;
  ColumnData data;
};

/// A borrowed scalar column, read where it lies: row r's value is the scalar of type `type` at
/// byte offset r * stride from `first`. A stride larger than the type reads one component of an
/// array of structs or vectors (the y of packed xyz positions: first = &x[0][1], stride =
/// sizeof(x[0])); a stride of 0 repeats one value on every row. The memory must stay valid and
/// unchanged while the table is used. Built with ColumnRef::of.
struct ColumnRef {
  std::string name;
  std::size_t type = 0;  ///< the index of the value's alternative in ColumnData
  const void* first = nullptr;
  std::size_t stride = 0;  ///< bytes from one row's value to the next

  template <class T>
  static ColumnRef of(std::string name, const T* first, std::size_t stride = sizeof(T)) {
    return {std::move(name), ColumnData(std::vector<T>()).index(), first, stride};
  }
};

/// A column of index lists, e.g. a mesh face's vertex indices: one list per row.
struct ListColumn {
  std::string name;
  std::vector<std::vector<std::int32_t>> data;
};

/// One table: `count` rows, each with a value of every scalar column and a list of every list
/// column. Writers write the owned columns first, then the borrowed ones (`refs`), then the
/// lists; readers keep the file's order and fill no `refs`.
struct Table {
  std::string name;
  std::size_t count = 0;
  std::vector<Column> columns;
  std::vector<ListColumn> lists;
  /// The file this table was read from (empty if built in memory); named in error messages.
  std::filesystem::path source;
  /// Scalar columns the table does not own (see ColumnRef). The look-ups below that return a
  /// reference (find, column, values) see only `columns`; has() and column_as_double/float see
  /// both; own() copies these into `columns`.
  std::vector<ColumnRef> refs;

  /// Copies every borrowed column into `columns` (after the ones there, in order) and clears
  /// `refs`: the table then holds its data and writes the same file.
  void own();

  /// The scalar column called `name`, or nullptr.
  const Column* find(std::string_view name) const;
  /// The list column called `name`, or nullptr.
  const ListColumn* find_list(std::string_view name) const;
  /// The scalar column called `name`; throws IoError (naming the source, the table and the
  /// columns it does have) if there is none.
  const Column& column(std::string_view name) const;
  /// The list column called `name`; throws IoError if there is none.
  const ListColumn& list(std::string_view name) const;

  /// Whether a scalar column `name` is owned or borrowed.
  bool has(std::string_view name) const;
  /// The column `name`, owned or borrowed, converted to double (exact for every column type).
  std::vector<double> column_as_double(std::string_view name) const;
  /// The column `name`, owned or borrowed, converted to float (rounds doubles and integers
  /// beyond 2^24).
  std::vector<float> column_as_float(std::string_view name) const;
  /// The column `name` in its stored type T, without conversion; throws IoError if it is missing
  /// or stored in another type.
  template <class T>
  const std::vector<T>& values(std::string_view name) const;

 private:
  [[noreturn]] void throw_wrong_type(const Column& c, std::string_view wanted) const;
  const ColumnRef* find_ref(std::string_view name) const;
  template <class Out>
  std::vector<Out> column_as(std::string_view name) const;
};

/// A frame: free-text comments (the first names the time and source of a particle frame) and its
/// tables in order.
struct Frame {
  std::vector<std::string> comments;
  std::vector<Table> tables;
  /// The file this was read from (empty if built in memory); named in error messages.
  std::filesystem::path source;

  /// The table called `name`, or nullptr.
  const Table* find(std::string_view name) const;
  Table* find(std::string_view name);
  /// The table called `name`; throws IoError (naming the source and the tables it does have) if
  /// there is none.
  const Table& table(std::string_view name) const;
  /// Table::own() on every table.
  void own();
};

// ---------------------------------------------------------------------------------------------

template <class T>
const std::vector<T>& Table::values(std::string_view name) const {
  const Column& c = column(name);
  if (const auto* v = std::get_if<std::vector<T>>(&c.data)) return *v;
  throw_wrong_type(c, column_type_name(ColumnData(std::vector<T>()).index()));
}

}  // namespace slurry
