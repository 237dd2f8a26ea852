// Bad input as a new user gives it, one regression test per case: the CLI's exit code (2 bad
// scene or usage, 3 file or resource error), a fragment of its one-line message (file, field or
// argument, what was expected), and that a run failing before its first frame creates nothing.
// Then the output directory (another scene's frames, --overwrite, stale temporary files) and an
// interrupted run (SIGINT: the frame finishes, the summary is printed, exit 130).
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>
#include <algorithm>
#include <cctype>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

#include "slurry/engine/run/run.h"
#include "slurry/engine/scene/scene.h"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

const char* const kGood = R"({
  "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
  "solver": {"dimension": 2, "transfer": "apic", "kernel": "quadratic"},
  "materials": [{"name": "jelly", "model": "fixed_corotated", "density": 1000, "E": 1e5, "nu": 0.3}],
  "bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "jelly"}],
  "output": {"directory": "frames", "fps": 24, "frames": 2}
})";

std::string patched(const char* patch) {
  json j = json::parse(kGood);
  j.merge_patch(json::parse(patch));
  return j.dump();
}

/// kGood with one piece of its text replaced (for inputs nlohmann::json cannot build).
std::string replaced(const std::string& from, const std::string& to) {
  std::string s = kGood;
  return s.replace(s.find(from), from.size(), to);
}

std::string body(const char* extra) {
  return std::string(
             R"({"bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "jelly")") +
         extra + "}]}";
}

