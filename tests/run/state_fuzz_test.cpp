// Deterministic mutation fuzzing of the run's own files read back as untrusted input: checkpoint
// payloads (the run section and each solver's state, behind a valid checksum, so that the
// mutations reach the parsers a checksum does not protect) and the per-rank parts `slurry merge`
// joins. Each input is a real file of a small run with 1-4 mutations (byte flips, deletions,
// duplications, truncations, random bytes, little-endian integers that once broke a reader);
// resuming or merging must either succeed or throw slurry::Error, never anything else, and a
// resumed state must hold finite positions inside the domain. The fixed seeds make a finding
// reproducible; SLURRY_FUZZ_ITERATIONS multiplies the iteration counts.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <typeinfo>
#include <vector>

#include "fuzz_mutate.h"
#include "slurry/engine/errors.h"
#include "slurry/engine/run/run.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/checkpoint.h"
#include "slurry/io/scene_file.h"

namespace fs = std::filesystem;

namespace {

int iterations(int base) {
  const char* scale = std::getenv("SLURRY_FUZZ_ITERATIONS");
  return scale ? base * std::max(1, std::atoi(scale)) : base;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void write_file(const fs::path& p, const std::string& bytes) { std::ofstream(p, std::ios::binary) << bytes; }

fs::path scratch(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("slurry_state_fuzz_" + std::to_string(::getpid())) / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

/// One mutated copy of binary `seed`: counts and sizes are the fields a state reader trusts
/// least, so the special mutation writes integers that overflow or mislead them (and infinities
/// and NaNs where doubles lie), 4 or 8 bytes in place.
std::string mutate(const std::string& seed, std::mt19937_64& rng) {
  static const std::uint64_t kValues[] = {0, 1, 0xffffffffu, 0x7fffffffu, 0x80000000u, 0xffffffffffffffffull,
                                          std::uint64_t(1) << 40, 0x7ff0000000000000ull /* +inf */,
                                          0x7ff8000000000000ull /* NaN */, 0xfff0000000000000ull /* -inf */};
  return slurry::test::mutate(seed, rng, [&](std::string& s, std::size_t at, const auto& pick) {
    const std::uint64_t v = kValues[pick(std::size(kValues))];
    const std::size_t width = rng() % 2 ? 8 : 4;
    if (at + width <= s.size()) std::memcpy(&s[at], &v, width);
  });
}

/// Runs fn(); anything but success or slurry::Error is a finding, reported with the iteration.
template <class Fn>
bool clean(int i, Fn&& fn) {
  try {
    fn();
    return true;
  } catch (const slurry::Error&) {
  } catch (const std::exception& e) {
    ADD_FAILURE() << "iteration " << i << ": unexpected " << typeid(e).name() << ": " << e.what();
  }
  return false;
}

/// Small 2D scenes of the three solvers, each writing a checkpoint at frame 2.
std::string scene_text(const std::string& solver) {
  if (solver == "flip")
    return R"({"domain": {"min": [0, 0], "max": [1, 1], "dx": 0.1},
      "solver": {"type": "flip", "dimension": 2, "transfer": "apic"},
      "materials": [{"name": "water", "model": "fluid"}],
      "bodies": [{"shape": "box", "min": [0.1, 0.1], "max": [0.5, 0.5], "material": "water"}],
      "output": {"directory": "frames", "fps": 24, "frames": 2, "checkpoint_every": 2,
                 "attributes": ["position", "velocity", "id"]}})";
  if (solver == "fem")
    return R"({"domain": {"min": [0, 0], "max": [1, 1], "dx": 0.1},
      "solver": {"type": "fem", "dimension": 2},
      "materials": [{"name": "rubber", "model": "corotated_linear", "E": 1e5, "nu": 0.3}],
      "bodies": [{"shape": "box", "min": [0.3, 0.4], "max": [0.6, 0.6], "material": "rubber"}],
      "output": {"directory": "frames", "fps": 24, "frames": 2, "checkpoint_every": 2,
                 "attributes": ["position", "velocity"]}})";
  return R"({"domain": {"min": [0, 0], "max": [1, 1], "dx": 0.1},
    "solver": {"dimension": 2, "transfer": "mls"},
    "materials": [{"name": "snow", "model": "fixed_corotated", "density": 400, "E": 1e4, "nu": 0.2,
                   "plasticity": "snow"}, {"name": "jelly", "E": 1e4}],
    "bodies": [{"shape": "box", "min": [0.1, 0.1], "max": [0.4, 0.4], "material": "snow"},
               {"shape": "box", "min": [0.5, 0.1], "max": [0.8, 0.3], "material": "jelly"}],
    "output": {"directory": "frames", "fps": 24, "frames": 2, "checkpoint_every": 2,
               "attributes": ["position", "velocity", "J", "plastic", "material"]}})";
}

class CheckpointFuzz : public ::testing::TestWithParam<std::string> {};

