// Deterministic mutation fuzzing of the readers of untrusted files: the scene parser (parse_scene,
// then estimate and check_resources; the example scenes, and a mesh collider's keyframes), the
// PLY reader, the TetGen reader and the triangle mesh reader (OBJ and PLY, then the closed-mesh
// check and placement). Each
// input is a seed file with 1-4 mutations (byte flips, insertions of tokens that once broke a
// reader, deletions, duplications, truncations); every reader must either accept it or throw
// slurry::Error, never anything else. Crashes, hangs and undefined behaviour show up as a failed
// test, and under the sanitizer build (.ci/test, build/asan) as a report. The iteration count is
// fixed (SLURRY_FUZZ_ITERATIONS multiplies it for longer runs), so a finding is reproducible.
#include <gtest/gtest.h>

#include <unistd.h>
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <typeinfo>
#include <vector>

#include "fuzz_mutate.h"
#include "slurry/io/tetgen.h"
#include "slurry/io/ply.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"
#include "slurry/io/triangle_mesh_file.h"

namespace {

namespace fs = std::filesystem;

int iterations(int base) {
  const char* scale = std::getenv("SLURRY_FUZZ_ITERATIONS");
  return scale ? base * std::max(1, std::atoi(scale)) : base;
}

const char* const kTokens[] = {
    "1e400",
    "-1e400",
    "-1",
    "4294967297",
    "18446744073709551616",
    "-9223372036854775809",
    "1e-300",
    "0",
    "nan",
    "null",
    "true",
    "[",
    "]",
    "{",
    "}",
    "\"",
    ",",
    ":",
    "\"dx\": 1,",
    "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[",
    "1073741824",
    "element vertex 4294967295\n",
    "property list uint int vertex_indices\n",
    "\xff\xfe",
    "end_header\n",
    "#",
    "\n",
    "\0"};

/// One mutated copy of `seed`, the special mutation inserting a token that once broke a reader.
std::string mutate(const std::string& seed, std::mt19937_64& rng) {
  return slurry::test::mutate(seed, rng, [](std::string& s, std::size_t at, const auto& pick) {
    s.insert(at, kTokens[pick(std::size(kTokens))]);
  });
}

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void write_file(const fs::path& p, const std::string& text) {
  std::ofstream(p, std::ios::binary) << text;
}

/// Runs fn(input); anything but success or slurry::Error is a finding, reported with the input.
template <class Fn>
void expect_clean(const std::string& input, Fn&& fn) {
  try {
    fn();
  } catch (const slurry::Error&) {
  } catch (const std::exception& e) {
    ADD_FAILURE() << "unexpected " << typeid(e).name() << ": " << e.what() << "\ninput ("
                  << input.size() << " bytes): " << input.substr(0, 400);
  }
}

fs::path scratch(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("slurry_fuzz_" + std::to_string(::getpid())) / name;
  fs::create_directories(dir);
  return dir;
}

TEST(Fuzz, SceneParser) {
  std::vector<std::string> seeds;
  for (const auto& e : fs::directory_iterator(SLURRY_EXAMPLES_DIR))
    if (e.path().extension() == ".json") seeds.push_back(read_file(e.path()));
  std::sort(seeds.begin(), seeds.end());  // directory order is not deterministic
  ASSERT_GE(seeds.size(), 8u);
  std::mt19937_64 rng(11);
  int accepted = 0;
  const int n = iterations(20000);
  for (int i = 0; i < n; ++i) {
    const std::string input = mutate(seeds[std::size_t(i) % seeds.size()], rng);
    expect_clean(input, [&] {
      const slurry::Scene s = slurry::parse_scene(input, "fuzz.json");
      s.estimate();
      slurry::check_resources(s, 1e6);
      ++accepted;
    });
  }
  // The mutations must leave some inputs valid, or the fuzzer only tests the JSON syntax check.
  EXPECT_GT(accepted, n / 50);
}

TEST(Fuzz, PlyReader) {
  slurry::io::PlyData data;
  data.comments = {"fuzz seed"};
  slurry::Table v;
  v.name = "vertex";
  v.count = 5;
  v.columns.push_back({"x", std::vector<float>{0, 1, 2, 3, 4}});
  v.columns.push_back({"id", std::vector<std::uint32_t>{5, 6, 7, 8, 9}});
  slurry::Table f;
  f.name = "face";
  f.count = 2;
  f.lists.push_back({"vertex_indices", {{0, 1, 2}, {2, 3, 4}}});
  data.tables = {v, f};
  const fs::path dir = scratch("ply");
  std::vector<std::string> seeds;
  for (auto format : {slurry::io::PlyFormat::Ascii, slurry::io::PlyFormat::BinaryLittleEndian}) {
    slurry::io::write_ply(dir / "seed.ply", data, format);
    seeds.push_back(read_file(dir / "seed.ply"));
  }
  std::mt19937_64 rng(12);
  const int n = iterations(3000);
  for (int i = 0; i < n; ++i) {
    const std::string input = mutate(seeds[std::size_t(i) % seeds.size()], rng);
    write_file(dir / "in.ply", input);
    expect_clean(input, [&] { slurry::io::read_ply(dir / "in.ply"); });
  }
  fs::remove_all(dir);
}

TEST(Fuzz, TetgenReader) {
  const fs::path dir = scratch("tetgen");
  const auto cube = slurry::fem::box_mesh<3>(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, 1, 1),
                                             Eigen::Vector3i(2, 1, 1));
  slurry::io::write_tetgen<3>(dir / "seed", cube);
  const std::string node = read_file(dir / "seed.node"), ele = read_file(dir / "seed.ele");
  std::mt19937_64 rng(13);
  const int n = iterations(3000);
  for (int i = 0; i < n; ++i) {
    const bool mutate_node = i % 2 == 0;
    const std::string input = mutate(mutate_node ? node : ele, rng);
    write_file(dir / "in.node", mutate_node ? input : node);
    write_file(dir / "in.ele", mutate_node ? ele : input);
    expect_clean(input, [&] { slurry::io::read_tetgen<3>(dir / "in"); });
    expect_clean(input, [&] { slurry::io::read_tetgen<2>(dir / "in"); });
  }
  fs::remove_all(dir);
}

