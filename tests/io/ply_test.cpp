// Tests of the PLY reader and writer against the format as described by Greg Turk, "The PLY
// Polygon File Format" (Stanford 3D Scanning Repository): exact round trips, the header text
// and body size byte for byte, a hand-made big-endian file, error messages and atomic writes.
#include "slurry/io/ply.h"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "slurry/engine/errors.h"

namespace slurry::io {
namespace {

namespace fs = std::filesystem;

// ---- helpers ----------------------------------------------------------------------------------

class PlyTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* test = ::testing::UnitTest::GetInstance()->current_test_info();
    std::random_device rd;
    // Parameterised test names contain '/'.
    std::string name = std::string(test->test_suite_name()) + "_" + test->name();
    std::replace(name.begin(), name.end(), '/', '_');
    dir_ = fs::temp_directory_path() / ("slurry_ply_" + name + "_" + std::to_string(rd()));
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  std::vector<std::string> dir_entries() const {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(dir_))
      names.push_back(e.path().filename().string());
    return names;
  }

  fs::path dir_;
};

std::string read_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void write_bytes(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// Runs f, expects an IoError and returns its message ("" and a test failure if none was thrown).
template <class F>
std::string io_error_of(F&& f) {
  try {
    f();
  } catch (const IoError& e) {
    return e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected slurry::IoError, got another exception: " << e.what();
    return "";
  }
  ADD_FAILURE() << "expected slurry::IoError, nothing was thrown";
  return "";
}

#define EXPECT_CONTAINS(text, part) \
  EXPECT_NE(std::string(text).find(part), std::string::npos) << "message: " << (text)

template <class T>
auto bits(T v) {
  using U = std::conditional_t<sizeof(T) == 4, std::uint32_t, std::uint64_t>;
  U u;
  std::memcpy(&u, &v, sizeof v);
  return u;
}

// Values at the edges of each type: integer limits; signed zeros, denormals, the normal range
// limits, infinities, NaN and values with a full mantissa for floating point.
template <class T>
std::vector<T> edge_values() {
  using L = std::numeric_limits<T>;
  if constexpr (std::is_integral_v<T>) {
    std::vector<T> v{L::min(), L::max(), T(0), T(1), T(L::max() - 1), T(L::min() + 1), T(42)};
    if constexpr (std::is_signed_v<T>) v.push_back(T(-1));
    return v;
  } else {
    return {T(0),           -T(0),    L::denorm_min(), -L::denorm_min(), L::min() - L::denorm_min(),
            L::min(),       L::max(), L::lowest(),     L::epsilon(),     T(1) / T(3),
            T(-2) / T(7),   T(1e-30), T(3.0e38),       L::infinity(),    -L::infinity(),
            L::quiet_NaN(), T(0.1),   T(16777217.0)};
  }
}

// A column of n values cycling through the edge values of T.
template <class T>
std::vector<T> edge_column(std::size_t n) {
  const std::vector<T> e = edge_values<T>();
  std::vector<T> v(n);
  for (std::size_t i = 0; i < n; ++i) v[i] = e[i % e.size()];
  return v;
}

void expect_same_column(const ColumnData& a, const ColumnData& b, const std::string& name) {
  ASSERT_EQ(a.index(), b.index()) << "property " << name << " changed type";
  std::visit(
      [&](const auto& va) {
        using V = std::decay_t<decltype(va)>;
        using T = typename V::value_type;
        const V& vb = std::get<V>(b);
        ASSERT_EQ(va.size(), vb.size()) << name;
        for (std::size_t i = 0; i < va.size(); ++i) {
          if constexpr (std::is_floating_point_v<T>) {
            if (std::isnan(va[i])) {
              EXPECT_TRUE(std::isnan(vb[i])) << name << " row " << i;
            } else {
              EXPECT_EQ(bits(va[i]), bits(vb[i]))
                  << name << " row " << i << ": wrote " << va[i] << ", read " << vb[i];
            }
          } else {
            EXPECT_EQ(+va[i], +vb[i]) << name << " row " << i;
          }
        }
      },
      a);
}

void expect_same(const PlyData& a, const PlyData& b) {
  EXPECT_EQ(a.comments, b.comments);
  EXPECT_EQ(a.obj_info, b.obj_info);
  ASSERT_EQ(a.tables.size(), b.tables.size());
  for (std::size_t e = 0; e < a.tables.size(); ++e) {
    const Table& ea = a.tables[e];
    const Table& eb = b.tables[e];
    EXPECT_EQ(ea.name, eb.name);
    EXPECT_EQ(ea.count, eb.count);
    ASSERT_EQ(ea.columns.size(), eb.columns.size()) << ea.name;
    for (std::size_t p = 0; p < ea.columns.size(); ++p) {
      EXPECT_EQ(ea.columns[p].name, eb.columns[p].name);
      expect_same_column(ea.columns[p].data, eb.columns[p].data,
                         ea.name + "." + ea.columns[p].name);
    }
    ASSERT_EQ(ea.lists.size(), eb.lists.size()) << ea.name;
    for (std::size_t l = 0; l < ea.lists.size(); ++l) {
      EXPECT_EQ(ea.lists[l].name, eb.lists[l].name);
      EXPECT_EQ(ea.lists[l].data, eb.lists[l].data) << ea.name << "." << ea.lists[l].name;
    }
  }
}

// One element holding a column of every scalar type, 40 rows of edge values.
PlyData all_types_data() {
  constexpr std::size_t n = 40;
  PlyData d;
  d.comments = {"every PLY scalar type", "", "  leading spaces kept"};
  d.obj_info = {"slurry ply_test"};
  Table& v = d.tables.emplace_back();
  v.name = "vertex";
  v.count = n;
  v.columns = {{"c", edge_column<std::int8_t>(n)},  {"uc", edge_column<std::uint8_t>(n)},
                  {"s", edge_column<std::int16_t>(n)}, {"us", edge_column<std::uint16_t>(n)},
                  {"i", edge_column<std::int32_t>(n)}, {"ui", edge_column<std::uint32_t>(n)},
                  {"f", edge_column<float>(n)},        {"d", edge_column<double>(n)}};
  return d;
}

// vertex (x, y, z), face (a scalar and a list) and edge (two ints): several elements, lists of
// length 0 to 255 with extreme indices.
PlyData mesh_data() {
  PlyData d;
  Table& v = d.tables.emplace_back();
  v.name = "vertex";
  v.count = 4;
  v.columns = {{"x", std::vector<float>{0.f, 1.f, 0.f, 0.25f}},
                  {"y", std::vector<float>{0.f, 0.f, 1.f, -0.5f}},
                  {"z", std::vector<float>{0.f, 0.f, 0.f, 1e-40f}}};
  Table& f = d.tables.emplace_back();
  f.name = "face";
  f.count = 4;
  f.columns = {{"flags", std::vector<std::uint8_t>{1, 2, 255, 0}}};
  std::vector<std::int32_t> long_list(255);
  for (std::size_t i = 0; i < long_list.size(); ++i) long_list[i] = static_cast<std::int32_t>(i);
  f.lists = {{"vertex_indices",
              {{0, 1, 2},
               {},
               long_list,
               {std::numeric_limits<std::int32_t>::max(), std::numeric_limits<std::int32_t>::min(),
                -1, 3}}}};
  Table& e = d.tables.emplace_back();
  e.name = "edge";
  e.count = 3;
  e.columns = {{"vertex1", std::vector<std::int32_t>{0, 1, 2}},
                  {"vertex2", std::vector<std::int32_t>{1, 2, 0}}};
  return d;
}

PlyData xyz_data(std::size_t n) {
  PlyData d;
  Table& v = d.tables.emplace_back();
  v.name = "vertex";
  v.count = n;
  std::vector<float> x(n), y(n), z(n);
  for (std::size_t i = 0; i < n; ++i) {
    x[i] = 0.5f * static_cast<float>(i);
    y[i] = -static_cast<float>(i);
    z[i] = 1.0f / static_cast<float>(i + 1);
  }
  v.columns = {{"x", x}, {"y", y}, {"z", z}};
  return d;
}

std::vector<std::string> header_lines(const std::string& bytes, std::size_t* body_offset) {
  const std::string end = "end_header\n";
  const std::size_t at = bytes.find(end);
  EXPECT_NE(at, std::string::npos) << "no end_header line";
  if (at == std::string::npos) return {};
  *body_offset = at + end.size();
  std::vector<std::string> lines;
  std::istringstream in(bytes.substr(0, *body_offset));
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

const char* format_name(PlyFormat f) {
  return f == PlyFormat::Ascii ? "ascii" : "binary";
}

// ---- round trips ----------------------------------------------------------------------------

class PlyRoundTrip : public PlyTest, public ::testing::WithParamInterface<PlyFormat> {};

TEST_P(PlyRoundTrip, EveryScalarTypeWithEdgeValuesIsExact) {
  const PlyData written = all_types_data();
  const fs::path path = dir_ / "all_types.ply";
  write_ply(path, written, GetParam());
  const PlyData read = read_ply(path);
  expect_same(written, read);
  EXPECT_EQ(read.source, path);
  EXPECT_EQ(read.table("vertex").source, path);
}

TEST_P(PlyRoundTrip, ListPropertiesAndSeveralElements) {
  const PlyData written = mesh_data();
  const fs::path path = dir_ / "mesh.ply";
  write_ply(path, written, GetParam());
  const PlyData read = read_ply(path);
  expect_same(written, read);
  EXPECT_EQ(read.table("face").list("vertex_indices").data[2].size(), 255u);
}

TEST_P(PlyRoundTrip, EmptyElementsAndNoElements) {
  PlyData d;
  d.tables.push_back({"vertex", 0, {{"x", std::vector<double>{}}}, {}, {}, {}});
  d.tables.push_back({"face", 0, {}, {{"vertex_indices", {}}}, {}, {}});
  const fs::path path = dir_ / "empty.ply";
  write_ply(path, d, GetParam());
  expect_same(d, read_ply(path));

  const PlyData none;
  write_ply(path, none, GetParam());
  EXPECT_TRUE(read_ply(path).tables.empty());
}

TEST_P(PlyRoundTrip, OverwritesAnExistingFileAndLeavesNoTemporaryFile) {
  const fs::path path = dir_ / "f0001.ply";
  write_bytes(path, "old contents");
  write_ply(path, xyz_data(1000), GetParam());
  expect_same(xyz_data(1000), read_ply(path));
  EXPECT_EQ(dir_entries(), std::vector<std::string>{"f0001.ply"});
}

INSTANTIATE_TEST_SUITE_P(Formats, PlyRoundTrip,
                         ::testing::Values(PlyFormat::BinaryLittleEndian, PlyFormat::Ascii),
                         [](const auto& info) { return std::string(format_name(info.param)); });

TEST_F(PlyTest, ColumnAccessorsConvertAndCheckTypes) {
  const fs::path path = dir_ / "all_types.ply";
  write_ply(path, all_types_data(), PlyFormat::BinaryLittleEndian);
  const PlyData d = read_ply(path);
  const Table& v = d.table("vertex");
  EXPECT_EQ(v.column_as_double("ui")[1], 4294967295.0);
  EXPECT_EQ(v.column_as_double("c")[0], -128.0);
  EXPECT_EQ(v.column_as_double("f")[6], static_cast<double>(std::numeric_limits<float>::max()));
  EXPECT_EQ(v.column_as_float("d")[9], 1.0f / 3.0f);
  EXPECT_EQ(v.values<std::uint16_t>("us")[1], 65535);
  EXPECT_EQ(v.values<double>("d").size(), 40u);

  std::string msg = io_error_of([&] { v.column_as_double("vz"); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "element 'vertex' has no property 'vz'");
  EXPECT_CONTAINS(msg, "'ui'");
  msg = io_error_of([&] { v.values<float>("d"); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "stored as double, not float");
  msg = io_error_of([&] { d.table("face"); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "no element 'face'");
  EXPECT_EQ(d.find("face"), nullptr);
  EXPECT_EQ(v.find("nope"), nullptr);
}

// ---- the header and body against the format description ---------------------------------

TEST_F(PlyTest, BinaryHeaderLinesAndBodySizeFollowTheSpec) {
  PlyData d;
  d.comments = {"written by ply_test", ""};
  d.obj_info = {"num_cols 3"};
  constexpr std::size_t n = 7;
  Table& v = d.tables.emplace_back();
  v.name = "vertex";
  v.count = n;
  v.columns = {{"x", std::vector<float>(n)},
                  {"vx", std::vector<double>(n)},
                  {"material", std::vector<std::uint8_t>(n)},
                  {"m16", std::vector<std::uint16_t>(n)},
                  {"c", std::vector<std::int8_t>(n)},
                  {"s", std::vector<std::int16_t>(n)},
                  {"i", std::vector<std::int32_t>(n)},
                  {"u", std::vector<std::uint32_t>(n)}};
  const fs::path path = dir_ / "header.ply";
  write_ply(path, d);

  const std::string bytes = read_bytes(path);
  std::size_t body = 0;
  const std::vector<std::string> expected{"ply",
                                          "format binary_little_endian 1.0",
                                          "comment written by ply_test",
                                          "comment",
                                          "obj_info num_cols 3",
                                          "element vertex 7",
                                          "property float x",
                                          "property double vx",
                                          "property uchar material",
                                          "property ushort m16",
                                          "property char c",
                                          "property short s",
                                          "property int i",
                                          "property uint u",
                                          "end_header"};
  EXPECT_EQ(header_lines(bytes, &body), expected);
  EXPECT_EQ(bytes.find('\r'), std::string::npos) << "header lines must end in \\n only";
  EXPECT_EQ(bytes.size() - body, n * (4 + 8 + 1 + 2 + 1 + 2 + 4 + 4));
}

TEST_F(PlyTest, BinaryBodyIsPackedLittleEndianRows) {
  PlyData d;
  d.tables.push_back({"vertex",
                        2,
                        {{"x", std::vector<float>{1.5f, -2.0f}},
                         {"m", std::vector<std::uint16_t>{0x0102, 0xA0B0}},
                         {"d", std::vector<double>{-2.25, 1.0}}},
                        {},
                        {}, {}});
  d.tables.push_back({"face", 1, {}, {{"vertex_indices", {{1, -1}}}}, {}, {}});
  const fs::path path = dir_ / "body.ply";
  write_ply(path, d);
  const std::string bytes = read_bytes(path);
  std::size_t body = 0;
  const std::vector<std::string> lines = header_lines(bytes, &body);
  ASSERT_GE(lines.size(), 3u);
  EXPECT_EQ(lines[lines.size() - 2], "property list uchar int vertex_indices");
  const std::string expected_body(
      "\x00\x00\xC0\x3F"
      "\x02\x01"
      "\x00\x00\x00\x00\x00\x00\x02\xC0"
      "\x00\x00\x00\xC0"
      "\xB0\xA0"
      "\x00\x00\x00\x00\x00\x00\xF0\x3F"
      "\x02"
      "\x01\x00\x00\x00"
      "\xFF\xFF\xFF\xFF",
      2 * (4 + 2 + 8) + 1 + 8);
  EXPECT_EQ(bytes.substr(body), expected_body);
}

TEST_F(PlyTest, AsciiHeaderAndBodyText) {
  PlyData d;
  d.tables.push_back({"vertex",
                        2,
                        {{"x", std::vector<float>{0.1f, -0.0f}},
                         {"material", std::vector<std::uint8_t>{255, 7}},
                         {"c", std::vector<std::int8_t>{-128, 65}},
                         {"J", std::vector<double>{1e300, 0.1}}},
                        {},
                        {}, {}});
  d.tables.push_back({"face", 1, {}, {{"vertex_indices", {{0, 1, -1}}}}, {}, {}});
  const fs::path path = dir_ / "ascii.ply";
  write_ply(path, d, PlyFormat::Ascii);
  const std::string bytes = read_bytes(path);
  std::size_t body = 0;
  const std::vector<std::string> expected{"ply",
                                          "format ascii 1.0",
                                          "element vertex 2",
                                          "property float x",
                                          "property uchar material",
                                          "property char c",
                                          "property double J",
                                          "element face 1",
                                          "property list uchar int vertex_indices",
                                          "end_header"};
  EXPECT_EQ(header_lines(bytes, &body), expected);
  // Numbers, not characters, for char/uchar; shortest exact text for floats.
  EXPECT_EQ(bytes.substr(body), "0.1 255 -128 1e+300\n-0 7 65 0.1\n3 0 1 -1\n");
}

// ---- reading files from other writers -----------------------------------------------------

TEST_F(PlyTest, ReadsHandWrittenBigEndianFile) {
  const std::string header =
      "ply\n"
      "format binary_big_endian 1.0\n"
      "comment written byte by byte\n"
      "element vertex 2\n"
      "property float32 x\n"
      "property int16 s\n"
      "property uint u\n"
      "property float64 d\n"
      "element face 1\n"
      "property list uint8 int32 vertex_indices\n"
      "end_header\n";
  const std::string body(
      "\x3F\xC0\x00\x00"                  // x = 1.5
      "\xFF\xFE"                          // s = -2
      "\x01\x02\x03\x04"                  // u = 0x01020304
      "\xC0\x02\x00\x00\x00\x00\x00\x00"  // d = -2.25
      "\x80\x00\x00\x00"                  // x = -0.0
      "\x01\x02"                          // s = 258
      "\xFF\xFF\xFF\xFF"                  // u = 4294967295
      "\x3F\xF0\x00\x00\x00\x00\x00\x00"  // d = 1.0
      "\x03"                              // 3 indices
      "\x00\x00\x00\x01"
      "\x00\x00\x00\x02"
      "\xFF\xFF\xFF\xFF",
      2 * (4 + 2 + 4 + 8) + 1 + 12);
  const fs::path path = dir_ / "big.ply";
  write_bytes(path, header + body);

  const PlyData d = read_ply(path);
  EXPECT_EQ(d.comments, std::vector<std::string>{"written byte by byte"});
  const Table& v = d.table("vertex");
  ASSERT_EQ(v.count, 2u);
  EXPECT_EQ(v.values<float>("x")[0], 1.5f);
  EXPECT_EQ(bits(v.values<float>("x")[1]), 0x80000000u);
  EXPECT_EQ(v.values<std::int16_t>("s"), (std::vector<std::int16_t>{-2, 258}));
  EXPECT_EQ(v.values<std::uint32_t>("u"), (std::vector<std::uint32_t>{0x01020304u, 0xFFFFFFFFu}));
  EXPECT_EQ(v.values<double>("d"), (std::vector<double>{-2.25, 1.0}));
  EXPECT_EQ(d.table("face").list("vertex_indices").data,
            (std::vector<std::vector<std::int32_t>>{{1, 2, -1}}));
}

TEST_F(PlyTest, ReadsAsciiWithCrLfObjInfoAndOtherListTypes) {
  const fs::path path = dir_ / "crlf.ply";
  write_bytes(path,
              "ply\r\n"
              "format ascii 1.0\r\n"
              "obj_info scanned 1994\r\n"
              "comment made by hand\r\n"
              "element vertex 2\r\n"
              "property float x\r\n"
              "property uint8 m\r\n"
              "element face 2\r\n"
              "property list ushort uint vertex_indices\r\n"
              "property uchar red\r\n"
              "end_header\r\n"
              "1.25\t+3\r\n"
              "  -7e-3 0  \r\n"
              "3 0 1 2 200\r\n"
              "0 9\r\n"
              "\r\n");
  const PlyData d = read_ply(path);
  EXPECT_EQ(d.obj_info, std::vector<std::string>{"scanned 1994"});
  EXPECT_EQ(d.comments, std::vector<std::string>{"made by hand"});
  EXPECT_EQ(d.table("vertex").values<float>("x"), (std::vector<float>{1.25f, -7e-3f}));
  EXPECT_EQ(d.table("vertex").values<std::uint8_t>("m"), (std::vector<std::uint8_t>{3, 0}));
  EXPECT_EQ(d.table("face").list("vertex_indices").data,
            (std::vector<std::vector<std::int32_t>>{{0, 1, 2}, {}}));
  EXPECT_EQ(d.table("face").values<std::uint8_t>("red"), (std::vector<std::uint8_t>{200, 9}));
}

// ---- errors -------------------------------------------------------------------------------

constexpr const char* kAsciiHeader =
    "ply\n"
    "format ascii 1.0\n"
    "element vertex 2\n"
    "property float x\n"
    "end_header\n";

// A reader opens only regular files: a FIFO would block it forever (nothing writes to it), so it
// is refused at once, as are directories and loops of symbolic links, each named for what it is.
TEST_F(PlyTest, FifoDirectoryAndLinkLoopAreRefusedForWhatTheyAre) {
  const fs::path fifo = dir_ / "frame_0001.ply";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::string msg = io_error_of([&] { read_ply(fifo); });
  EXPECT_CONTAINS(msg, fifo.string() + ": a FIFO (named pipe), not a regular file (expected a PLY file)");
  const fs::path dir = dir_ / "frame_0002.ply";
  fs::create_directory(dir);
  msg = io_error_of([&] { read_ply(dir); });
  EXPECT_CONTAINS(msg, dir.string() + ": a directory, not a file (expected a PLY file)");
  const fs::path a = dir_ / "a.ply", b = dir_ / "b.ply";
  fs::create_symlink(b, a);
  fs::create_symlink(a, b);
  msg = io_error_of([&] { read_ply(a); });
  EXPECT_CONTAINS(msg, a.string() + ": a loop of symbolic links (expected a PLY file)");
  const fs::path dangling = dir_ / "c.ply";
  fs::create_symlink(dir_ / "gone.ply", dangling);
  msg = io_error_of([&] { read_ply(dangling); });
  EXPECT_CONTAINS(msg, dangling.string() + ": a symbolic link to a file that does not exist");
}

TEST_F(PlyTest, MissingFileIsAnError) {
  const fs::path path = dir_ / "nope.ply";
  const std::string msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "no such file");
}

TEST_F(PlyTest, BadMagicIsAnError) {
  const fs::path path = dir_ / "magic.ply";
  write_bytes(path, std::string("plx\nformat ascii 1.0\nelement vertex 0\nend_header\n"));
  std::string msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "bad magic");
  EXPECT_CONTAINS(msg, "'plx'");

  write_bytes(path, "");
  msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, "the file is empty");
}

TEST_F(PlyTest, UnknownFormatIsAnError) {
  const fs::path path = dir_ / "format.ply";
  write_bytes(path, "ply\nformat binary_middle_endian 1.0\nelement vertex 0\nend_header\n");
  std::string msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "line 2: unknown format 'binary_middle_endian'");
  EXPECT_CONTAINS(msg, "binary_big_endian");

  write_bytes(path, "ply\nformat ascii 2.0\nend_header\n");
  msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, "unsupported PLY version '2.0'");

  write_bytes(path, "ply\nelement vertex 0\nend_header\n");
  msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, "'element' comes before the 'format' line");
}

