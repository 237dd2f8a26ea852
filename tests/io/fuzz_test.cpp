// Deterministic mutation fuzzing of the three readers of untrusted files: the scene parser
// (parse_scene, then estimate and check_resources), the PLY reader and the TetGen reader. Each
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

#include "slurry/io/tetgen.h"
#include "slurry/io/ply.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"

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

/// One mutated copy of `seed`.
std::string mutate(const std::string& seed, std::mt19937_64& rng) {
  std::string s = seed;
  const auto pick = [&](std::size_t n) { return n == 0 ? std::size_t(0) : std::size_t(rng() % n); };
  const int n = 1 + int(rng() % 4);
  for (int k = 0; k < n; ++k) {
    const std::size_t at = pick(s.size() + 1);
    switch (rng() % 6) {
      case 0:  // flip a byte
        if (!s.empty()) s[pick(s.size())] ^= char(1 << (rng() % 8));
        break;
      case 1:  // a token that once broke a reader
        s.insert(at, kTokens[pick(std::size(kTokens))]);
        break;
      case 2:  // delete a range
        s.erase(at, pick(32) + 1);
        break;
      case 3: {  // duplicate a range
        const std::string part = s.substr(at, pick(64) + 1);
        s.insert(pick(s.size() + 1), part);
        break;
      }
      case 4:  // truncate
        s.resize(at);
        break;
      default:  // a random byte
        s.insert(at, 1, char(rng() % 256));
        break;
    }
  }
  return s;
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

}  // namespace
