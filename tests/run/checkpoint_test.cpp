// Checkpoints and resume, and on_instability "retry".
//
// A run stopped (or killed) and resumed from its newest checkpoint writes frames and stats.csv
// byte-identical to an uninterrupted run, for MPM, FLIP (with an emitter: its generator state
// matters) and FEM, on 1 and 2 threads (the resumed half on the other thread count). Corrupt,
// truncated and other-version checkpoints are refused with a message and the previous one is
// used; a changed scene file is refused unless forced. A scene that blows up with "stop"
// finishes with "retry", with the frames before the first retry identical to "stop"'s.
#include <gtest/gtest.h>

#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "slurry/io/checkpoint.h"
#include "slurry/engine/run/run.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"
#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/mpm/mpm_solver.h"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

/// MPM: snow (plasticity, hardening raises the wave speed) and jelly (two materials: the
/// material channel), MLS (the C channel), a moving collider; 2D, coarse.
json mpm_scene() {
  return json::parse(R"({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
    "solver": {"dimension": 2, "transfer": "mls", "kernel": "quadratic", "max_dt": 0.004},
    "materials": [
      {"name": "snow", "model": "fixed_corotated", "density": 400, "E": 1e4, "nu": 0.2, "plasticity": "snow",
       "hardening": 5},
      {"name": "jelly", "model": "fixed_corotated", "density": 1000, "E": 1e4, "nu": 0.3}],
    "bodies": [
      {"shape": "sphere", "center": [0.3, 0.5], "radius": 0.15, "material": "snow", "velocity": [4, 1],
       "particles_per_cell": 4, "sampling": "jittered", "seed": 7},
      {"shape": "box", "min": [0.55, 0.1], "max": [0.8, 0.35], "material": "jelly", "particles_per_cell": 4}],
    "colliders": [{"shape": "box", "min": [0.85, 0.0], "max": [0.95, 0.9], "velocity": [-0.3, 0], "friction": 0.5}],
    "boundaries": {"friction": 0.3},
    "output": {"directory": "frames", "fps": 24, "frames": 7, "checkpoint_every": 3,
               "attributes": ["position", "velocity", "J", "plastic", "material"]}
  })");
}

/// FLIP: an emitter (its random generator and carried fraction), APIC, reseeding.
json flip_scene() {
  return json::parse(R"({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.04},
    "solver": {"type": "flip", "dimension": 2, "transfer": "apic", "kernel": "linear", "cfl": 2, "max_dt": 0.01,
               "reseed": {"min_per_cell": 2}},
    "materials": [{"name": "water", "model": "fluid", "density": 1000}],
    "bodies": [{"shape": "box", "min": [0.0, 0.0], "max": [0.3, 0.4], "material": "water", "particles_per_cell": 4,
                "sampling": "jittered", "seed": 3}],
    "emitters": [{"shape": "box", "min": [0.5, 0.8], "max": [0.62, 0.9], "rate": 0.05, "velocity": [0, -1.0],
                  "material": "water", "particles_per_cell": 4, "seed": 11}],
    "colliders": [{"shape": "sphere", "center": [0.6, 0.3], "radius": 0.1}],
    "output": {"directory": "frames", "fps": 24, "frames": 7, "checkpoint_every": 3,
               "attributes": ["position", "velocity", "id"]}
  })");
}

/// FEM: a clamped beam, explicit.
json fem_scene() {
  return json::parse(R"({
    "domain": {"min": [0, 0], "max": [1, 0.6], "dx": 0.04},
    "solver": {"type": "fem", "dimension": 2, "precision": "double", "max_dt": 0.001},
    "materials": [{"name": "rubber", "model": "corotated_linear", "density": 1000, "E": 1e6, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.1, 0.4], "max": [0.9, 0.48], "material": "rubber"}],
    "colliders": [{"shape": "box", "min": [0.0, 0.3], "max": [0.105, 0.6], "condition": "sticky"}],
    "output": {"directory": "frames", "fps": 24, "frames": 7, "checkpoint_every": 3,
               "attributes": ["position", "velocity", "J"]}
  })");
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