TEST_F(PlyTest, UnknownTypeIsAnError) {
  const fs::path path = dir_ / "type.ply";
  write_bytes(path, "ply\nformat ascii 1.0\nelement vertex 1\nproperty flaot x\nend_header\n1\n");
  std::string msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "line 4: unknown property type 'flaot'");
  EXPECT_CONTAINS(msg, "uchar");

  write_bytes(path,
              "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar float uv\nend_header\n");
  msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, "item type 'float' (expected an integer type");
}

TEST_F(PlyTest, MalformedHeadersAreErrors) {
  const fs::path path = dir_ / "header.ply";
  const std::vector<std::pair<std::string, std::string>> cases{
      {"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "no 'end_header' line"},
      {"ply\nformat ascii 1.0\nelement vertex -3\nend_header\n", "count '-3'"},
      {"ply\nformat ascii 1.0\nproperty float x\nend_header\n", "before any 'element'"},
      {"ply\nformat ascii 1.0\nelement v 1\nproperty float\nend_header\n", "malformed property"},
      {"ply\nformat ascii 1.0\nelement v 1\nproperty float x\nproperty int x\nend_header\n",
       "second property called 'x'"},
      {"ply\nformat ascii 1.0\nvertices 3\nend_header\n", "unknown header keyword 'vertices'"},
      {"ply\ncomment no format\nend_header\n", "no 'format' line"},
  };
  for (const auto& [text, phrase] : cases) {
    write_bytes(path, text);
    const std::string msg = io_error_of([&] { read_ply(path); });
    EXPECT_CONTAINS(msg, path.string());
    EXPECT_CONTAINS(msg, phrase);
  }
}

TEST_F(PlyTest, TruncatedBinaryBodyIsAnError) {
  const fs::path path = dir_ / "short.ply";
  write_ply(path, xyz_data(10));
  const std::string full = read_bytes(path);
  write_bytes(path, full.substr(0, full.size() - 6));  // row 9 keeps x and half of y
  std::string msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "binary body truncated in element 'vertex'");
  EXPECT_CONTAINS(msg, "row 9 of 10");
  EXPECT_CONTAINS(msg, "property 'y'");

  // The same inside an element with a list, parsed row by row.
  write_ply(path, mesh_data());
  const std::string mesh = read_bytes(path);
  const std::size_t edge_bytes = 3 * 8;
  write_bytes(path, mesh.substr(0, mesh.size() - edge_bytes - 5));  // into face row 3's list
  msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, "binary body truncated in element 'face'");
  EXPECT_CONTAINS(msg, "row 3 of 4");
  EXPECT_CONTAINS(msg, "property 'vertex_indices'");

  // A header that promises far more rows than the file holds fails without allocating them.
  write_bytes(path, std::string("ply\nformat binary_little_endian 1.0\nelement face 4000000000000\n"
                                "property list uchar int vertex_indices\nend_header\n") +
                        std::string("\x01\x02\x00\x00\x00", 5));
  msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, "row 1 of 4000000000000");
}

