// The look-ups and copies of frame.h.
#include "slurry/engine/frame.h"

#include <algorithm>
#include <array>
#include <cstring>

#include "slurry/engine/errors.h"
#include "slurry/engine/quote_text.h"

namespace slurry {
namespace {

constexpr std::array<std::string_view, 8> kTypeNames{"char", "uchar", "short", "ushort",
                                                     "int",  "uint",  "float", "double"};
constexpr std::array<std::size_t, 8> kTypeSizes{1, 1, 2, 2, 4, 4, 4, 8};

[[noreturn]] void fail(const std::filesystem::path& source, const std::string& what) {
  throw IoError((source.empty() ? std::string("<in-memory frame>") : source.string()) + ": " + what);
}


std::string describe_columns(const Table& t) {
  if (t.columns.empty() && t.lists.empty()) return "it has no properties";
  std::string s = "it has";
  const char* sep = " ";
  for (const Column& c : t.columns) {
    s += sep + quote_text(c.name);
    sep = ", ";
  }
  for (const ListColumn& l : t.lists) {
    s += sep + ("list " + quote_text(l.name));
    sep = ", ";
  }
  return s;
}

template <class Out>
std::vector<Out> convert_column(const Column& c) {
  return std::visit(
      [](const auto& v) {
        std::vector<Out> out(v.size());
        std::transform(v.begin(), v.end(), out.begin(), [](auto x) { return static_cast<Out>(x); });
        return out;
      },
      c.data);
}

/// Row values of a strided column of alternative `type`, converted to Out.
template <class Out, std::size_t I = 0>
std::vector<Out> convert_strided(std::size_t type, const unsigned char* first, std::size_t stride, std::size_t n) {
  if constexpr (I + 1 < std::variant_size_v<ColumnData>) {
    if (type != I) return convert_strided<Out, I + 1>(type, first, stride, n);
  }
  using T = typename std::variant_alternative_t<I, ColumnData>::value_type;
  std::vector<Out> out(n);
  for (std::size_t i = 0; i < n; ++i) {
    T v;
    std::memcpy(&v, first + i * stride, sizeof(T));
    out[i] = static_cast<Out>(v);
  }
  return out;
}

template <std::size_t I = 0>
ColumnData copy_strided(std::size_t type, const unsigned char* first, std::size_t stride, std::size_t n) {
  if constexpr (I + 1 < std::variant_size_v<ColumnData>) {
    if (type != I) return copy_strided<I + 1>(type, first, stride, n);
  }
  using T = typename std::variant_alternative_t<I, ColumnData>::value_type;
  std::vector<T> v(n);
  for (std::size_t i = 0; i < n; ++i) std::memcpy(&v[i], first + i * stride, sizeof(T));
  return ColumnData(std::move(v));
}

}  // namespace

std::string quote_text(std::string_view s) {
  constexpr std::size_t kMax = 60;
  std::string out = "'";
  for (std::size_t i = 0; i < s.size() && i < kMax; ++i) {
    const auto c = static_cast<unsigned char>(s[i]);
    out += (c >= 0x20 && c < 0x7f) ? static_cast<char>(c) : '?';
  }
  if (s.size() > kMax) out += "...";
  return out + "'";
}

std::string_view column_type_name(std::size_t type) { return type < kTypeNames.size() ? kTypeNames[type] : "?"; }
std::size_t column_type_size(std::size_t type) { return type < kTypeSizes.size() ? kTypeSizes[type] : 0; }

const Column* Table::find(std::string_view n) const {
  for (const Column& c : columns)
    if (c.name == n) return &c;
  return nullptr;
}

const ListColumn* Table::find_list(std::string_view n) const {
  for (const ListColumn& l : lists)
    if (l.name == n) return &l;
  return nullptr;
}

const Column& Table::column(std::string_view n) const {
  if (const Column* c = find(n)) return *c;
  if (find_list(n))
    fail(source, "property " + quote_text(n) + " of element " + quote_text(name) +
                     " is a list (expected a scalar property; use list())");
  fail(source, "element " + quote_text(name) + " has no property " + quote_text(n) + " (" + describe_columns(*this) + ")");
}

const ListColumn& Table::list(std::string_view n) const {
  if (const ListColumn* l = find_list(n)) return *l;
  if (find(n))
    fail(source, "property " + quote_text(n) + " of element " + quote_text(name) +
                     " is a scalar (expected a list property; use column())");
  fail(source, "element " + quote_text(name) + " has no list property " + quote_text(n) + " (" + describe_columns(*this) + ")");
}

const ColumnRef* Table::find_ref(std::string_view n) const {
  for (const ColumnRef& c : refs)
    if (c.name == n) return &c;
  return nullptr;
}

bool Table::has(std::string_view n) const { return find(n) || find_ref(n); }

template <class Out>
std::vector<Out> Table::column_as(std::string_view n) const {
  if (!find(n))
    if (const ColumnRef* c = find_ref(n); c && c->type < kTypeNames.size() && (count == 0 || c->first))
      return convert_strided<Out>(c->type, static_cast<const unsigned char*>(c->first), c->stride, count);
  return convert_column<Out>(column(n));
}

std::vector<double> Table::column_as_double(std::string_view n) const { return column_as<double>(n); }

std::vector<float> Table::column_as_float(std::string_view n) const { return column_as<float>(n); }

void Table::throw_wrong_type(const Column& c, std::string_view wanted) const {
  fail(source, "property " + quote_text(c.name) + " of element " + quote_text(name) + " is stored as " +
                   std::string(column_type_name(c.data.index())) + ", not " + std::string(wanted) +
                   " (expected the stored type; column_as_double() converts)");
}

void Table::own() {
  for (const ColumnRef& c : refs) {
    if (c.type >= kTypeNames.size() || (count > 0 && c.first == nullptr))
      fail(source, "element " + quote_text(name) + " borrowed column " + quote_text(c.name) +
                       " has no valid type or address (expected one made by ColumnRef::of)");
    columns.push_back({c.name, copy_strided(c.type, static_cast<const unsigned char*>(c.first), c.stride, count)});
  }
  refs.clear();
}

void Frame::own() {
  for (Table& t : tables) t.own();
}

const Table* Frame::find(std::string_view name) const {
  for (const Table& t : tables)
    if (t.name == name) return &t;
  return nullptr;
}

Table* Frame::find(std::string_view name) { return const_cast<Table*>(static_cast<const Frame*>(this)->find(name)); }

const Table& Frame::table(std::string_view name) const {
  if (const Table* t = find(name)) return *t;
  std::string have;
  for (const Table& t : tables) have += (have.empty() ? "" : ", ") + quote_text(t.name);
  fail(source, "no element " + quote_text(name) + " (" +
                   (have.empty() ? std::string("the file has no elements") : "it has " + have) + ")");
}

}  // namespace slurry