/// A scratch directory per test, emptied first.
fs::path scratch(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("slurry_checkpoint_" + std::to_string(::getpid())) / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

/// Writes the scene file and loads it (so that its hash is that of the file's bytes).
slurry::Scene write_scene(const fs::path& file, const json& j) {
  std::ofstream(file) << j.dump(2);
  return slurry::load_scene(file);
}

struct Outcome {
  slurry::RunSummary summary;
  std::vector<std::string> notices;
};

Outcome run(const slurry::Scene& scene, const fs::path& out, int frames, int threads,
            bool resume = false, bool force = false) {
  Outcome r;
  slurry::RunOptions o;
  o.directory = out;
  o.frames = frames;
  o.threads = threads;
  o.resume = resume;
  o.force = force;
  o.notice = [&](const std::string& line) { r.notices.push_back(line); };
  r.summary = slurry::run_scene(scene, o);
  return r;
}

std::string joined(const std::vector<std::string>& lines) {
  std::string s;
  for (const auto& l : lines) s += l + "\n";
  return s;
}

/// Frames 0..last and stats.csv of b are byte-identical to a's, and b holds no later frame.
void expect_same_frames(const fs::path& a, const fs::path& b, int last) {
  for (int f = 0; f <= last; ++f) {
    const auto fa = slurry::frame_file(a, f), fb = slurry::frame_file(b, f);
    ASSERT_TRUE(fs::exists(fa)) << fa;
    ASSERT_TRUE(fs::exists(fb)) << fb;
    EXPECT_TRUE(slurp(fa) == slurp(fb)) << "frame " << f << " differs: " << fa << " vs " << fb;
  }
  EXPECT_FALSE(fs::exists(slurry::frame_file(b, last + 1)));
  EXPECT_EQ(slurp(a / "stats.csv"), slurp(b / "stats.csv"));
}

fs::path checkpoint(const fs::path& dir, int frame) {
  char name[32];
  std::snprintf(name, sizeof name, "checkpoint_%04d.slc", frame);
  return dir / name;
}

// --- Resume is byte-identical, per solver and thread count. ---

struct ResumeCase {
  const char* name;
  json (*scene)();
  int threads;  // of the uninterrupted run and the first half; the resumed half uses the other
                // count
};

void PrintTo(const ResumeCase& c, std::ostream* os) {
  *os << c.name;
}

class Resume : public ::testing::TestWithParam<ResumeCase> {};

TEST_P(Resume, FramesAndStatsAreByteIdenticalToAnUninterruptedRun) {
  const auto& c = GetParam();
  const fs::path dir = scratch(std::string("resume_") + c.name);
  const auto scene = write_scene(dir / "scene.json", c.scene());
  const int other = 3 - c.threads;
  run(scene, dir / "whole", 7, c.threads);
  // The first part stops after frame 5; checkpoints every 3 frames: only frame 3's exists.
  run(scene, dir / "parts", 5, c.threads);
  EXPECT_TRUE(fs::exists(checkpoint(dir / "parts", 3)));
  EXPECT_FALSE(fs::exists(checkpoint(dir / "parts", 5)));
  const Outcome resumed = run(scene, dir / "parts", 7, other, true);
  EXPECT_EQ(resumed.summary.resumed_from, 3);
  EXPECT_EQ(resumed.summary.frames_written, 8);
  EXPECT_NE(joined(resumed.notices).find("resuming from"), std::string::npos)
      << joined(resumed.notices);
  // Frames 4 and 5 of the first part are written again, then 6 and 7.
  expect_same_frames(dir / "whole", dir / "parts", 7);
  EXPECT_TRUE(fs::exists(checkpoint(dir / "parts", 6)));
  // Resuming a run that is complete writes nothing new and changes nothing.
  const std::string before = slurp(slurry::frame_file(dir / "parts", 7));
  run(scene, dir / "parts", 7, c.threads, true);
  EXPECT_EQ(slurp(slurry::frame_file(dir / "parts", 7)), before);
}

INSTANTIATE_TEST_SUITE_P(
    Solvers, Resume,
    ::testing::Values(ResumeCase{"mpm_1", mpm_scene, 1}, ResumeCase{"mpm_2", mpm_scene, 2},
                      ResumeCase{"flip_1", flip_scene, 1}, ResumeCase{"flip_2", flip_scene, 2},
                      ResumeCase{"fem_1", fem_scene, 1}, ResumeCase{"fem_2", fem_scene, 2}),
    [](const auto& info) { return std::string(info.param.name); });

// A SIGINT-style stop (RunOptions::stop) leaves a checkpoint of the frame it stopped after.
TEST(Checkpoint, StoppedRunLeavesACheckpointOfItsLastFrame) {
  const fs::path dir = scratch("stop");
  const auto scene = write_scene(dir / "scene.json", mpm_scene());
  run(scene, dir / "whole", 7, 1);
  volatile std::sig_atomic_t stop = 0;
  slurry::RunOptions o;
  o.directory = dir / "parts";
  o.threads = 1;
  o.stop = &stop;
  const auto s = slurry::run_scene(scene, o, [&](const slurry::FrameReport& r) {
    if (r.frame == 4) stop = SIGINT;
  });
  EXPECT_EQ(s.interrupted, SIGINT);
  EXPECT_TRUE(fs::exists(checkpoint(dir / "parts", 4)));
  EXPECT_EQ(run(scene, dir / "parts", 7, 1, true).summary.resumed_from, 4);
  expect_same_frames(dir / "whole", dir / "parts", 7);
}

// --- Refused checkpoints. ---

enum class Damage { Flip, Truncate, Version, Empty };

void damage(const fs::path& file, Damage d) {
  std::string bytes = slurp(file);
  switch (d) {
    case Damage::Flip:
      bytes[bytes.size() / 2] ^= 0x10;
      break;
    case Damage::Truncate:
      bytes.resize(bytes.size() - 100);
      break;
    case Damage::Version:
      bytes[8] = 99;
      break;  // the format version field
    case Damage::Empty:
      bytes.clear();
      break;
  }
  std::ofstream(file, std::ios::binary | std::ios::trunc) << bytes;
}

TEST(Checkpoint, CorruptTruncatedOrOtherVersionIsRefusedAndThePreviousOneUsed) {
  const fs::path dir = scratch("corrupt");
  auto j = mpm_scene();
  j["output"]["checkpoint_every"] = 2;
  const auto scene = write_scene(dir / "scene.json", j);
  run(scene, dir / "whole", 8, 1);
  run(scene, dir / "base", 6, 1);
  // The last two are kept.
  EXPECT_FALSE(fs::exists(checkpoint(dir / "base", 2)));
  EXPECT_TRUE(fs::exists(checkpoint(dir / "base", 4)));
  EXPECT_TRUE(fs::exists(checkpoint(dir / "base", 6)));
  const std::pair<Damage, const char*> cases[] = {{Damage::Flip, "checksum mismatch"},
                                                  {Damage::Truncate, "truncated"},
                                                  {Damage::Version, "checkpoint format version 99"},
                                                  {Damage::Empty, "truncated: 0 bytes"}};
  for (const auto& [kind, message] : cases) {
    SCOPED_TRACE(message);
    const fs::path out = dir / "damaged";
    fs::remove_all(out);
    fs::copy(dir / "base", out, fs::copy_options::recursive);
    damage(checkpoint(out, 6), kind);
    const Outcome r = run(scene, out, 8, 1, true);
    const std::string log = joined(r.notices);
    EXPECT_NE(log.find("refused checkpoint " + checkpoint(out, 6).string() + ": " + message),
              std::string::npos)
        << log;
    EXPECT_NE(log.find("using an earlier one"), std::string::npos) << log;
    EXPECT_EQ(r.summary.resumed_from, 4);
    expect_same_frames(dir / "whole", out, 8);
  }
  // Both damaged: nothing to resume from, and the reasons are named.
  const fs::path out = dir / "both";
  fs::copy(dir / "base", out, fs::copy_options::recursive);
  damage(checkpoint(out, 6), Damage::Flip);
  damage(checkpoint(out, 4), Damage::Truncate);
  try {
    run(scene, out, 8, 1, true);
    ADD_FAILURE() << "resumed from damaged checkpoints";
  } catch (const slurry::IoError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("no valid checkpoint to resume from"), std::string::npos) << m;
    EXPECT_NE(m.find("checksum mismatch"), std::string::npos) << m;
    EXPECT_NE(m.find("truncated"), std::string::npos) << m;
  }
  // A directory without checkpoints.
  EXPECT_THROW(run(scene, dir / "none", 8, 1, true), slurry::IoError);
}