// check_ply: a binary file's size against its header, without reading the body; ascii and list
// bodies read whole.
TEST_F(PlyTest, CheckPlyFindsCutAndLongFilesFromTheHeader) {
  const fs::path path = dir_ / "check.ply";
  write_ply(path, xyz_data(10));
  const std::string full = read_bytes(path);
  EXPECT_NO_THROW(slurry::io::check_ply(path));
  write_bytes(path, full.substr(0, full.size() - 6));
  std::string msg = io_error_of([&] { slurry::io::check_ply(path); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "truncated: the file has " + std::to_string(full.size() - 6) + " bytes, its header and element "
                       "counts give " + std::to_string(full.size()) + " bytes");
  write_bytes(path, full + "xy");
  EXPECT_CONTAINS(io_error_of([&] { slurry::io::check_ply(path); }), "too long: the file has");
  write_bytes(path, full.substr(0, full.find("end_header")));  // the header cut before its end
  EXPECT_CONTAINS(io_error_of([&] { slurry::io::check_ply(path); }), "no 'end_header' line");
  write_ply(path, mesh_data());  // lists: read whole
  EXPECT_NO_THROW(slurry::io::check_ply(path));
  const std::string mesh = read_bytes(path);
  write_bytes(path, mesh.substr(0, mesh.size() - 3));
  EXPECT_CONTAINS(io_error_of([&] { slurry::io::check_ply(path); }), "binary body truncated");
  write_ply(path, xyz_data(5), PlyFormat::Ascii);
  EXPECT_NO_THROW(slurry::io::check_ply(path));
  const std::string text = read_bytes(path);
  write_bytes(path, text.substr(0, text.size() - 4));
  EXPECT_FALSE(io_error_of([&] { slurry::io::check_ply(path); }).empty());
}

TEST_F(PlyTest, TrailingDataAfterBodyIsAnError) {
  const fs::path path = dir_ / "long.ply";
  write_ply(path, xyz_data(3));
  write_bytes(path, read_bytes(path) + "xy");
  std::string msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, "2 bytes of unexpected data after the last element");

  write_bytes(path, std::string(kAsciiHeader) + "1\n2\n3\n");
  msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, "line 8: unexpected data after the last element");
}

