// PLY reader and writer. The format facts (header grammar, type names and sizes, body layout)
// follow Greg Turk, "The PLY Polygon File Format", as published by the Stanford 3D Scanning
// Repository; see ply.h for a summary.
// One file of about 1,060 lines: the reader and the writer share the type table, the byte-order
// copies and the header grammar of one specification.
#include "slurry/io/ply.h"

#include "atomic_file.h"
#include "input_file.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <charconv>
#include <cstring>
#include <fstream>
#include <limits>
#include <new>
#include <string>
#include <system_error>
#include <utility>

#include "slurry/engine/errors.h"
#include "slurry/engine/quote_text.h"

#if defined(_WIN32)
#include <process.h>
#else
#include <unistd.h>
#endif

namespace slurry::io {
namespace fs = std::filesystem;

namespace {

// C++17 has no std::endian; every compiler we build with predefines these macros.
#if defined(__BYTE_ORDER__) && defined(__ORDER_LITTLE_ENDIAN__) && defined(__ORDER_BIG_ENDIAN__)
constexpr bool kHostLittleEndian = __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__;
#elif defined(_WIN32)
constexpr bool kHostLittleEndian = true;
#else
#error "ply.cpp: cannot tell the host byte order on this compiler"
#endif

// Large enough that a binary body goes to the OS in few system calls, small enough to stay in
// L2/L3.
constexpr std::size_t kChunkBytes = std::size_t{1} << 20;

// ---- scalar types ---------------------------------------------------------------------------

// Same order as the alternatives of ColumnData, so that data.index() is the type.
enum class ScalarType : std::uint8_t {
  Int8,
  UInt8,
  Int16,
  UInt16,
  Int32,
  UInt32,
  Float32,
  Float64
};

template <std::size_t I>
using Alternative = typename std::variant_alternative_t<I, ColumnData>::value_type;
static_assert(std::is_same_v<Alternative<0>, std::int8_t> &&
                  std::is_same_v<Alternative<1>, std::uint8_t> &&
                  std::is_same_v<Alternative<2>, std::int16_t> &&
                  std::is_same_v<Alternative<3>, std::uint16_t> &&
                  std::is_same_v<Alternative<4>, std::int32_t> &&
                  std::is_same_v<Alternative<5>, std::uint32_t> &&
                  std::is_same_v<Alternative<6>, float> && std::is_same_v<Alternative<7>, double>,
              "ColumnData alternatives must follow the ScalarType order");
static_assert(sizeof(float) == 4 && sizeof(double) == 8 && std::numeric_limits<float>::is_iec559 &&
                  std::numeric_limits<double>::is_iec559,
              "PLY float and double are IEEE 754 binary32 and binary64");

struct TypeInfo {
  std::string_view name;   // canonical name from the PLY description; the one we write
  std::string_view alias;  // sized name used by later writers; accepted when reading
  std::size_t size;
  bool integer;
};
constexpr std::array<TypeInfo, 8> kTypes{{{"char", "int8", 1, true},
                                          {"uchar", "uint8", 1, true},
                                          {"short", "int16", 2, true},
                                          {"ushort", "uint16", 2, true},
                                          {"int", "int32", 4, true},
                                          {"uint", "uint32", 4, true},
                                          {"float", "float32", 4, false},
                                          {"double", "float64", 8, false}}};
constexpr const char* kExpectedTypes =
    "expected one of char, uchar, short, ushort, int, uint, float, double, or the aliases int8, "
    "uint8, int16, uint16, int32, uint32, float32, float64";

const TypeInfo& info(ScalarType t) {
  return kTypes[static_cast<std::size_t>(t)];
}
ScalarType type_of(const ColumnData& d) {
  return static_cast<ScalarType>(d.index());
}

bool parse_type_name(std::string_view s, ScalarType& out) {
  for (std::size_t i = 0; i < kTypes.size(); ++i) {
    if (s == kTypes[i].name || s == kTypes[i].alias) {
      out = static_cast<ScalarType>(i);
      return true;
    }
  }
  return false;
}

// Calls f(T{}) with T the C++ type of t.
template <class F>
decltype(auto) visit_type(ScalarType t, F&& f) {
  switch (t) {
    case ScalarType::Int8:
      return f(std::int8_t{});
    case ScalarType::UInt8:
      return f(std::uint8_t{});
    case ScalarType::Int16:
      return f(std::int16_t{});
    case ScalarType::UInt16:
      return f(std::uint16_t{});
    case ScalarType::Int32:
      return f(std::int32_t{});
    case ScalarType::UInt32:
      return f(std::uint32_t{});
    case ScalarType::Float32:
      return f(float{});
    case ScalarType::Float64:
      break;
  }
  return f(double{});
}

template <class V>
using ValueType = typename std::decay_t<V>::value_type;

ColumnData make_column(ScalarType t, std::size_t n) {
  return visit_type(t, [n](auto tag) { return ColumnData(std::vector<decltype(tag)>(n)); });
}

// ---- messages -------------------------------------------------------------------------------

std::string display_name(const fs::path& file) {
  return file.empty() ? std::string("<in-memory PLY data>") : file.string();
}

[[noreturn]] void fail(const fs::path& file, const std::string& what) {
  throw IoError(display_name(file) + ": " + what);
}


std::string expected_value(ScalarType t) {
  return visit_type(t, [t](auto tag) -> std::string {
    using T = decltype(tag);
    if constexpr (std::is_floating_point_v<T>) {
      return std::string("a ") + std::string(info(t).name) + " number";
    } else {
      return "an integer in " + std::to_string(+std::numeric_limits<T>::min()) + ".." +
             std::to_string(+std::numeric_limits<T>::max());
    }
  });
}

// Names in a PLY header are single whitespace-free tokens.
bool is_valid_name(std::string_view s) {
  if (s.empty()) return false;
  return std::none_of(s.begin(), s.end(), [](char ch) {
    const auto c = static_cast<unsigned char>(ch);
    return c <= 0x20 || c == 0x7f;
  });
}

bool has_line_break(std::string_view s) {
  return s.find_first_of("\r\n") != std::string_view::npos;
}

// ---- byte copies ----------------------------------------------------------------------------

template <class T, bool Swap>
T load(const unsigned char* src) {
  unsigned char b[sizeof(T)];
  std::memcpy(b, src, sizeof(T));
  if constexpr (Swap) std::reverse(b, b + sizeof(T));
  T v;
  std::memcpy(&v, b, sizeof(T));
  return v;
}

template <class T>
T load(const unsigned char* src, bool swap) {
  return swap ? load<T, true>(src) : load<T, false>(src);
}

// Copies n values of S bytes, src_stride bytes apart, into every stride-th slot of dst, as little
// endian.
template <std::size_t S>
void scatter_le(const unsigned char* src, std::size_t src_stride, std::size_t n, unsigned char* dst,
                std::size_t stride) {
  for (std::size_t i = 0; i < n; ++i) {
    unsigned char b[S];
    std::memcpy(b, src + i * src_stride, S);
    if constexpr (!kHostLittleEndian) std::reverse(b, b + S);
    std::memcpy(dst + i * stride, b, S);
  }
}

void scatter_le(std::size_t size, const unsigned char* src, std::size_t src_stride, std::size_t n,
                unsigned char* dst, std::size_t stride) {
  switch (size) {
    case 1:
      return scatter_le<1>(src, src_stride, n, dst, stride);
    case 2:
      return scatter_le<2>(src, src_stride, n, dst, stride);
    case 4:
      return scatter_le<4>(src, src_stride, n, dst, stride);
    default:
      return scatter_le<8>(src, src_stride, n, dst, stride);
  }
}

// The inverse of scatter_le, for either file byte order.
template <class T, bool Swap>
void gather(const unsigned char* src, std::size_t stride, std::size_t n, T* out) {
  for (std::size_t i = 0; i < n; ++i) out[i] = load<T, Swap>(src + i * stride);
}

template <class T>
void append_le(std::vector<unsigned char>& buf, T v) {
  unsigned char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  if constexpr (!kHostLittleEndian) std::reverse(b, b + sizeof(T));
  buf.insert(buf.end(), b, b + sizeof(T));
}

// A column as the writers read it: row r's value is the `type` at data + r * stride.
struct RawColumn {
  const unsigned char* data;
  std::size_t size;    // bytes per value
  std::size_t stride;  // bytes between rows
  ScalarType type;
};

RawColumn raw(const ColumnData& d) {
  return std::visit(
      [&d](const auto& v) {
        constexpr std::size_t size = sizeof(ValueType<decltype(v)>);
        return RawColumn{reinterpret_cast<const unsigned char*>(v.data()), size, size, type_of(d)};
      },
      d);
}

RawColumn raw(const ColumnRef& c) {
  const auto t = static_cast<ScalarType>(c.type);
  return RawColumn{static_cast<const unsigned char*>(c.first), info(t).size, c.stride, t};
}

// Every scalar column of an element in file order: the owned columns, then the borrowed ones.
std::vector<RawColumn> raw_columns(const Table& el) {
  std::vector<RawColumn> cols;
  cols.reserve(el.columns.size() + el.refs.size());
  for (const Column& p : el.columns) cols.push_back(raw(p.data));
  for (const ColumnRef& c : el.refs) cols.push_back(raw(c));
  return cols;
}

// ---- writing --------------------------------------------------------------------------------

void validate(const fs::path& path, const Frame& data, const std::vector<std::string>& obj_info) {
  for (std::size_t i = 0; i < data.comments.size(); ++i)
    if (has_line_break(data.comments[i]))
      fail(path, "comment " + std::to_string(i) + " " + quote_text(data.comments[i]) +
                     " contains a line break (expected one header line per comment)");
  for (std::size_t i = 0; i < obj_info.size(); ++i)
    if (has_line_break(obj_info[i]))
      fail(path, "obj_info " + std::to_string(i) + " " + quote_text(obj_info[i]) +
                     " contains a line break (expected one header line per obj_info)");

  for (std::size_t e = 0; e < data.tables.size(); ++e) {
    const Table& el = data.tables[e];
    if (!is_valid_name(el.name))
      fail(path, "element " + std::to_string(e) + " has the name " + quote_text(el.name) +
                     " (expected a non-empty name without whitespace)");
    for (std::size_t k = 0; k < e; ++k)
      if (data.tables[k].name == el.name)
        fail(path, "two elements are called " + quote_text(el.name) + " (expected unique names)");

    const std::string where = "element " + quote_text(el.name);
    std::vector<std::string_view> names;
    auto check_name = [&](const std::string& name) {
      if (!is_valid_name(name))
        fail(path, where + " has a property called " + quote_text(name) +
                       " (expected a non-empty name without whitespace)");
      if (std::find(names.begin(), names.end(), name) != names.end())
        fail(path, where + " has two properties called " + quote_text(name) +
                       " (expected unique names within an element)");
      names.push_back(name);
    };
    for (const Column& p : el.columns) {
      check_name(p.name);
      const std::size_t n = std::visit([](const auto& v) { return v.size(); }, p.data);
      if (n != el.count)
        fail(path, where + " property " + quote_text(p.name) + " has " + std::to_string(n) +
                       " values but the element count is " + std::to_string(el.count) +
                       " (expected every column to have count values)");
    }
    for (const ColumnRef& c : el.refs) {
      check_name(c.name);
      if (c.type >= kTypes.size())
        fail(path, where + " borrowed column " + quote_text(c.name) + " has the type index " +
                       std::to_string(c.type) + " (expected 0..7, as ColumnRef::of sets it)");
      if (el.count > 0 && c.first == nullptr)
        fail(path, where + " borrowed column " + quote_text(c.name) + " points nowhere (expected the " +
                       "address of its first value for " + std::to_string(el.count) + " rows)");
    }
    for (const ListColumn& l : el.lists) {
      check_name(l.name);
      if (l.data.size() != el.count)
        fail(path, where + " list property " + quote_text(l.name) + " has " +
                       std::to_string(l.data.size()) + " rows but the element count is " +
                       std::to_string(el.count) + " (expected count rows)");
      for (std::size_t r = 0; r < l.data.size(); ++r)
        if (l.data[r].size() > std::numeric_limits<std::uint8_t>::max())
          fail(path, where + " list property " + quote_text(l.name) + " row " + std::to_string(r) +
                         " has " + std::to_string(l.data[r].size()) +
                         " items (expected at most 255: list lengths are written as uchar)");
    }
  }
}

std::string make_header(const Frame& data, const std::vector<std::string>& obj_info, PlyFormat format) {
  std::string h = "ply\n";
  h += format == PlyFormat::Ascii ? "format ascii 1.0\n" : "format binary_little_endian 1.0\n";
  for (const std::string& c : data.comments) h += c.empty() ? "comment\n" : "comment " + c + "\n";
  for (const std::string& c : obj_info) h += c.empty() ? "obj_info\n" : "obj_info " + c + "\n";
  for (const Table& el : data.tables) {
    h += "element " + el.name + " " + std::to_string(el.count) + "\n";
    for (const Column& p : el.columns)
      h += "property " + std::string(info(type_of(p.data)).name) + " " + p.name + "\n";
    for (const ColumnRef& c : el.refs)
      h += "property " + std::string(info(static_cast<ScalarType>(c.type)).name) + " " + c.name + "\n";
    for (const ListColumn& l : el.lists) h += "property list uchar int " + l.name + "\n";
  }
  h += "end_header\n";
  return h;
}


using detail::AtomicFile;

void write_binary_element(AtomicFile& file, const Table& el) {
  const std::vector<RawColumn> cols = raw_columns(el);
  std::size_t stride = 0;
  for (const RawColumn& c : cols) stride += c.size;
  if (el.count == 0) return;

  if (el.lists.empty()) {
    // Fixed-size rows: interleave whole column slices into a chunk, one pass per column.
    if (stride == 0) return;
    const std::size_t rows_per_chunk = std::max<std::size_t>(1, kChunkBytes / stride);
    std::vector<unsigned char> buf(std::min(rows_per_chunk, el.count) * stride);
    for (std::size_t r0 = 0; r0 < el.count; r0 += rows_per_chunk) {
      const std::size_t n = std::min(rows_per_chunk, el.count - r0);
      std::size_t offset = 0;
      for (const RawColumn& c : cols) {
        scatter_le(c.size, c.data + r0 * c.stride, c.stride, n, buf.data() + offset, stride);
        offset += c.size;
      }
      file.write(buf.data(), n * stride);
    }
    return;
  }

  std::vector<unsigned char> buf;
  buf.reserve(kChunkBytes + 4096);
  for (std::size_t r = 0; r < el.count; ++r) {
    for (const RawColumn& c : cols) {
      const std::size_t at = buf.size();
      buf.insert(buf.end(), c.data + r * c.stride, c.data + r * c.stride + c.size);
      if constexpr (!kHostLittleEndian) std::reverse(buf.begin() + at, buf.end());
    }
    for (const ListColumn& l : el.lists) {
      const std::vector<std::int32_t>& items = l.data[r];
      buf.push_back(static_cast<unsigned char>(items.size()));
      for (std::int32_t v : items) append_le(buf, v);
    }
    if (buf.size() >= kChunkBytes) {
      file.write(buf.data(), buf.size());
      buf.clear();
    }
  }
  file.write(buf.data(), buf.size());
}

template <class T>
void append_ascii(std::string& out, T v) {
  char tmp[64];
  std::to_chars_result r;
  if constexpr (std::is_floating_point_v<T>) {
    // Shortest text that reads back to the same bits, independent of the global locale.
    r = std::to_chars(tmp, tmp + sizeof tmp, v);
  } else {
    r = std::to_chars(tmp, tmp + sizeof tmp, static_cast<long long>(v));
  }
  out.append(tmp, r.ptr);
}

template <class T>
void append_ascii_at(std::string& out, const unsigned char* value) {
  T v;
  std::memcpy(&v, value, sizeof(T));
  append_ascii(out, v);
}

void write_ascii_element(AtomicFile& file, const Table& el) {
  struct Column {
    RawColumn raw;
    void (*append)(std::string&, const unsigned char*);
  };
  std::vector<Column> cols;
  for (const RawColumn& c : raw_columns(el))
    cols.push_back({c, visit_type(c.type, [](auto tag) { return &append_ascii_at<decltype(tag)>; })});
  if (cols.empty() && el.lists.empty()) return;  // rows without properties take no space

  std::string buf;
  buf.reserve(kChunkBytes + 4096);
  for (std::size_t r = 0; r < el.count; ++r) {
    bool first = true;
    auto separate = [&] {
      if (!first) buf += ' ';
      first = false;
    };
    for (const Column& c : cols) {
      separate();
      c.append(buf, c.raw.data + r * c.raw.stride);
    }
    for (const ListColumn& l : el.lists) {
      separate();
      append_ascii(buf, l.data[r].size());
      for (std::int32_t v : l.data[r]) {
        buf += ' ';
        append_ascii(buf, v);
      }
    }
    buf += '\n';
    if (buf.size() >= kChunkBytes) {
      file.write(buf.data(), buf.size());
      buf.clear();
    }
  }
  file.write(buf.data(), buf.size());
}

// ---- reading --------------------------------------------------------------------------------

std::string read_whole_file(const fs::path& path) {
  slurry::detail::require_memory_for(path, slurry::detail::regular_file_size(path, "a PLY file"));
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, "cannot open the file for reading (permission denied?)");
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  in.seekg(0, std::ios::beg);
  if (size < 0 || !in) fail(path, "cannot determine the file size (expected a regular file)");
  std::string bytes(static_cast<std::size_t>(size), '\0');
  in.read(bytes.data(), size);
  if (in.gcount() != size) fail(path, "reading the file failed (I/O error?)");
  return bytes;
}

bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

// Whitespace-separated tokens of one line.
class Tokens {
 public:
  explicit Tokens(std::string_view line) : s_(line) {}
  bool next(std::string_view& tok) {
    while (i_ < s_.size() && is_space(s_[i_])) ++i_;
    if (i_ == s_.size()) return false;
    const std::size_t b = i_;
    while (i_ < s_.size() && !is_space(s_[i_])) ++i_;
    tok = s_.substr(b, i_ - b);
    return true;
  }