std::string nested(const std::string& open, const std::string& close, int depth) {
  std::string s;
  for (int i = 0; i < depth; ++i) s += open;
  for (int i = 0; i < depth; ++i) s += close;
  return s;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

/// A scratch directory per test, emptied first.
fs::path scratch(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("slurry_bad_input_" + std::to_string(::getpid())) / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

struct Result {
  int code = -1;
  std::string out, err;
};

/// Runs the CLI in `dir` (so that the scenes' "frames" directory lands there).
Result cli(const fs::path& dir, const std::string& args) {
  const std::string cmd = "cd '" + dir.string() + "' && '" + std::string(SLURRY_CLI) + "' " + args +
                          " > out.txt 2> err.txt";
  const int status = std::system(cmd.c_str());
  Result r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  r.out = slurp(dir / "out.txt");
  r.err = slurp(dir / "err.txt");
  return r;
}

/// The exit code and a fragment of stderr.
void expect_exit(const Result& r, int code, const std::string& fragment) {
  EXPECT_EQ(r.code, code) << r.err;
  EXPECT_NE(r.err.find(fragment), std::string::npos)
      << "stderr: " << r.err << "\nexpected: " << fragment;
}

struct Case {
  const char* name;
  std::string scene;  // written to scene.json ("" = none)
  std::string args;   // after the program name
  int code;
  std::string message;  // a fragment of stderr
};

std::vector<Case> cases() {
  const std::string ball_scene = R"({
    "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.1},
    "solver": {"type": "fem", "dimension": 3},
    "materials": [{"name": "jelly", "model": "corotated_linear", "E": 1e5, "nu": 0.3}],
    "bodies": [{"mesh": "m", "material": "jelly"}]
  })";
  return {
      // Crashes.
      {"deep_top_level", nested("[", "]", 100000), "run scene.json", 2, "scene.json: [0][0][0]"},
      {"deep_top_level_message", nested("[", "]", 100000), "run scene.json", 2,
       "nested deeper than 64 levels"},
      {"deep_domain",
       replaced(R"({"min": [0, 0], "max": [1, 1], "dx": 0.05})", nested("[", "]", 100000)),
       "run scene.json", 2, "scene.json: domain[0][0]"},
      {"dx_1e400", replaced("\"dx\": 0.05", "\"dx\": 1e400"), "run scene.json", 2,
       "scene.json: domain.dx: number '1e400' is out of the range of double"},
      {"velocity_1e400",
       replaced("\"material\": \"jelly\"}]", "\"material\": \"jelly\", \"velocity\": [0, 1e400]}]"),
       "run scene.json", 2,
       "scene.json: bodies[0].velocity[1]: number '1e400' is out of the range of double"},
      {"gravity_1e400",
       replaced("\"kernel\": \"quadratic\"", "\"kernel\": \"quadratic\", \"gravity\": [-1e400, 0]"),
       "run scene.json", 2,
       "scene.json: solver.gravity[0]: number '-1e400' is out of the range of double"},
      {"domain_max_1e400", replaced("\"max\": [1, 1]", "\"max\": [1e400, 1]"), "run scene.json", 2,
       "scene.json: domain.max[0]: number '1e400' is out of the range of double"},
      {"node_header_2_30", ball_scene, "validate scene.json", 3,
       "m.node:2: the file ends early (expected point 2 of 1073741824)"},
      {"ele_header_2_30", ball_scene, "validate scene.json", 3,
       "m.ele:2: the file ends early (expected element 2 of 1073741824)"},
      {"flip_2000_cubed",
       patched(R"({"solver": {"type": "flip", "transfer": "flip", "dimension": 3},
         "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.0005},
         "materials": [{"name": "jelly", "model": "fluid"}],
         "bodies": [{"shape": "box", "min": [0.2, 0.2, 0.2], "max": [0.4, 0.4, 0.4], "material": "jelly", "particles_per_cell": 0.001}],
         "boundaries": {"walls": "slip"}})"),
       "run scene.json", 3, "scene.json: domain.dx: the run would need about"},
      {"fem_1e8_tets",
       patched(
           R"({"solver": {"type": "fem", "dimension": 3}, "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.002},
         "materials": [{"name": "jelly", "model": "corotated_linear"}],
         "bodies": [{"shape": "box", "min": [0, 0, 0], "max": [1, 1, 1], "material": "jelly"}]})"),
       "run scene.json", 3, "mesh elements"},
      {"dev_zero", "", "run /dev/zero", 3, "/dev/zero: larger than 64 MiB (expected a scene file"},
      // Hangs.
      {"threads_10000", kGood, "run scene.json --threads 10000", 2,
       "--threads: expected an integer in [0, "},
      {"particles_1e10",
       patched(
           R"({"bodies": [{"shape": "box", "min": [0.1, 0.1], "max": [0.9, 0.9], "material": "jelly", "particles_per_cell": 512}],
                                   "domain": {"dx": 0.0001}})"),
       "run scene.json", 3, "scene.json: bodies[0]: the bodies would seed"},
      {"fps_1e-300", patched(R"({"output": {"fps": 1e-300}})"), "run scene.json", 2,
       "scene.json: output.fps: expected a number in [1e-06, 1000000], got 1e-300"},
      {"max_dt_1e-300", patched(R"({"solver": {"max_dt": 1e-300}})"), "run scene.json", 2,
       "scene.json: solver.max_dt: 1e-300 s would take"},
      {"cfl_1e-300",
       patched(
           (R"({"solver": {"cfl": 1e-300}, )" + body(R"(, "velocity": [1, 0])").substr(1)).c_str()),
       "run -q scene.json", 2, "scene.json: solver.cfl: the substep fell to"},
      {"elastic_cfl_1e-300", patched(R"({"solver": {"elastic_cfl": 1e-300}})"), "run scene.json", 2,
       "scene.json: solver.elastic_cfl: the elastic limit"},
      // Silently wrong.
      {"dimension_wraps", patched(R"({"solver": {"dimension": 4294967298}})"), "run scene.json", 2,
       "scene.json: solver.dimension: expected 2 or 3, got 4294967298"},
      {"frames_wraps", patched(R"({"output": {"frames": 4294967297}})"), "run scene.json", 2,
       "scene.json: output.frames: expected an integer in [0, 2147483647], got 4294967297"},
      {"seed_negative", patched(body(R"(, "sampling": "jittered", "seed": -1)").c_str()),
       "run scene.json", 2,
       "scene.json: bodies[0].seed: expected an integer in [0, 18446744073709551615], got -1"},
      {"attributes_empty", patched(R"({"output": {"attributes": []}})"), "run scene.json", 2,
       "scene.json: output.attributes: expected a list that includes \"position\""},
      {"out_empty", kGood, "run scene.json --out ''", 2,
       "--out: expected a non-empty directory path"},
      {"duplicate_key", replaced("\"dx\": 0.05", "\"dx\": 0.05, \"dx\": 0.1"), "run scene.json", 2,
       "scene.json: domain.dx: duplicate key"},
      {"description_number", patched(R"({"description": 42})"), "run scene.json", 2,
       "scene.json: description: expected a string, got 42"},
      {"body_1e-7",
       patched(
           R"({"bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.2000001, 0.2000001], "material": "jelly"}]})"),
       "run scene.json", 2,
       "scene.json: bodies[0]: the body is 9.99999999751e-08 m across along axis 0, expected at "
       "least one particle spacing"},
      {"ppc_1e-9", patched(body(R"(, "particles_per_cell": 1e-9)").c_str()), "run scene.json", 2,
       "scene.json: bodies[0]: the body is 0.2 m across along axis 0, expected at least one "
       "particle spacing"},
      {"overlapping_bodies",
       patched(
           R"({"bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "jelly"},
                                                    {"shape": "sphere", "center": [0.45, 0.3], "radius": 0.1, "material": "jelly"}]})"),
       "run scene.json", 2, "scene.json: bodies[1]: overlaps bodies[0]"},
      {"directory_as_scene", "", "run .", 3, ".: is a directory (expected a scene file, JSON)"},
      // Exit codes of the CLI.
      {"frames_negative", kGood, "run scene.json --frames -1", 2,
       "--frames: expected an integer in [0, 2147483647], got \"-1\""},
      {"frames_abc", kGood, "run scene.json --frames abc", 2,
       "--frames: expected an integer in [0, 2147483647], got \"abc\""},
      {"frames_huge", kGood, "run scene.json --frames 99999999999", 2, "got \"99999999999\""},
      {"threads_negative", kGood, "run scene.json --threads -1", 2,
       "--threads: expected an integer in [0, "},
      {"no_subcommand", kGood, "", 2, "slurry: error: A subcommand is required"},
      {"unknown_option", kGood, "run scene.json --bogus", 2,
       "slurry: error: The following argument was not expected: --bogus"},
      {"memory_limit_zero", kGood, "run scene.json --memory-limit 0", 2,
       "--memory-limit: expected a number > 0, got \"0\""},
      {"validate_missing_mesh", R"({
         "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.1}, "solver": {"type": "fem", "dimension": 3},
         "materials": [{"name": "jelly", "model": "corotated_linear"}], "bodies": [{"mesh": "nowhere", "material": "jelly"}]})",
       "validate scene.json", 3, "nowhere.node: no such file (expected a TetGen mesh file)"},
      {"run_bad_mesh", ball_scene, "run scene.json", 3, "m.node:2: the file ends early"},
  };
}