// A checkpoint streamed in small and large pieces (through the writer's buffer and around it)
// is the file the payload handed over in one piece writes, and reads back; a producer that fails midway leaves neither the checkpoint
// nor its temporary file.
TEST(Checkpoint, StreamedFileEqualsTheWholePayloadsAndAFailedOneLeavesNothing) {
  const fs::path dir = fs::temp_directory_path() / ("slurry_ckpt_stream_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::string payload(3'500'000, '\0');  // pieces below, at and above the 1 MiB buffer
  for (std::size_t i = 0; i < payload.size(); ++i) payload[i] = char((i * 2654435761u) >> 13);
  const std::size_t pieces[] = {1, 7, 1u << 20, 5, (1u << 20) + 3, 1000, 2000};
  slurry::detail::write_checkpoint(dir / "whole.slc", 42, 3, [&](const slurry::detail::PayloadSink& sink) {
    sink(payload.data(), payload.size());
  });
  slurry::detail::write_checkpoint(dir / "streamed.slc", 42, 3, [&](const slurry::detail::PayloadSink& sink) {
    std::size_t at = 0;
    for (std::size_t k = 0; at < payload.size(); ++k) {
      const std::size_t n = std::min(pieces[k % 7], payload.size() - at);
      sink(payload.data() + at, n);
      at += n;
    }
  });
  const auto bytes = [](const fs::path& f) {
    std::ifstream in(f, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  };
  EXPECT_EQ(bytes(dir / "whole.slc"), bytes(dir / "streamed.slc"));
  const auto c = slurry::detail::read_checkpoint(dir / "streamed.slc");
  EXPECT_EQ(c.frame, 3);
  EXPECT_EQ(c.scene_hash, 42u);
  EXPECT_TRUE(c.payload == payload);

  EXPECT_THROW(slurry::detail::write_checkpoint(dir / "failed.slc", 42, 4,
                                                [&](const slurry::detail::PayloadSink& sink) {
                                                  sink(payload.data(), 2'000'000);
                                                  throw slurry::IoError("the gather failed");
                                                }),
               slurry::IoError);
  int files = 0;
  for (const auto& e : fs::directory_iterator(dir)) files += e.path().filename().string().rfind("failed", 0) == 0;
  EXPECT_EQ(files, 0) << "a failed checkpoint left a file";
  fs::remove_all(dir);
}

// A checkpoint in parts (output.per_rank, one file per process) is listed by its part 0 once
// every rank from 0 up is present, and names all its parts; an incomplete set is no checkpoint.
TEST(Checkpoint, PartsAreListedAsOneCheckpointWhenComplete) {
  namespace d = slurry::detail;
  const fs::path dir = fs::temp_directory_path() / ("slurry_ckpt_parts_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const auto touch = [](const fs::path& f) { std::ofstream(f) << "x"; };
  touch(d::checkpoint_file(dir, 2));
  for (int r = 0; r < 3; ++r) touch(d::checkpoint_part_file(dir, 3, r));
  touch(d::checkpoint_part_file(dir, 4, 0));  // rank 1 missing
  touch(d::checkpoint_part_file(dir, 4, 2));
  touch(d::checkpoint_part_file(dir, 5, 1));  // no rank 0
  EXPECT_EQ(d::checkpoint_part_file(dir, 3, 1).filename().string(), "checkpoint_0003.rank1.slc");
  const auto list = d::list_checkpoints(dir);
  ASSERT_EQ(list.size(), 2u);
  EXPECT_EQ(list[0].first, 2);
  EXPECT_EQ(list[0].second, d::checkpoint_file(dir, 2));
  EXPECT_EQ(list[1].first, 3);
  EXPECT_EQ(list[1].second, d::checkpoint_part_file(dir, 3, 0));
  const auto parts = d::checkpoint_parts(list[1].second);
  ASSERT_EQ(parts.size(), 3u);
  for (int r = 0; r < 3; ++r) EXPECT_EQ(parts[std::size_t(r)], d::checkpoint_part_file(dir, 3, r));
  EXPECT_EQ(d::checkpoint_parts(list[0].second), std::vector<fs::path>{d::checkpoint_file(dir, 2)});
  fs::remove_all(dir);
}

// A FIFO where a checkpoint is expected is refused at once (reading it would block forever), and
// the resume falls back to the checkpoint before it.
TEST(Checkpoint, FifoIsRefusedAndThePreviousOneUsed) {
  const fs::path dir = scratch("fifo");
  const auto scene = write_scene(dir / "a.json", mpm_scene());
  run(scene, dir / "frames", 6, 1);
  const fs::path newest = checkpoint(dir / "frames", 6);
  ASSERT_TRUE(fs::exists(newest));
  fs::remove(newest);
  ASSERT_EQ(::mkfifo(newest.c_str(), 0600), 0);
  try {
    slurry::detail::read_checkpoint(newest);
    ADD_FAILURE() << "a FIFO was read as a checkpoint";
  } catch (const slurry::IoError& e) {
    EXPECT_NE(std::string(e.what()).find(newest.string() + ": a FIFO (named pipe), not a regular file (expected a "
                                                           "slurry checkpoint)"),
              std::string::npos)
        << e.what();
  }
  const Outcome r = run(scene, dir / "frames", 6, 1, /*resume=*/true);
  EXPECT_EQ(r.summary.resumed_from, 3);
  EXPECT_NE(joined(r.notices).find("a FIFO (named pipe)"), std::string::npos) << joined(r.notices);
}

// A checkpoint is untrusted input however valid its checksum: a state whose positions, ids or
// values were altered is refused with a message naming the particle (a position outside the grid
// or a repeated id ended in SIGSEGV), and the unaltered state loads.
template <class Sim, class Change>
std::string altered_state_error(const slurry::Scene& scene, Change change) {
  Sim a(scene);
  a.step(a.stable_dt());
  change(a.particles());
  std::string state;
  a.save_state(state);
  Sim b(scene);
  try {
    b.load_state(state, "altered.slc");
  } catch (const slurry::IoError& e) {
    return e.what();
  }
  return "";
}

TEST(Checkpoint, AlteredStateIsRefusedNamingTheParticle) {
  const auto mpm = slurry::parse_scene(mpm_scene().dump(), "mpm.json");
  using Mpm = slurry::MpmSolver<float, 2>;
  const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
  EXPECT_EQ(altered_state_error<Mpm>(mpm, [](auto&) {}), "");
  EXPECT_NE(altered_state_error<Mpm>(mpm, [&](auto& P) { P.x[5][0] = nan; })
                .find("altered.slc: the solver state does not fit this scene: the position of particle 5 is not "
                      "finite or lies outside the grid"),
            std::string::npos);
  EXPECT_NE(altered_state_error<Mpm>(mpm, [](auto& P) { P.x[6][1] = 1e6f; }).find("the position of particle 6"),
            std::string::npos);
  EXPECT_NE(altered_state_error<Mpm>(mpm, [](auto& P) { P.id[7] = P.id[8]; }).find("is held by more than one particle"),
            std::string::npos);
  EXPECT_NE(altered_state_error<Mpm>(mpm, [](auto& P) { P.id[7] = 4000000000u; })
                .find("the id 4000000000 of particle 7 is not below"),
            std::string::npos);
  EXPECT_NE(altered_state_error<Mpm>(mpm, [&](auto& P) { P.v[2][1] = inf; }).find("the velocity of particle 2 is not finite"),
            std::string::npos);
  EXPECT_NE(altered_state_error<Mpm>(mpm, [&](auto& P) { P.F[3](0, 1) = nan; }).find("F of particle 3 is not finite"),
            std::string::npos);

  const auto flip = slurry::parse_scene(flip_scene().dump(), "flip.json");
  using Flip = slurry::flip::FlipSolver<float, 2>;
  EXPECT_EQ(altered_state_error<Flip>(flip, [](auto&) {}), "");
  EXPECT_NE(altered_state_error<Flip>(flip, [](auto& P) { P.x[4][0] = -3.0f; }).find("the position of particle 4"),
            std::string::npos);
  EXPECT_NE(altered_state_error<Flip>(flip, [](auto& P) { P.id[1] = P.id[0]; }).find("is held by more than one particle"),
            std::string::npos);
  EXPECT_NE(altered_state_error<Flip>(flip, [](auto& P) { P.id[1] = P.next_id; }).find("is not below"),
            std::string::npos);
}

TEST(Checkpoint, OtherSolverLayoutIsRefused) {
  // A checkpoint of the MPM scene offered to the FEM scene (same file name, forced past the
  // hash): the layout check names the mismatch, and nothing else fits.
  const fs::path dir = scratch("layout");
  const auto mpm = write_scene(dir / "scene.json", mpm_scene());
  run(mpm, dir / "frames", 3, 1);
  const auto fem = write_scene(dir / "scene.json", fem_scene());
  try {
    run(fem, dir / "frames", 7, 1, true, true);
    ADD_FAILURE() << "resumed an MPM checkpoint in an FEM run";
  } catch (const slurry::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("expected the FEM section"), std::string::npos)
        << e.what();
  }
}

TEST(Checkpoint, ChangedSceneIsRefusedUnlessForced) {
  const fs::path dir = scratch("changed");
  auto j = mpm_scene();
  const auto scene = write_scene(dir / "scene.json", j);
  run(scene, dir / "frames", 4, 1);
  j["materials"][1]["E"] = 6e4;
  const auto changed = write_scene(dir / "scene.json", j);
  try {
    run(changed, dir / "frames", 7, 1, true);
    ADD_FAILURE() << "resumed a changed scene";
  } catch (const slurry::SceneError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("the scene file changed"), std::string::npos) << m;
    EXPECT_NE(m.find("--force"), std::string::npos) << m;
  }
  const Outcome forced = run(changed, dir / "frames", 7, 1, true, true);
  EXPECT_EQ(forced.summary.resumed_from, 3);
  EXPECT_TRUE(fs::exists(slurry::frame_file(dir / "frames", 7)));
}

TEST(Checkpoint, SceneKeysAreValidated) {
  auto j = mpm_scene();
  j["output"]["checkpoint_every"] = -1;
  EXPECT_THROW(slurry::parse_scene(j.dump(), "s.json"), slurry::SceneError);
  j = mpm_scene();
  j["solver"]["on_instability"] = "pray";
  try {
    slurry::parse_scene(j.dump(), "s.json");
    ADD_FAILURE();
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("s.json: solver.on_instability"), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("\"retry\""), std::string::npos) << e.what();
  }
  j = mpm_scene();
  j["solver"]["max_retries"] = 0;
  EXPECT_THROW(slurry::parse_scene(j.dump(), "s.json"), slurry::SceneError);
  // The hash is the scene text's: any edit changes it.
  EXPECT_NE(slurry::parse_scene(mpm_scene().dump(), "s.json").source_hash,
            slurry::parse_scene(mpm_scene().dump(1), "s.json").source_hash);
}