TEST_F(PlyTest, TruncatedAsciiBodyIsAnError) {
  const fs::path path = dir_ / "short.ply";
  write_ply(path, xyz_data(5), PlyFormat::Ascii);
  const std::string full = read_bytes(path);
  std::size_t cut = full.size() - 1;
  for (int lines = 0; lines < 2; ++lines) cut = full.rfind('\n', cut - 1);
  write_bytes(path, full.substr(0, cut + 1));  // the last two rows are gone
  std::string msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "ascii body truncated in element 'vertex'");
  EXPECT_CONTAINS(msg, "row 3 of 5");

  write_bytes(path, full.substr(0, full.rfind(' ')));  // the last row loses its z
  msg = io_error_of([&] { read_ply(path); });
  EXPECT_CONTAINS(msg, "ascii body truncated in element 'vertex'");
  EXPECT_CONTAINS(msg, "row 4 of 5 (counting from 0) before property 'z'");
}

TEST_F(PlyTest, BadAsciiValuesAreErrors) {
  const fs::path path = dir_ / "values.ply";
  const std::vector<std::pair<std::string, std::string>> cases{
      {std::string(kAsciiHeader) + "1.5\nabc\n", "line 7: element 'vertex' row 1 of 2"},
      {std::string(kAsciiHeader) + "1.5\nabc\n", "'abc' is not a valid float value"},
      {std::string(kAsciiHeader) + "1.5 2\n3\n", "line 6: element 'vertex' row 0 of 2"},
      {std::string(kAsciiHeader) + "1.5 2\n3\n", "extra value '2'"},
      {"ply\nformat ascii 1.0\nelement v 1\nproperty uchar m\nend_header\n256\n",
       "'256' is not a valid uchar value (expected an integer in 0..255)"},
      {"ply\nformat ascii 1.0\nelement v 2\nproperty int a\nproperty int b\nend_header\n1\n2 3\n",
       "line 7: element 'v' row 0 of 2 (counting from 0) ends before property 'b'"},
      {"ply\nformat ascii 1.0\nelement f 1\nproperty list char int i\nend_header\n-1\n",
       "has the length -1"},
  };
  for (const auto& [text, phrase] : cases) {
    write_bytes(path, text);
    const std::string msg = io_error_of([&] { read_ply(path); });
    EXPECT_CONTAINS(msg, path.string());
    EXPECT_CONTAINS(msg, phrase);
  }
}