 private:
  std::string_view s_;
  std::size_t i_ = 0;
};

std::vector<std::string_view> split(std::string_view line) {
  std::vector<std::string_view> out;
  Tokens t(line);
  std::string_view tok;
  while (t.next(tok)) out.push_back(tok);
  return out;
}

template <class T>
bool parse_ascii(std::string_view tok, T& out) {
  const char* b = tok.data();
  const char* e = b + tok.size();
  // from_chars rejects a leading '+', which some writers emit.
  if (b != e && *b == '+') {
    ++b;
    if (b != e && *b == '-') return false;
  }
  if constexpr (std::is_floating_point_v<T>) {
    const auto r = std::from_chars(b, e, out);
    return r.ec == std::errc() && r.ptr == e && b != e;
  } else if constexpr (std::is_signed_v<T>) {
    long long v = 0;
    const auto r = std::from_chars(b, e, v);
    if (r.ec != std::errc() || r.ptr != e || b == e) return false;
    if (v < std::numeric_limits<T>::min() || v > std::numeric_limits<T>::max()) return false;
    out = static_cast<T>(v);
    return true;
  } else {
    unsigned long long v = 0;
    const auto r = std::from_chars(b, e, v);
    if (r.ec != std::errc() || r.ptr != e || b == e) return false;
    if (v > std::numeric_limits<T>::max()) return false;
    out = static_cast<T>(v);
    return true;
  }
}

enum class Encoding { Ascii, BinaryLittleEndian, BinaryBigEndian };

// Where each property of an element sits in a row, in header order.
struct Slot {
  bool is_list = false;
  std::size_t index = 0;  // into Table::columns or Table::lists
  ScalarType type{};      // scalar type, or the item type of a list
  ScalarType count_type{};
};

std::string row_text(std::size_t row, std::size_t count) {
  return "row " + std::to_string(row) + " of " + std::to_string(count) + " (counting from 0)";
}

class Reader {
 public:
  Reader(const fs::path& path, std::string bytes) : path_(path), bytes_(std::move(bytes)) {}