class BadInput : public testing::TestWithParam<Case> {};

TEST_P(BadInput, ExitCodeAndMessageAndNothingWritten) {
  const Case& c = GetParam();
  const fs::path dir = scratch(c.name);
  if (!c.scene.empty()) std::ofstream(dir / "scene.json") << c.scene;
  std::ofstream(dir / "m.node") << "1073741824 3 0 0\n1 0 0 0\n";
  std::ofstream(dir / "m.ele") << "1073741824 4 0\n1 1 1 1 1\n";
  if (std::string(c.name) == "ele_header_2_30") {
    std::ofstream(dir / "m.node") << "4 3 0 0\n1 0 0 0\n2 0.5 0 0\n3 0 0.5 0\n4 0 0 0.5\n";
  }
  const Result r = cli(dir, c.args);
  RecordProperty("message", r.err);  // for the table of cases (--gtest_output=xml)
  expect_exit(r, c.code, c.message);
  EXPECT_EQ(r.err.find("1.79"), std::string::npos) << r.err;  // no DBL_MAX printed in full
  const auto at = r.err.find("slurry: error: ");
  EXPECT_EQ(r.err.find('\n', at), r.err.size() - 1)
      << "expected a one-line message at the end: " << r.err;
  if (std::string(c.name) != "cfl_1e-300") {  // that one fails at its first substep, after frame 0
    EXPECT_FALSE(fs::exists(dir / "frames")) << "a failed run left its output directory";
  }
}

INSTANTIATE_TEST_SUITE_P(Campaign, BadInput, testing::ValuesIn(cases()),
                         [](const testing::TestParamInfo<Case>& i) {
                           std::string n = i.param.name;
                           for (char& ch : n)
                             if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
                           return n;
                         });