TEST_F(PlyTest, MismatchedColumnSizesAreRejectedBeforeTouchingTheDisk) {
  PlyData d = xyz_data(10);
  std::get<std::vector<float>>(d.tables[0].columns[1].data).pop_back();
  const fs::path path = dir_ / "bad.ply";
  const std::string msg = io_error_of([&] { write_ply(path, d); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "element 'vertex' property 'y' has 9 values but the element count is 10");
  EXPECT_FALSE(fs::exists(path));
  EXPECT_TRUE(dir_entries().empty());
}

TEST_F(PlyTest, InvalidDataIsRejectedOnWrite) {
  const fs::path path = dir_ / "bad.ply";
  auto expect_rejected = [&](const PlyData& d, const std::string& phrase) {
    const std::string msg = io_error_of([&] { write_ply(path, d); });
    EXPECT_CONTAINS(msg, path.string());
    EXPECT_CONTAINS(msg, phrase);
    EXPECT_TRUE(dir_entries().empty());
  };
  PlyData d = xyz_data(2);
  d.tables[0].columns[2].name = "x";
  expect_rejected(d, "two properties called 'x'");
  d = xyz_data(2);
  d.tables[0].columns[2].name = "z coordinate";
  expect_rejected(d, "property called 'z coordinate'");
  d = xyz_data(2);
  d.tables[0].columns[2].name = "";
  expect_rejected(d, "expected a non-empty name without whitespace");
  d = xyz_data(2);
  d.tables.push_back(d.tables[0]);
  expect_rejected(d, "two elements are called 'vertex'");
  d = xyz_data(2);
  d.comments = {"one\ntwo"};
  expect_rejected(d, "contains a line break");
  d = mesh_data();
  d.tables[1].lists[0].data[0].resize(256);
  expect_rejected(d, "row 0 has 256 items (expected at most 255");
  d = mesh_data();
  d.tables[1].lists[0].data.pop_back();
  expect_rejected(d, "list property 'vertex_indices' has 3 rows but the element count is 4");
}

TEST_F(PlyTest, WritingIntoAMissingDirectoryIsAnError) {
  const fs::path path = dir_ / "no_such_dir" / "f0001.ply";
  const std::string msg = io_error_of([&] { write_ply(path, xyz_data(3)); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "does not exist");
  EXPECT_FALSE(fs::exists(dir_ / "no_such_dir"));
}

// ---- atomicity ----------------------------------------------------------------------------

TEST_F(PlyTest, SuccessfulWritesLeaveNoTemporaryFiles) {
  for (int i = 0; i < 3; ++i) {
    write_ply(dir_ / "f0001.ply", xyz_data(100), PlyFormat::BinaryLittleEndian);
    write_ply(dir_ / "f0002.ply", mesh_data(), PlyFormat::Ascii);
  }
  std::vector<std::string> names = dir_entries();
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"f0001.ply", "f0002.ply"}));
}