  PlyData read() {
    data_.source = path_;
    parse_header();
    for (Table& el : data_.tables) el.source = path_;
    if (encoding_ == Encoding::Ascii) {
      read_ascii_body();
    } else {
      const bool file_little = encoding_ == Encoding::BinaryLittleEndian;
      read_binary_body(file_little != kHostLittleEndian);
    }
    return std::move(data_);
  }

  /// For check_ply: parses the header of bytes_ (the file's first bytes) and returns the size the
  /// whole file must have, or 0 when the body's size cannot be known from the header (an ascii
  /// body, or binary rows with list properties).
  std::uintmax_t expected_size() {
    parse_header();
    if (encoding_ == Encoding::Ascii) return 0;
    std::uintmax_t size = pos_;
    for (std::size_t e = 0; e < data_.tables.size(); ++e) {
      if (!data_.tables[e].lists.empty()) return 0;
      std::uintmax_t stride = 0;
      for (const Slot& s : slots_[e]) stride += info(s.type).size;
      const std::uintmax_t count = data_.tables[e].count;
      if (stride > 0 && count > (std::numeric_limits<std::uintmax_t>::max() - size) / stride)
        fail(path_, "element " + quote_text(data_.tables[e].name) + " has " + std::to_string(count) +
                        " rows, more than any file can hold");
      size += count * stride;
    }
    return size;
  }