// --- on_instability "retry". ---

/// A jelly block hit by a sphere collider at 15 m/s at t = 0.15 s (frame 4): the substep, set
/// by the elastic limit while the block rests, lets the struck particles move 1.6 cells in
/// one substep, which the health check refuses (limit 1 cell at cfl 0.5).
json struck_scene(const char* on_instability) {
  json j = json::parse(R"({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
    "solver": {"dimension": 2, "transfer": "mls", "max_dt": 0.01},
    "materials": [{"name": "jelly", "model": "fixed_corotated", "density": 1000, "E": 1e4, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.4, 0.05], "max": [0.7, 0.3], "material": "jelly", "particles_per_cell": 4}],
    "colliders": [{"shape": "sphere", "center": [-1.95, 0.15], "radius": 0.1, "velocity": [15, 0]}],
    "output": {"directory": "frames", "fps": 24, "frames": 10, "checkpoint_every": 0, "attributes": ["position", "velocity"]}
  })");
  j["solver"]["on_instability"] = on_instability;
  return j;
}

TEST(Retry, SceneThatStopsFinishesWithRetryAndEarlierFramesAreIdentical) {
  const fs::path dir = scratch("retry");
  // The same scene file name for both runs: frames name their source.
  const auto stop = write_scene(dir / "scene.json", struck_scene("stop"));
  try {
    run(stop, dir / "stop", 10, 1);
    ADD_FAILURE() << "the struck block was expected to become unstable with \"stop\"";
  } catch (const slurry::SimulationError& e) {
    EXPECT_NE(std::string(e.what()).find("CFL violation"), std::string::npos) << e.what();
  }
  int good = 0;  // frames "stop" wrote
  while (fs::exists(slurry::frame_file(dir / "stop", good))) ++good;
  ASSERT_GE(good, 3);
  ASSERT_LT(good, 10);
  const auto retry = write_scene(dir / "scene.json", struck_scene("retry"));
  const Outcome r = run(retry, dir / "retry", 10, 1);
  EXPECT_EQ(r.summary.frames_written, 11);
  EXPECT_GE(r.summary.retries, 1);
  const std::string log = joined(r.notices);
  EXPECT_NE(log.find("retry 1 of 3: frame " + std::to_string(good) + " redone from t = "),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("with the substep x 0.5 after: "), std::string::npos) << log;
  for (int f = 0; f < good; ++f)
    EXPECT_TRUE(slurp(slurry::frame_file(dir / "stop", f)) ==
                slurp(slurry::frame_file(dir / "retry", f)))
        << f;
  // Every later frame is written (the health check passed every substep after the retry).
  for (int f = good; f <= 10; ++f) EXPECT_TRUE(fs::exists(slurry::frame_file(dir / "retry", f)));
  // Fewer halvings than needed: the run stops, naming the retries.
  auto j = struck_scene("retry");
  j["colliders"][0]["velocity"] = {60, 0};
  j["colliders"][0]["center"] = {0.3 - 60 * 0.15, 0.15};
  j["solver"]["max_retries"] = 1;
  const auto hopeless = write_scene(dir / "scene.json", j);
  try {
    run(hopeless, dir / "hopeless", 10, 1);
    ADD_FAILURE() << "a collider at 60 m/s was expected to need more than one halving";
  } catch (const slurry::SimulationError& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "still unstable after 1 retries with the substep halved (solver.max_retries)"),
              std::string::npos)
        << e.what();
  }
}

