// merge_rank_frames (run.h): the per-rank parts of a frame are joined only when they come from
// one run. A part left in the directory by another run of the same scene (same process count,
// time and columns) carries another run token and is refused; nothing is merged then.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "slurry/engine/errors.h"
#include "slurry/engine/run/run.h"
#include "slurry/io/ply.h"

namespace fs = std::filesystem;

namespace {

/// Part `rank` of 2 of frame 1: the particles with ids rank, rank + 2, ... of 4, with x = id.
void write_part(const fs::path& dir, int rank, const std::string& token) {
  slurry::io::PlyData d;
  d.comments = {"slurry frame t=0.04 source=scene.json", "slurry part " + std::to_string(rank) + " of 2 id=requested"};
  if (!token.empty()) d.comments.push_back("slurry run " + token);
  slurry::Table& v = d.tables.emplace_back();
  v.name = "vertex";
  std::vector<float> x;
  std::vector<std::uint32_t> id;
  for (std::uint32_t i = std::uint32_t(rank); i < 4; i += 2) x.push_back(float(i)), id.push_back(i);
  v.count = id.size();
  v.columns.push_back({"x", x});
  v.columns.push_back({"id", id});
  slurry::io::write_ply(slurry::rank_frame_file(dir, 1, rank), d);
}

}  // namespace

TEST(Merge, PartsOfAnotherRunOfTheSameSceneAreRefused) {
  const fs::path dir = fs::temp_directory_path() / ("slurry_merge_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  write_part(dir, 0, "0000beef");
  write_part(dir, 1, "12345678");  // left by another run
  try {
    slurry::merge_rank_frames(dir);
    FAIL() << "parts of two runs were merged";
  } catch (const slurry::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("part of another run than"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(slurry::frame_file(dir, 1)));

  write_part(dir, 1, "0000beef");  // the same run
  const auto m = slurry::merge_rank_frames(dir);
  EXPECT_EQ(m.frames, 1);
  EXPECT_EQ(m.particles, 4u);
  const auto merged = slurry::io::read_ply(slurry::frame_file(dir, 1));
  ASSERT_EQ(merged.comments.size(), 1u);  // the frame's own comment, as one process writes it
  EXPECT_EQ(merged.table("vertex").column_as_double("x"), (std::vector<double>{0, 1, 2, 3}));
  fs::remove_all(dir);
}