 private:
  [[noreturn]] void fail_line(const std::string& what) const {
    fail(path_, "line " + std::to_string(line_) + ": " + what);
  }

  // The next line (without its "\n" or "\r\n"), advancing pos_ and line_.
  bool next_line(std::string_view& line) {
    if (pos_ >= bytes_.size()) return false;
    std::size_t end = bytes_.find('\n', pos_);
    const std::size_t next = end == std::string::npos ? bytes_.size() : end + 1;
    if (end == std::string::npos) end = bytes_.size();
    line = std::string_view(bytes_).substr(pos_, end - pos_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    pos_ = next;
    ++line_;
    return true;
  }

  // The text after the keyword of a comment or obj_info line.
  static std::string rest_of_line(std::string_view line, std::string_view keyword) {
    std::size_t at = static_cast<std::size_t>(keyword.data() - line.data()) + keyword.size();
    if (at < line.size()) ++at;  // the one separator after the keyword
    return std::string(line.substr(at));
  }

  void parse_header() {
    std::string_view line;
    if (bytes_.empty())
      fail(path_, "the file is empty (expected a PLY header starting with 'ply')");
    next_line(line);
    if (line != "ply")
      fail(path_, "bad magic: the first line is " + quote_text(line) +
                      " (expected 'ply'; this is not a PLY file)");

    bool have_format = false;
    bool ended = false;
    while (!ended && next_line(line)) {
      const std::vector<std::string_view> t = split(line);
      if (t.empty()) continue;
      const std::string_view kw = t[0];
      if (kw == "comment") {
        data_.comments.push_back(rest_of_line(line, kw));
      } else if (kw == "obj_info") {
        data_.obj_info.push_back(rest_of_line(line, kw));
      } else if (kw == "format") {
        parse_format(t, have_format);
      } else if (kw == "element") {
        if (!have_format)
          fail_line(
              "'element' comes before the 'format' line (expected 'format <ascii|"
              "binary_little_endian|binary_big_endian> 1.0' right after 'ply')");
        parse_element(t);
      } else if (kw == "property") {
        parse_property(t);
      } else if (kw == "end_header") {
        if (t.size() != 1) fail_line("unexpected text after 'end_header': " + quote_text(line));
        ended = true;
      } else {
        fail_line("unknown header keyword " + quote_text(kw) +
                  " (expected comment, obj_info, format, element, property or end_header)");
      }
    }
    if (!ended)
      fail(path_, "the header has no 'end_header' line (the file ends at line " +
                      std::to_string(line_) + "; truncated header or not a PLY file)");
    if (!have_format)
      fail(path_,
           "the header has no 'format' line (expected 'format <ascii|"
           "binary_little_endian|binary_big_endian> 1.0' right after 'ply')");
  }

  void parse_format(const std::vector<std::string_view>& t, bool& have_format) {
    if (have_format) fail_line("a second 'format' line (expected exactly one)");
    if (t.size() != 3)
      fail_line(
          "malformed format line (expected 'format <ascii|binary_little_endian|"
          "binary_big_endian> 1.0')");
    if (t[1] == "ascii") {
      encoding_ = Encoding::Ascii;
    } else if (t[1] == "binary_little_endian") {
      encoding_ = Encoding::BinaryLittleEndian;
    } else if (t[1] == "binary_big_endian") {
      encoding_ = Encoding::BinaryBigEndian;
    } else {
      fail_line("unknown format " + quote_text(t[1]) +
                " (expected ascii, binary_little_endian or binary_big_endian)");
    }
    if (t[2] != "1.0") fail_line("unsupported PLY version " + quote_text(t[2]) + " (expected 1.0)");
    have_format = true;
  }

  void parse_element(const std::vector<std::string_view>& t) {
    if (t.size() != 3) fail_line("malformed element line (expected 'element <name> <count>')");
    if (find_element(t[1]))
      fail_line("a second element called " + quote_text(t[1]) + " (expected unique element names)");
    unsigned long long count = 0;
    const auto r = std::from_chars(t[2].data(), t[2].data() + t[2].size(), count);
    if (r.ec != std::errc() || r.ptr != t[2].data() + t[2].size() ||
        count > std::numeric_limits<std::size_t>::max())
      fail_line("element " + quote_text(t[1]) + " has the count " + quote_text(t[2]) +
                " (expected a non-negative integer)");
    Table& el = data_.tables.emplace_back();
    el.name = std::string(t[1]);
    el.count = static_cast<std::size_t>(count);
    slots_.emplace_back();
  }

  void parse_property(const std::vector<std::string_view>& t) {
    if (data_.tables.empty())
      fail_line(
          "'property' comes before any 'element' line (expected 'element <name> <count>' "
          "first)");
    Table& el = data_.tables.back();
    const bool is_list = t.size() >= 2 && t[1] == "list";
    if (is_list ? t.size() != 5 : t.size() != 3)
      fail_line(
          "malformed property line (expected 'property <type> <name>' or 'property list "
          "<count-type> <item-type> <name>')");
    const std::string_view name = t.back();
    if (el.find(name) || el.find_list(name))
      fail_line("element " + quote_text(el.name) + " has a second property called " + quote_text(name) +
                " (expected unique property names)");

    Slot slot;
    slot.is_list = is_list;
    auto type = [&](std::string_view s) {
      ScalarType st{};
      if (!parse_type_name(s, st))
        fail_line("unknown property type " + quote_text(s) + " (" + kExpectedTypes + ")");
      return st;
    };
    if (is_list) {
      slot.count_type = type(t[2]);
      slot.type = type(t[3]);
      if (!info(slot.count_type).integer)
        fail_line("list property " + quote_text(name) + " has the count type " + quote_text(t[2]) +
                  " (expected an integer type)");
      if (!info(slot.type).integer)
        fail_line("list property " + quote_text(name) + " has the item type " + quote_text(t[3]) +
                  " (expected an integer type; lists are read as int32 indices)");
      slot.index = el.lists.size();
      el.lists.push_back({std::string(name), {}});
    } else {
      slot.type = type(t[1]);
      slot.index = el.columns.size();
      el.columns.push_back({std::string(name), {}});
    }
    slots_.back().push_back(slot);
  }

  const Table* find_element(std::string_view name) const { return data_.find(name); }

  // -- binary

  void read_binary_body(bool swap) {
    const auto* p = reinterpret_cast<const unsigned char*>(bytes_.data()) + pos_;
    const auto* end = reinterpret_cast<const unsigned char*>(bytes_.data()) + bytes_.size();
    for (std::size_t e = 0; e < data_.tables.size(); ++e) {
      Table& el = data_.tables[e];
      if (el.lists.empty()) {
        read_binary_fixed(el, slots_[e], p, end, swap);
      } else {
        read_binary_rows(el, slots_[e], p, end, swap);
      }
    }
    if (p != end)
      fail(path_, std::to_string(end - p) +
                      " bytes of unexpected data after the last element (expected the body to "
                      "end there; is an element count in the header too small?)");
  }

  void read_binary_fixed(Table& el, const std::vector<Slot>& slots, const unsigned char*& p,
                         const unsigned char* end, bool swap) {
    std::size_t stride = 0;
    for (const Slot& s : slots) stride += info(s.type).size;
    const auto remaining = static_cast<std::size_t>(end - p);
    if (stride > 0 && el.count > remaining / stride) {
      const std::size_t row = remaining / stride;
      const std::size_t in_row = remaining % stride;
      std::size_t offset = 0;
      std::string_view property;
      for (const Slot& s : slots) {
        if (offset + info(s.type).size > in_row) {
          property = el.columns[s.index].name;
          break;
        }
        offset += info(s.type).size;
      }
      fail(path_, "binary body truncated in element " + quote_text(el.name) + ": data ran out at " +
                      row_text(row, el.count) + ", property " + quote_text(property) +
                      " (the element needs " + std::to_string(el.count) + " rows x " +
                      std::to_string(stride) + " bytes, but only " + std::to_string(remaining) +
                      " bytes remain)");
    }
    std::size_t offset = 0;
    for (const Slot& s : slots) {
      ColumnData col = make_column(s.type, el.count);
      std::visit(
          [&](auto& v) {
            using T = ValueType<decltype(v)>;
            if (swap) {
              gather<T, true>(p + offset, stride, el.count, v.data());
            } else {
              gather<T, false>(p + offset, stride, el.count, v.data());
            }
          },
          col);
      el.columns[s.index].data = std::move(col);
      offset += info(s.type).size;
    }
    p += el.count * stride;
  }

  void read_binary_rows(Table& el, const std::vector<Slot>& slots, const unsigned char*& p,
                        const unsigned char* end, bool swap) {
    std::size_t min_row = 0;
    for (const Slot& s : slots) min_row += info(s.is_list ? s.count_type : s.type).size;
    // A truncated body fails before row `rows`, so never allocate more rows than the bytes allow.
    const std::size_t rows = std::min(el.count, static_cast<std::size_t>(end - p) / min_row + 1);
    for (const Slot& s : slots) {
      if (s.is_list) {
        el.lists[s.index].data.resize(rows);
      } else {
        el.columns[s.index].data = make_column(s.type, rows);
      }
    }
    for (std::size_t r = 0; r < el.count; ++r) {
      for (const Slot& s : slots) {
        auto need = [&](std::size_t n) {
          if (static_cast<std::size_t>(end - p) < n)
            fail(path_, "binary body truncated in element " + quote_text(el.name) + ": data ran out at " +
                            row_text(r, el.count) + ", property " +
                            quote_text(s.is_list ? el.lists[s.index].name : el.columns[s.index].name));
        };
        if (!s.is_list) {
          need(info(s.type).size);
          std::visit([&](auto& v) { v[r] = load<ValueType<decltype(v)>>(p, swap); },
                     el.columns[s.index].data);
          p += info(s.type).size;
          continue;
        }
        need(info(s.count_type).size);
        const long long n = visit_type(s.count_type, [&](auto tag) {
          return static_cast<long long>(load<decltype(tag)>(p, swap));
        });
        p += info(s.count_type).size;
        const std::string& name = el.lists[s.index].name;
        if (n < 0)
          fail(path_, "element " + quote_text(el.name) + " " + row_text(r, el.count) + ": list " +
                          quote_text(name) + " has the length " + std::to_string(n) +
                          " (expected a non-negative length)");
        const std::size_t item = info(s.type).size;
        need(static_cast<std::size_t>(n) * item);
        std::vector<std::int32_t>& out = el.lists[s.index].data[r];
        out.resize(static_cast<std::size_t>(n));
        for (std::size_t i = 0; i < out.size(); ++i, p += item) {
          const long long v = visit_type(s.type, [&](auto tag) {
            return static_cast<long long>(load<decltype(tag)>(p, swap));
          });
          if (v > std::numeric_limits<std::int32_t>::max())
            fail(path_, "element " + quote_text(el.name) + " " + row_text(r, el.count) + ": list " +
                            quote_text(name) + " item " + std::to_string(v) +
                            " does not fit in int32 (expected indices below 2^31)");
          out[i] = static_cast<std::int32_t>(v);
        }
      }
    }
  }

  // -- ascii

  // The next line with any non-whitespace on it.
  bool next_data_line(std::string_view& line) {
    while (next_line(line))
      if (std::any_of(line.begin(), line.end(), [](char c) { return !is_space(c); })) return true;
    return false;
  }

  bool only_whitespace_left() const {
    return std::all_of(bytes_.begin() + static_cast<std::ptrdiff_t>(pos_), bytes_.end(),
                       [](char c) { return is_space(c) || c == '\n'; });
  }

  template <class T>
  T parse_value(std::string_view tok, ScalarType t, const Table& el, std::size_t row,
                const std::string& property) {
    T v{};
    if (!parse_ascii(tok, v))
      fail_line("element " + quote_text(el.name) + " " + row_text(row, el.count) + ", property " +
                quote_text(property) + ": " + quote_text(tok) + " is not a valid " + std::string(info(t).name) +
                " value (expected " + expected_value(t) + ")");
    return v;
  }

  long long parse_integer(std::string_view tok, ScalarType t, const Table& el, std::size_t row,
                          const std::string& property) {
    return visit_type(t, [&](auto tag) {
      return static_cast<long long>(parse_value<decltype(tag)>(tok, t, el, row, property));
    });
  }

  void read_ascii_body() {
    for (std::size_t e = 0; e < data_.tables.size(); ++e) {
      Table& el = data_.tables[e];
      const std::vector<Slot>& slots = slots_[e];
      if (slots.empty()) continue;  // rows without properties take no space
      // Each row takes at least one character and a line break.
      const std::size_t rows = std::min(el.count, (bytes_.size() - pos_) / 2 + 1);
      for (const Slot& s : slots) {
        if (s.is_list) {
          el.lists[s.index].data.resize(rows);
        } else {
          el.columns[s.index].data = make_column(s.type, rows);
        }
      }
      for (std::size_t r = 0; r < el.count; ++r) read_ascii_row(el, slots, r);
    }
    std::string_view line;
    if (next_data_line(line))
      fail_line("unexpected data after the last element: " + quote_text(line) +
                " (is an element count in the header too small?)");
  }

  void read_ascii_row(Table& el, const std::vector<Slot>& slots, std::size_t r) {
    std::string_view line;
    if (!next_data_line(line))
      fail(path_, "ascii body truncated in element " + quote_text(el.name) + ": data ran out at " +
                      row_text(r, el.count) + " at the end of the file (line " +
                      std::to_string(line_) + ")");
    Tokens tokens(line);
    std::string_view tok;
    auto next = [&](const std::string& property) {
      if (tokens.next(tok)) return;
      if (only_whitespace_left())
        fail(path_, "ascii body truncated in element " + quote_text(el.name) + ": data ran out at " +
                        row_text(r, el.count) + " before property " + quote_text(property) +
                        " on the last line (line " + std::to_string(line_) + ")");
      fail_line("element " + quote_text(el.name) + " " + row_text(r, el.count) +
                " ends before property " + quote_text(property) +
                " (expected one line per row holding all its properties)");
    };
    for (const Slot& s : slots) {
      if (!s.is_list) {
        const std::string& name = el.columns[s.index].name;
        next(name);
        std::visit(
            [&](auto& v) { v[r] = parse_value<ValueType<decltype(v)>>(tok, s.type, el, r, name); },
            el.columns[s.index].data);
        continue;
      }
      const std::string& name = el.lists[s.index].name;
      next(name);
      const long long n = parse_integer(tok, s.count_type, el, r, name);
      if (n < 0)
        fail_line("element " + quote_text(el.name) + " " + row_text(r, el.count) + ": list " +
                  quote_text(name) + " has the length " + std::to_string(n) +
                  " (expected a non-negative length)");
      std::vector<std::int32_t>& out = el.lists[s.index].data[r];
      out.clear();
      for (long long i = 0; i < n; ++i) {
        next(name);
        const long long v = parse_integer(tok, s.type, el, r, name);
        if (v > std::numeric_limits<std::int32_t>::max())
          fail_line("element " + quote_text(el.name) + " " + row_text(r, el.count) + ": list " +
                    quote_text(name) + " item " + std::to_string(v) +
                    " does not fit in int32 (expected indices below 2^31)");
        out.push_back(static_cast<std::int32_t>(v));
      }
    }
    if (tokens.next(tok))
      fail_line("element " + quote_text(el.name) + " " + row_text(r, el.count) + " has the extra value " +
                quote_text(tok) + " after its last property (expected one line per row)");
  }

  fs::path path_;
  std::string bytes_;
  std::size_t pos_ = 0;
  std::size_t line_ = 0;  // number of the line last returned by next_line, from 1
  Encoding encoding_ = Encoding::Ascii;
  PlyData data_;
  std::vector<std::vector<Slot>> slots_;  // per element, in header order
};

}  // namespace

// ---- entry points ---------------------------------------------------------------------------

void write_ply(const fs::path& path, const Frame& data, PlyFormat format, const std::vector<std::string>& obj_info) {
  if (path.filename().empty())
    fail(path, "the path names no file (expected a file name such as 'f0001.ply')");
  validate(path, data, obj_info);
  const fs::path dir = path.parent_path().empty() ? fs::path(".") : path.parent_path();
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    fail(path, "the directory " + quote_text(dir.string()) +
                   " does not exist (expected an existing directory; write_ply does not create "
                   "directories)");
  if (fs::is_directory(path, ec))
    fail(path, "it is a directory (expected a file path to write the PLY file to)");

  AtomicFile file(path);
  const std::string header = make_header(data, obj_info, format);
  file.write(header.data(), header.size());
  for (const Table& el : data.tables) {
    if (format == PlyFormat::Ascii) {
      write_ascii_element(file, el);
    } else {
      write_binary_element(file, el);
    }
  }
  file.commit();
}

void write_ply(const fs::path& path, const PlyData& data, PlyFormat format) {
  write_ply(path, static_cast<const Frame&>(data), format, data.obj_info);
}

void check_ply(const fs::path& path) {
  const std::uintmax_t size = slurry::detail::regular_file_size(path, "a PLY file");
  std::string head;
  {
    // The header: up to 1 MiB (a Slurry frame's header is a few hundred bytes).
    std::ifstream in(path, std::ios::binary);
    if (!in) fail(path, "cannot open the file for reading (permission denied?)");
    head.resize(std::size_t(std::min<std::uintmax_t>(size, std::uintmax_t(1) << 20)));
    in.read(head.data(), std::streamsize(head.size()));
    if (in.gcount() != std::streamsize(head.size())) fail(path, "reading the file failed (I/O error?)");
    const std::size_t end = head.find("end_header");
    const std::size_t eol = end == std::string::npos ? end : head.find('\n', end);
    if (eol != std::string::npos) head.resize(eol + 1);
  }
  const std::uintmax_t expected = Reader(path, std::move(head)).expected_size();
  if (expected == 0) {
    (void)read_ply(path);
    return;
  }
  if (size != expected)
    fail(path, std::string(size < expected ? "truncated" : "too long") + ": the file has " + std::to_string(size) +
                   " bytes, its header and element counts give " + std::to_string(expected) + " bytes" +
                   (size < expected ? " (expected a whole file; was it cut off while being written or copied?)"
                                    : " (expected the body to end after the last element)"));
}

PlyData read_ply(const fs::path& path) {
  try {
    return Reader(path, read_whole_file(path)).read();
  } catch (const std::bad_alloc&) {
    // The size check before reading passed (a sparse file, memory taken since), but it did not fit.
    throw ResourceError(path.string() + ": out of memory reading the PLY file; expected a file that fits in the "
                        "available memory");
  }
}

}  // namespace slurry::io