TEST(Retry, WithoutInstabilityFramesEqualStop) {
  const fs::path dir = scratch("retry_quiet");
  auto j = mpm_scene();
  run(write_scene(dir / "scene.json", j), dir / "stop", 4, 1);
  j["solver"]["on_instability"] = "retry";
  const Outcome r = run(write_scene(dir / "scene.json", j), dir / "retry", 4, 1);
  EXPECT_EQ(r.summary.retries, 0);
  EXPECT_TRUE(r.notices.empty()) << joined(r.notices);
  expect_same_frames(dir / "stop", dir / "retry", 4);
}

#ifdef SLURRY_CLI
struct Result {
  int code = -1;
  std::string err;
};

Result cli(const fs::path& dir, const std::string& args) {
  const std::string cmd = "cd '" + dir.string() + "' && '" + std::string(SLURRY_CLI) + "' " + args +
                          " > out.txt 2> err.txt";
  const int status = std::system(cmd.c_str());
  Result r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  r.err = slurp(dir / "err.txt");
  return r;
}

// SIGKILL at some moment after a checkpoint (no chance to finish a frame or clean up), then
// `slurry resume DIR`: the frames equal an uninterrupted run's, byte for byte.
TEST(CheckpointCli, KilledRunResumesByteIdentical) {
  const fs::path dir = scratch("kill");
  auto j = mpm_scene();
  j["output"]["frames"] = 60;
  j["output"]["checkpoint_every"] = 5;
  std::ofstream(dir / "a.json") << j.dump(2);
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    if (::chdir(dir.c_str()) != 0) ::_exit(99);
    if (!std::freopen("out1.txt", "w", stdout) || !std::freopen("err1.txt", "w", stderr))
      ::_exit(98);
    ::execl(SLURRY_CLI, SLURRY_CLI, "run", "-q", "a.json", "--threads", "2",
            static_cast<char*>(nullptr));
    ::_exit(97);
  }
  // Wait (without a time limit: ctest's timeout is the backstop) for the second checkpoint,
  // unless the run ends first (it should not: 50 frames are left).
  int status = 0;
  pid_t done = 0;
  while (!fs::exists(checkpoint(dir / "frames", 10)) &&
         (done = ::waitpid(pid, &status, WNOHANG)) == 0)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ASSERT_EQ(done, 0) << "the run ended before its second checkpoint: " << slurp(dir / "err1.txt");
  ::kill(pid, SIGKILL);
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the run finished before it was killed";
  EXPECT_FALSE(fs::exists(slurry::frame_file(dir / "frames", 60)));
  const Result r = cli(dir, "resume -q frames --threads 1");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("slurry: resuming from frames/checkpoint_"), std::string::npos) << r.err;
  const Result whole = cli(dir, "run -q a.json --out whole --threads 1");
  ASSERT_EQ(whole.code, 0) << whole.err;
  expect_same_frames(dir / "whole", dir / "frames", 60);
  for (const auto& e : fs::directory_iterator(dir / "frames"))
    EXPECT_EQ(e.path().string().find(".tmp-"), std::string::npos) << "left behind: " << e.path();
}

