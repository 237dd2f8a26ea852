// TetGen .node/.ele reader and writer; see tetgen.h for the format and the error messages.
#include "slurry/io/tetgen.h"

#include "input_file.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

namespace slurry::io {
using fem::Mesh;
using fem::kDegenerateRatio;
namespace {

/// A whitespace-separated token stream over the non-comment part of a file's lines.
class TokenFile {
 public:
  explicit TokenFile(const std::filesystem::path& path)
      : path_(path), in_((slurry::detail::regular_file_size(path, "a TetGen mesh file"), path)) {
    if (!in_) throw IoError(path.string() + ": cannot open the mesh file (does it exist and is it readable?)");
  }

  /// Moves to the next line that has tokens; false at the end of the file.
  bool next_line() {
    std::string line;
    while (std::getline(in_, line)) {
      ++line_no_;
      if (const auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
      tokens_.clear();
      std::istringstream s(line);
      for (std::string t; s >> t;) tokens_.push_back(t);
      pos_ = 0;
      if (!tokens_.empty()) return true;
    }
    if (in_.bad()) throw IoError(path_.string() + ": read error");
    return false;
  }
  /// Starts the next non-empty line or fails naming what was expected there.
  void expect_line(const std::string& what) {
    if (!next_line())
      throw IoError(path_.string() + ":" + std::to_string(line_no_) + ": the file ends early (expected " + what + ")");
  }
  std::size_t tokens_left() const { return tokens_.size() - pos_; }

  [[noreturn]] void fail(const std::string& field, const std::string& what) const {
    throw IoError(path_.string() + ":" + std::to_string(line_no_) + ": " + field + ": " + what);
  }

  long long integer(const std::string& field) {
    const std::string t = token(field, "an integer");
    char* end = nullptr;
    errno = 0;
    const long long v = std::strtoll(t.c_str(), &end, 10);
    if (errno || end == t.c_str() || *end != '\0') fail(field, "expected an integer, got \"" + t + "\"");
    return v;
  }
  double number(const std::string& field) {
    const std::string t = token(field, "a number");
    char* end = nullptr;
    errno = 0;
    const double v = std::strtod(t.c_str(), &end);
    if (errno == ERANGE || end == t.c_str() || *end != '\0' || !std::isfinite(v))
      fail(field, "expected a finite number, got \"" + t + "\"");
    return v;
  }
  /// Fails if tokens are left on the current line beyond `allowed` more.
  void finish_line(const std::string& field) const {
    if (tokens_left() > 0) fail(field, "unexpected extra value \"" + tokens_[pos_] + "\" at the end of the line");
  }
  int line() const { return line_no_; }

 private:
  std::string token(const std::string& field, const std::string& what) {
    if (pos_ >= tokens_.size()) fail(field, "missing (expected " + what + ")");
    return tokens_[pos_++];
  }

  std::filesystem::path path_;
  std::ifstream in_;
  int line_no_ = 0;
  std::vector<std::string> tokens_;
  std::size_t pos_ = 0;
};

/// Items reserved up front at most; beyond that, storage grows with what the file holds.
constexpr long long kReserve = 1 << 16;

long long in_range(TokenFile& f, const std::string& field, long long v, long long lo, long long hi) {
  if (v < lo || v > hi)
    f.fail(field, "expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + std::to_string(v));
  return v;
}

}  // namespace

std::pair<std::filesystem::path, std::filesystem::path> tetgen_files(const std::filesystem::path& path) {
  std::filesystem::path stem = path;
  if (path.extension() == ".node" || path.extension() == ".ele") stem.replace_extension();
  std::filesystem::path node = stem, ele = stem;
  node += ".node";
  ele += ".ele";
  return {node, ele};
}

int tetgen_dimension(const std::filesystem::path& path) {
  TokenFile f(tetgen_files(path).first);
  f.expect_line("the header: <# of points> <dimension> <# of attributes> <boundary markers>");
  f.integer("number of points");
  return int(in_range(f, "dimension", f.integer("dimension"), 2, 3));
}

template <int Dim>
Mesh<Dim> read_tetgen(const std::filesystem::path& path) {
  // Named variables, not a structured binding: lambdas below capture them (C++17, clang 14).
  const auto files = tetgen_files(path);
  const std::filesystem::path &node_path = files.first, &ele_path = files.second;
  Mesh<Dim> mesh;
  int base = 0;
  std::vector<int> lines;  // line of each element in the .ele file, for messages
  {
    TokenFile f(node_path);
    f.expect_line("the header: <# of points> <dimension> <# of attributes> <boundary markers>");
    const long long n = in_range(f, "number of points", f.integer("number of points"), 1, 1LL << 30);
    const long long dim = f.integer("dimension");
    if (dim != Dim)
      f.fail("dimension", "expected " + std::to_string(Dim) + " (the scene's dimension), got " + std::to_string(dim));
    const long long attributes = in_range(f, "number of attributes", f.integer("number of attributes"), 0, 1 << 20);
    long long markers = 0;
    if (f.tokens_left() > 0) markers = in_range(f, "boundary markers", f.integer("boundary markers"), 0, 1);
    f.finish_line("header");
    // The header's count is not trusted for allocation: storage grows with the points actually
    // read, so a header announcing 2^30 points in a short file fails at its end, not in malloc.
    mesh.x.reserve(std::size_t(std::min(n, kReserve)));
    for (long long i = 0; i < n; ++i) {
      f.expect_line("point " + std::to_string(i + 1) + " of " + std::to_string(n));
      const std::string p = "point " + std::to_string(i);
      const long long index = f.integer(p + ", index");
      if (i == 0) {
        if (index != 0 && index != 1) f.fail(p + ", index", "expected 0 or 1 (the first index sets the numbering), got " + std::to_string(index));
        base = int(index);
      } else if (index != base + i) {
        f.fail(p + ", index", "expected " + std::to_string(base + i) + " (points numbered consecutively), got " + std::to_string(index));
      }
      static const char* axis[3] = {"x", "y", "z"};
      auto& x = mesh.x.emplace_back();
      for (int d = 0; d < Dim; ++d) x[d] = f.number(p + ", " + axis[d]);
      for (long long a = 0; a < attributes; ++a) f.number(p + ", attribute " + std::to_string(a));
      if (markers) f.integer(p + ", boundary marker");
      f.finish_line(p);
    }
    if (f.next_line()) f.fail("end of file", "expected no more points after " + std::to_string(n));
  }
  {
    TokenFile f(ele_path);
    f.expect_line("the header: <# of elements> <vertices per element> <# of attributes>");
    const long long n = in_range(f, "number of elements", f.integer("number of elements"), 1, 1LL << 30);
    const long long per = f.integer("vertices per element");
    if (per != Dim + 1)
      f.fail("vertices per element", "expected " + std::to_string(Dim + 1) + " (linear " +
                                          (Dim == 3 ? "tetrahedra" : "triangles") + "), got " + std::to_string(per));
    long long attributes = 0;
    if (f.tokens_left() > 0) attributes = in_range(f, "number of attributes", f.integer("number of attributes"), 0, 1 << 20);
    f.finish_line("header");
    mesh.elements.reserve(std::size_t(std::min(n, kReserve)));
    lines.reserve(std::size_t(std::min(n, kReserve)));
    const long long lo = base, hi = base + (long long)mesh.x.size() - 1;
    for (long long e = 0; e < n; ++e) {
      f.expect_line("element " + std::to_string(e + 1) + " of " + std::to_string(n));
      const std::string p = "element " + std::to_string(e);
      lines.push_back(f.line());
      auto& el = mesh.elements.emplace_back();
      const long long index = f.integer(p + ", index");
      if (index != base + e)
        f.fail(p + ", index", "expected " + std::to_string(base + e) + " (elements numbered like the points, consecutively), got " +
                                  std::to_string(index));
      for (int k = 0; k < Dim + 1; ++k) {
        const std::string field = p + ", vertex " + std::to_string(k);
        const long long v = f.integer(field);
        if (v < lo || v > hi)
          f.fail(field, "expected a point index in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + std::to_string(v));
        el[std::size_t(k)] = int(v - base);
      }
      for (long long a = 0; a < attributes; ++a) f.number(p + ", attribute " + std::to_string(a));
      f.finish_line(p);
    }
    if (f.next_line()) f.fail("end of file", "expected no more elements after " + std::to_string(n));
  }
  // Element checks with the element's line: degenerate elements, then orientation (a file may
  // use either orientation consistently; a mix means folded, inverted elements).
  const auto where = [&](std::size_t e) {
    return ele_path.string() + ":" + std::to_string(lines[e]) + ": element " + std::to_string(e + std::size_t(base)) + ": ";
  };
  std::size_t negative = 0;
  for (std::size_t e = 0; e < mesh.elements.size(); ++e) {
    const auto& el = mesh.elements[e];
    for (int a = 0; a < Dim + 1; ++a)
      for (int b = 0; b < a; ++b)
        if (el[std::size_t(a)] == el[std::size_t(b)])
          throw IoError(where(e) + "repeats point " + std::to_string(el[std::size_t(a)] + base) + " (expected " +
                        std::to_string(Dim + 1) + " distinct points)");
    const double det = mesh.edge_matrix(e).determinant();
    const double L = mesh.edge_range(e).second;
    if (!(std::abs(det) >= kDegenerateRatio * std::pow(L, Dim)))
      throw IoError(where(e) + "is degenerate (zero volume; expected " + (Dim == 3 ? "four points not in one plane" : "three points not on one line") + ")");
    if (det < 0) ++negative;
  }
  const bool flip = negative * 2 > mesh.elements.size();
  if (negative != 0 && negative != mesh.elements.size())
    for (std::size_t e = 0; e < mesh.elements.size(); ++e)
      if ((mesh.edge_matrix(e).determinant() < 0) != flip)
        throw IoError(where(e) + "is inverted: its orientation is opposite to that of the other " +
                      std::to_string(flip ? negative : mesh.elements.size() - negative) + " elements (a folded mesh)");
  if (flip)
    for (auto& el : mesh.elements) std::swap(el[Dim - 1], el[Dim]);
  try {
    check_mesh(mesh, ele_path.string());
  } catch (const SceneError& e) {
    throw IoError(e.what());
  }
  return mesh;
}

template <int Dim>
void write_tetgen(const std::filesystem::path& stem, const Mesh<Dim>& mesh) {
  const auto [node_path, ele_path] = tetgen_files(stem);
  {
    std::ofstream out(node_path);
    if (!out) throw IoError(node_path.string() + ": cannot create the file");
    out.precision(std::numeric_limits<double>::max_digits10);
    out << "# written by slurry: <# of points> <dimension> <# of attributes> <boundary markers>\n";
    out << mesh.x.size() << ' ' << Dim << " 0 0\n";
    for (std::size_t i = 0; i < mesh.x.size(); ++i) {
      out << i + 1;
      for (int d = 0; d < Dim; ++d) out << ' ' << mesh.x[i][d];
      out << '\n';
    }
    if (!out) throw IoError(node_path.string() + ": write error");
  }
  {
    std::ofstream out(ele_path);
    if (!out) throw IoError(ele_path.string() + ": cannot create the file");
    out << "# written by slurry: <# of elements> <vertices per element> <# of attributes>\n";
    out << mesh.elements.size() << ' ' << Dim + 1 << " 0\n";
    for (std::size_t e = 0; e < mesh.elements.size(); ++e) {
      out << e + 1;
      for (int v : mesh.elements[e]) out << ' ' << v + 1;
      out << '\n';
    }
    if (!out) throw IoError(ele_path.string() + ": write error");
  }
}

template Mesh<2> read_tetgen<2>(const std::filesystem::path&);
template Mesh<3> read_tetgen<3>(const std::filesystem::path&);
template void write_tetgen<2>(const std::filesystem::path&, const Mesh<2>&);
template void write_tetgen<3>(const std::filesystem::path&, const Mesh<3>&);

}  // namespace slurry::io