TEST(OutputDirectory, AnotherScenesFramesAreRefusedOrOverwritten) {
  const fs::path dir = scratch("other_scene");
  std::ofstream(dir / "a.json") << kGood;
  std::ofstream(dir / "b.json") << patched(R"({"output": {"frames": 1}})");
  ASSERT_EQ(cli(dir, "run -q a.json").code, 0);
  Result r = cli(dir, "run -q b.json");
  expect_exit(r, 3,
              "frames: holds 3 frames of another scene (a.json); expected an empty "
              "directory or this scene's own frames "
              "(pass --overwrite to remove them)");
  EXPECT_TRUE(fs::exists(dir / "frames" / "frame_0002.ply"));
  r = cli(dir, "run -q b.json --overwrite");
  expect_exit(r, 0, "removed 3 frames of an earlier run (--overwrite)");
  EXPECT_TRUE(fs::exists(dir / "frames" / "frame_0001.ply"));
  EXPECT_FALSE(fs::exists(dir / "frames" / "frame_0002.ply")) << "a mixed sequence";
  // The same scene again with fewer frames: its old frames go, without --overwrite.
  r = cli(dir, "run -q b.json --frames 0");
  expect_exit(r, 0, "removed 2 frames of an earlier run of this scene");
  EXPECT_FALSE(fs::exists(dir / "frames" / "frame_0001.ply"));
}

TEST(OutputDirectory, StaleTemporaryFilesAreRemoved) {
  const fs::path dir = scratch("stale");
  std::ofstream(dir / "a.json") << kGood;
  fs::create_directories(dir / "frames");
  std::ofstream(dir / "frames" / "frame_0003.ply.tmp-2147483646-0")
      << "partial";  // no such process
  const Result r = cli(dir, "run -q a.json");
  expect_exit(r, 0, "removed 1 temporary frame files of a killed run");
  EXPECT_FALSE(fs::exists(dir / "frames" / "frame_0003.ply.tmp-2147483646-0"));
}

// SIGINT while frames are being written: the run finishes the frame it is on, prints the
// summary and exits 130, leaving complete frames and no temporary file.
TEST(Interrupt, SigintFinishesTheFrameAndPrintsTheSummary) {
  const fs::path dir = scratch("sigint");
  std::ofstream(dir / "a.json") << patched(R"({"output": {"frames": 100000}})");
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    if (::chdir(dir.c_str()) != 0) ::_exit(99);
    if (!std::freopen("out.txt", "w", stdout) || !std::freopen("err.txt", "w", stderr)) ::_exit(98);
    ::execl(SLURRY_CLI, SLURRY_CLI, "run", "-q", "a.json", static_cast<char*>(nullptr));
    ::_exit(97);
  }
  // Wait (without a time limit: ctest's timeout is the backstop) for a few frames.
  while (!fs::exists(dir / "frames" / "frame_0003.ply"))
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  ::kill(pid, SIGINT);
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status)) << "killed by signal " << WTERMSIG(status);
  EXPECT_EQ(WEXITSTATUS(status), 130);
  const std::string err = slurp(dir / "err.txt"), out = slurp(dir / "out.txt");
  EXPECT_NE(err.find("slurry: stopped by SIGINT after frame"), std::string::npos) << err;
  EXPECT_NE(out.find("done: "), std::string::npos) << out;
  for (const auto& e : fs::directory_iterator(dir / "frames"))
    // The run statistics (one row per complete frame) and the checkpoint of the frame it
    // stopped after (run.h) are kept beside the frames.
    if (e.path().filename() != "stats.csv" && e.path().extension() != ".slc") {
      EXPECT_EQ(e.path().extension(), ".ply") << "left behind: " << e.path();
    }
}

TEST(Limits, MemoryLimitFromTheSceneOrTheCommandLine) {
  const fs::path dir = scratch("memory");
  std::ofstream(dir / "a.json") << patched(R"({"limits": {"memory_gb": 1e-6}})");
  Result r = cli(dir, "validate a.json");
  expect_exit(r, 3, "a.json: bodies[0]: the run would need about");
  EXPECT_NE(r.err.find("(limits.memory_gb)"), std::string::npos) << r.err;
  r = cli(dir, "validate a.json --memory-limit 1");
  EXPECT_EQ(r.code, 0) << r.err;
}

TEST(Limits, SubstepsPerFrame) {
  const fs::path dir = scratch("substeps");
  std::ofstream(dir / "a.json") << patched(R"({"limits": {"substeps_per_frame": 10}})");
  const Result r = cli(dir, "validate a.json");
  expect_exit(r, 2,
              "a.json: solver.max_dt: 0.001 s would take 41.6666666667 substeps per frame "
              "of 0.0416666666667 s, "
              "more than limits.substeps_per_frame = 10");
}

}  // namespace