// A resume runs to the last frame the run was started with (the checkpoint records it) unless
// --frames says otherwise, and never removes a frame it will not write again: a --frames below
// the frames on disk is an error that leaves every file in place.
TEST(CheckpointCli, ResumeKeepsTheRunsFrameCountAndNeverRemovesFrames) {
  const fs::path dir = scratch("cli_frames");
  auto j = mpm_scene();
  j["output"]["frames"] = 4;  // checkpoint_every 3
  std::ofstream(dir / "a.json") << j.dump(2);
  ASSERT_EQ(cli(dir, "run -q a.json --frames 7 --threads 1").code, 0);
  const fs::path frames = dir / "frames";
  std::vector<std::string> before;
  for (int f = 0; f <= 7; ++f) before.push_back(slurp(slurry::frame_file(frames, f)));
  ASSERT_TRUE(fs::exists(checkpoint(frames, 6)));
  // Asked for fewer frames than the directory holds: refused, nothing removed.
  Result r = cli(dir, "resume -q frames --frames 4 --threads 1");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("checkpoint_0006.slc: frame 6 lies beyond the run's last frame 4 (--frames); nothing was "
                       "removed; expected --frames 6 or more"),
            std::string::npos)
      << r.err;
  for (int f = 0; f <= 7; ++f) EXPECT_EQ(slurp(slurry::frame_file(frames, f)), before[std::size_t(f)]) << f;
  EXPECT_TRUE(fs::exists(checkpoint(frames, 6)));
  // Frame 7 is beyond --frames 6 although checkpoint 6 is not: refused too.
  r = cli(dir, "resume -q frames --frames 6 --threads 1");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("holds frame 7, beyond the run's last frame 6 (--frames); nothing was removed"),
            std::string::npos)
      << r.err;
  EXPECT_EQ(slurp(slurry::frame_file(frames, 7)), before[7]);
  // Without --frames: the run's own last frame, 7, not the scene's 4. Frame 7 is written again
  // from checkpoint 6, the same bytes.
  r = cli(dir, "resume -q frames --threads 1");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("resuming from frames/checkpoint_0006.slc"), std::string::npos) << r.err;
  for (int f = 0; f <= 7; ++f) EXPECT_EQ(slurp(slurry::frame_file(frames, f)), before[std::size_t(f)]) << f;
  EXPECT_FALSE(fs::exists(slurry::frame_file(frames, 8)));
}