// A checkpoint whose payload was altered behind a valid checksum (disk corruption the checksum
// cannot see, a file edited by a tool): the resume refuses it with an error, or loads a state
// that is whole (finite positions inside the domain) and runs on.
TEST_P(CheckpointFuzz, ResumeFromAMutatedPayloadIsCleanOrRefused) {
  const fs::path dir = scratch("checkpoint_" + GetParam());
  write_file(dir / "scene.json", scene_text(GetParam()));
  const slurry::Scene scene = slurry::load_scene(dir / "scene.json");
  slurry::RunOptions quiet;
  quiet.directory = dir / "frames";
  quiet.threads = 1;
  quiet.notice = [](const std::string&) {};
  slurry::run_scene(scene, quiet);
  const fs::path file = slurry::detail::checkpoint_file(dir / "frames", 2);
  const slurry::detail::Checkpoint seed = slurry::detail::read_checkpoint(file);
  const std::string frames_before = slurp(dir / "frames" / "frame_0001.ply");
  std::mt19937_64 rng(21);
  int resumed = 0;
  const int n = iterations(150);
  for (int i = 0; i < n; ++i) {
    const std::string payload = mutate(seed.payload, rng);
    slurry::detail::write_checkpoint(file, seed.scene_hash, seed.frame,
                                     [&](const slurry::detail::PayloadSink& sink) { sink(payload.data(), payload.size()); });
    slurry::RunOptions o = quiet;
    o.resume = true;
    o.frames = 3;
    const bool ok = clean(i, [&] {
      slurry::run_scene(scene, o, [&](const slurry::FrameReport& report) {
        if (!report.frame_data) return;
        for (const char* axis : {"x", "y"})
          for (double v : report.frame_data->table("vertex").column_as_double(axis))
            ASSERT_TRUE(std::isfinite(v) && v >= -0.5 && v <= 1.5) << "iteration " << i << ": " << axis << " = " << v;
      });
    });
    resumed += ok;
    // The frames before the checkpoint are never touched by a resume, whether it ran or not.
    ASSERT_EQ(slurp(dir / "frames" / "frame_0001.ply"), frames_before) << "iteration " << i;
  }
  // Most mutations must be refused (else the fuzzer tests nothing), and the seed must resume.
  EXPECT_LT(resumed, n);
  slurry::detail::write_checkpoint(file, seed.scene_hash, seed.frame,
                                   [&](const slurry::detail::PayloadSink& sink) { sink(seed.payload.data(), seed.payload.size()); });
  slurry::RunOptions o = quiet;
  o.resume = true;
  o.frames = 3;
  EXPECT_NO_THROW(slurry::run_scene(scene, o));
  fs::remove_all(dir);
}

INSTANTIATE_TEST_SUITE_P(Solvers, CheckpointFuzz, ::testing::Values("mpm", "flip", "fem"));

// Per-rank parts altered on disk: merge joins them or refuses with an error naming the file; it
// never crashes, and a refused merge leaves the parts in place.
TEST(MergeFuzz, MutatedPartsAreMergedOrRefused) {
  const fs::path dir = scratch("merge");
  // Two parts of frame 1, written as a run split over two processes writes them.
  const auto part = [&](int rank) {
    std::string text = "ply\nformat binary_little_endian 1.0\ncomment slurry frame t=0.04 source=scene.json\n"
                       "comment slurry part " + std::to_string(rank) + " of 2 id=requested\ncomment slurry run 0000abcd\n"
                       "element vertex 2\nproperty float x\nproperty float y\nproperty uint id\nend_header\n";
    for (std::uint32_t id = std::uint32_t(rank); id < 4; id += 2) {
      const float xy[2] = {float(id), 0.5f};
      text.append(reinterpret_cast<const char*>(xy), sizeof xy);
      text.append(reinterpret_cast<const char*>(&id), sizeof id);
    }
    return text;
  };
  const std::string seeds[2] = {part(0), part(1)};
  write_file(dir / "frame_0001.rank0.ply", seeds[0]);
  write_file(dir / "frame_0001.rank1.ply", seeds[1]);
  ASSERT_EQ(slurry::merge_rank_frames(dir, true).frames, 1);  // the seeds merge
  std::mt19937_64 rng(22);
  int merged = 0;
  const int n = iterations(1500);
  for (int i = 0; i < n; ++i) {
    const int which = i % 2;
    write_file(dir / "frame_0001.rank0.ply", which == 0 ? mutate(seeds[0], rng) : seeds[0]);
    write_file(dir / "frame_0001.rank1.ply", which == 1 ? mutate(seeds[1], rng) : seeds[1]);
    fs::remove(dir / "frame_0001.ply");
    const bool ok = clean(i, [&] { slurry::merge_rank_frames(dir, true); });
    merged += ok;
    if (!ok) {
      EXPECT_TRUE(fs::exists(dir / "frame_0001.rank0.ply") && fs::exists(dir / "frame_0001.rank1.ply")) << i;
    }
  }
  EXPECT_GT(merged, 0);
  EXPECT_LT(merged, n);
  fs::remove_all(dir);
}

}  // namespace