TEST_F(PlyTest, FailedWriteLeavesTheOlderFileIntact) {
  const fs::path path = dir_ / "f0001.ply";
  write_ply(path, xyz_data(5));
  const std::string before = read_bytes(path);

  PlyData bad = xyz_data(8);
  bad.tables[0].count = 9;
  const std::string msg = io_error_of([&] { write_ply(path, bad); });
  EXPECT_CONTAINS(msg, "has 8 values but the element count is 9");
  EXPECT_EQ(read_bytes(path), before);
  EXPECT_EQ(dir_entries(), std::vector<std::string>{"f0001.ply"});
  expect_same(xyz_data(5), read_ply(path));
}

TEST_F(PlyTest, WritingOntoADirectoryFailsAndRemovesNothing) {
  const fs::path path = dir_ / "frame.ply";
  fs::create_directory(path);
  const std::string msg = io_error_of([&] { write_ply(path, xyz_data(2)); });
  EXPECT_CONTAINS(msg, path.string());
  EXPECT_CONTAINS(msg, "it is a directory");
  EXPECT_TRUE(fs::is_directory(path));
  EXPECT_EQ(dir_entries(), std::vector<std::string>{"frame.ply"});
}

// Borrowed columns (ColumnRef) read packed vectors component by component, a constant with
// stride 0, and a plain array; the file must be byte-identical to the one written from copies,
// in both encodings, and own() must turn the borrowed frame into exactly those copies.
TEST_F(PlyTest, BorrowedColumnsWriteTheSameBytesAsCopies) {
  struct Vec3 {
    float c[3];
  };
  const std::size_t n = 3000;  // several rows per chunk, and more than one chunk of ascii text
  std::vector<Vec3> x(n);
  std::vector<std::uint32_t> id(n);
  for (std::size_t i = 0; i < n; ++i) {
    x[i] = {{0.1f * float(i), -2.5f + float(i) / 7.0f, float(i * i) * 1e-3f}};
    id[i] = std::uint32_t(n - i) * 2654435761u;
  }
  const std::uint16_t material = 7;

  PlyData copied;
  copied.comments = {"borrowed"};
  Table& c = copied.tables.emplace_back();
  c.name = "vertex";
  c.count = n;
  const char* names[3] = {"x", "y", "z"};
  for (int d = 0; d < 3; ++d) {
    std::vector<float> col(n);
    for (std::size_t i = 0; i < n; ++i) col[i] = x[i].c[d];
    c.columns.push_back({names[d], col});
  }
  c.columns.push_back({"material", std::vector<std::uint16_t>(n, material)});
  c.columns.push_back({"id", id});

  PlyData borrowed;
  borrowed.comments = {"borrowed"};
  Table& b = borrowed.tables.emplace_back();
  b.name = "vertex";
  b.count = n;
  for (int d = 0; d < 3; ++d) b.refs.push_back(ColumnRef::of(names[d], &x[0].c[d], sizeof(Vec3)));
  b.refs.push_back(ColumnRef::of("material", &material, 0));
  b.refs.push_back(ColumnRef::of("id", id.data()));

  for (const PlyFormat format : {PlyFormat::BinaryLittleEndian, PlyFormat::Ascii}) {
    write_ply(dir_ / "copied.ply", copied, format);
    write_ply(dir_ / "borrowed.ply", borrowed, format);
    const std::string want = read_bytes(dir_ / "copied.ply");
    EXPECT_GT(want.size(), n * 18);
    EXPECT_EQ(read_bytes(dir_ / "borrowed.ply"), want) << (format == PlyFormat::Ascii ? "ascii" : "binary");
  }
  // A borrowed column is not a property until it is owned; then it is the copy.
  EXPECT_EQ(borrowed.tables[0].find("x"), nullptr);
  PlyData owned = borrowed;
  x[0].c[0] = 99.0f;  // the copy does not follow the array any more
  owned.own();
  x[0].c[0] = 0.0f;
  ASSERT_TRUE(owned.tables[0].refs.empty());
  ASSERT_EQ(owned.tables[0].columns.size(), 5u);
  EXPECT_EQ(owned.tables[0].values<float>("x")[0], 99.0f);
  owned.tables[0].columns[0] = c.columns[0];
  for (std::size_t k = 0; k < 5; ++k) {
    EXPECT_EQ(owned.tables[0].columns[k].name, c.columns[k].name);
    EXPECT_EQ(owned.tables[0].columns[k].data, c.columns[k].data) << c.columns[k].name;
  }
  // Names are checked across owned and borrowed columns; a borrowed column must point somewhere.
  PlyData clash = borrowed;
  clash.tables[0].columns.push_back({"id", std::vector<std::uint8_t>(n)});
  EXPECT_CONTAINS(io_error_of([&] { write_ply(dir_ / "bad.ply", clash); }), "two properties called 'id'");
  PlyData dangling = borrowed;
  dangling.tables[0].refs[1].first = nullptr;
  EXPECT_CONTAINS(io_error_of([&] { write_ply(dir_ / "bad.ply", dangling); }), "borrowed column 'y' points nowhere");
  EXPECT_FALSE(fs::exists(dir_ / "bad.ply"));
}

}  // namespace
}  // namespace slurry::io