// A frame before the checkpoint that was cut off (a copy interrupted, a disk filled by another
// program) is kept by a resume, so it refuses that checkpoint; with none left, the resume stops
// with the damaged frame named and nothing removed.
TEST(CheckpointCli, DamagedFrameBeforeTheCheckpointRefusesIt) {
  const fs::path dir = scratch("cli_damaged");
  auto j = mpm_scene();
  j["output"]["checkpoint_every"] = 2;
  std::ofstream(dir / "a.json") << j.dump(2);
  ASSERT_EQ(cli(dir, "run -q a.json --frames 6 --threads 1").code, 0);
  const fs::path frames = dir / "frames";
  ASSERT_TRUE(fs::exists(checkpoint(frames, 4)));
  ASSERT_TRUE(fs::exists(checkpoint(frames, 6)));
  // Frame 5 cut off: checkpoint 6 is refused, checkpoint 4 used, frames 5 and 6 written again.
  std::vector<std::string> before;
  for (int f = 0; f <= 6; ++f) before.push_back(slurp(slurry::frame_file(frames, f)));
  fs::resize_file(slurry::frame_file(frames, 5), before[5].size() - 7);
  Result r = cli(dir, "resume -q frames --threads 1");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("frame_0005.ply before it is damaged"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("truncated: the file has " + std::to_string(before[5].size() - 7) + " bytes"), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("resuming from frames/checkpoint_0004.slc"), std::string::npos) << r.err;
  for (int f = 0; f <= 6; ++f) EXPECT_EQ(slurp(slurry::frame_file(frames, f)), before[std::size_t(f)]) << f;
  // Frame 1 cut off, before both checkpoints: no checkpoint left, an error naming the frame, and
  // every file kept.
  fs::resize_file(slurry::frame_file(frames, 1), before[1].size() / 2);
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(frames)) files.push_back(e.path());
  r = cli(dir, "resume -q frames --threads 1");
  EXPECT_EQ(r.code, 3) << r.err;
  EXPECT_NE(r.err.find("no valid checkpoint to resume from"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("frame_0001.ply before it is damaged"), std::string::npos) << r.err;
  for (const auto& file : files) EXPECT_TRUE(fs::exists(file)) << file;
  EXPECT_EQ(fs::file_size(slurry::frame_file(frames, 1)), before[1].size() / 2);
}