// A mesh collider's keyframes (times, translations, rotations): the mutations fall inside the
// keyframe list of a scene that is otherwise valid.
TEST(Fuzz, ColliderKeyframes) {
  std::string keys;
  for (int k = 0; k < 8; ++k)
    keys += std::string(k ? ", " : "") + R"({"time": )" + std::to_string(0.25 * k) + R"(, "translation": [0.5, )" +
            std::to_string(0.3 + 0.01 * k) + R"(, 0.5], "rotation": [0, 0, )" + std::to_string(45 * k) + "]}";
  const std::string head = R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.1}, "solver": {"dimension": 3},
    "materials": [{"name": "m"}], "bodies": [{"shape": "box", "min": [0.2, 0.5, 0.2], "max": [0.4, 0.7, 0.4], "material": "m"}],
    "colliders": [{"shape": "mesh", "mesh": "paddle.obj", "keyframes": [)";
  const std::string tail = "]}]}";
  ASSERT_NO_THROW(slurry::parse_scene(head + keys + tail, "keys.json"));
  std::mt19937_64 rng(14);
  int accepted = 0;
  const int n = iterations(5000);
  for (int i = 0; i < n; ++i) {
    const std::string input = head + mutate(keys, rng) + tail;
    expect_clean(input, [&] {
      const slurry::Scene s = slurry::parse_scene(input, "keys.json");
      slurry::check_resources(s, 1e6);
      ++accepted;
    });
  }
  // Some mutations leave valid keys (a changed digit), so the checks after the syntax ran too.
  EXPECT_GT(accepted, n / 200);
  EXPECT_LT(accepted, n);
}

// Triangle meshes of mesh bodies and colliders, OBJ (with the i/t/n and negative index forms) and
// PLY (ascii and binary), read, then checked for a closed surface and placed.
TEST(Fuzz, TriangleMeshReader) {
  const fs::path dir = scratch("mesh");
  const std::string obj =
      "# cube\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\nvt 0 0\nvn 0 0 1\n"
      "f 1/1/1 4/1/1 3/1/1 2/1/1\nf 5 6 7 8\nf -8 -7 -3 -4\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";
  slurry::io::PlyData ply;
  slurry::Table v;
  v.name = "vertex";
  v.count = 8;
  std::vector<float> x, y, z;
  for (int c = 0; c < 8; ++c) x.push_back(float(c & 1)), y.push_back(float((c >> 1) & 1)), z.push_back(float(c >> 2));
  v.columns = {{"x", x}, {"y", y}, {"z", z}};
  slurry::Table f;
  f.name = "face";
  f.count = 6;
  f.lists.push_back({"vertex_indices", {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}}});
  ply.tables = {v, f};
  struct Seed {
    std::string name, bytes;
  };
  std::vector<Seed> seeds = {{"in.obj", obj}};
  for (auto format : {slurry::io::PlyFormat::Ascii, slurry::io::PlyFormat::BinaryLittleEndian}) {
    slurry::io::write_ply(dir / "seed.ply", ply, format);
    seeds.push_back({"in.ply", read_file(dir / "seed.ply")});
  }
  for (const Seed& seed : seeds) {  // every seed is a closed cube
    write_file(dir / seed.name, seed.bytes);
    ASSERT_NO_THROW(slurry::geometry::place_closed_mesh(slurry::io::read_triangle_mesh(dir / seed.name),
                                                        Eigen::Vector3d::Ones(), Eigen::Matrix3d::Identity(),
                                                        Eigen::Vector3d::Zero(), seed.name));
  }
  std::mt19937_64 rng(15);
  int closed = 0;
  const int n = iterations(3000);
  for (int i = 0; i < n; ++i) {
    const Seed& seed = seeds[std::size_t(i) % seeds.size()];
    const std::string input = mutate(seed.bytes, rng);
    write_file(dir / seed.name, input);
    expect_clean(input, [&] {
      slurry::geometry::TriangleMesh m = slurry::io::read_triangle_mesh(dir / seed.name);
      slurry::geometry::place_closed_mesh(std::move(m), Eigen::Vector3d(2, 1, 0.5),
                                          slurry::geometry::euler_degrees(Eigen::Vector3d(10, 20, 30)),
                                          Eigen::Vector3d(0.1, 0.2, 0.3), seed.name);
      ++closed;
    });
  }
  EXPECT_GT(closed, 0);
  EXPECT_LT(closed, n);
  fs::remove_all(dir);
}

}  // namespace