// Resuming a finished run does nothing and says so; its summary compares the last frame with
// the first (not an empty state: "mass -100%").
TEST(CheckpointCli, ResumingAFinishedRunSaysItIsComplete) {
  const fs::path dir = scratch("cli_finished");
  std::ofstream(dir / "a.json") << mpm_scene().dump(2);
  ASSERT_EQ(cli(dir, "run -q a.json --frames 6 --threads 1").code, 0);
  const std::string run_out = slurp(dir / "out.txt");
  const Result r = cli(dir, "resume -q frames --threads 1");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("the run is already complete"), std::string::npos) << r.err;
  const std::string out = slurp(dir / "out.txt");
  EXPECT_NE(out.find("stats: mass +0%"), std::string::npos) << out;
  EXPECT_EQ(out.find("-100%"), std::string::npos) << out;
  EXPECT_TRUE(fs::exists(slurry::frame_file(dir / "frames", 6)));
  EXPECT_NE(run_out.find("done: 7 frames"), std::string::npos) << run_out;
  EXPECT_NE(out.find("done: 7 frames"), std::string::npos) << out;
}

// A changed output.fps, even with --force, would put the resumed frames at the wrong times
// (every later frame written at once, with no substep): refused.
TEST(CheckpointCli, ChangedFrameRateIsRefusedEvenWithForce) {
  const fs::path dir = scratch("cli_fps");
  auto j = mpm_scene();
  std::ofstream(dir / "a.json") << j.dump(2);
  ASSERT_EQ(cli(dir, "run -q a.json --frames 4 --threads 1").code, 0);
  j["output"]["fps"] = 48;
  std::ofstream(dir / "a.json") << j.dump(2);
  const Result r = cli(dir, "run -q a.json --resume --force --frames 8 --threads 1");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("expected the output.fps the run was started with"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(slurry::frame_file(dir / "frames", 5)));
}

TEST(CheckpointCli, ChangedSceneNeedsForceAndUsageErrors) {
  const fs::path dir = scratch("cli_changed");
  auto j = mpm_scene();
  std::ofstream(dir / "a.json") << j.dump(2);
  ASSERT_EQ(cli(dir, "run -q a.json --frames 4 --threads 1").code, 0);
  j["solver"]["gravity"] = {0, -5};
  std::ofstream(dir / "a.json") << j.dump(2);
  Result r = cli(dir, "run -q a.json --resume --threads 1");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("a.json: the scene file changed since its checkpoints"), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("pass --force"), std::string::npos) << r.err;
  r = cli(dir, "run -q a.json --resume --force --threads 1 --frames 7");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir / "frames" / "frame_0007.ply"));
  r = cli(dir, "run -q a.json --force");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--force: only with --resume"), std::string::npos) << r.err;
  r = cli(dir, "resume -q nowhere");
  EXPECT_EQ(r.code, 3);
  EXPECT_NE(r.err.find("nowhere: no readable checkpoint"), std::string::npos) << r.err;
}
#endif

}  // namespace
