// The determinism scene's frame, written by a build with another parallel backend (TBB):
//   determinism_tbb OUT.ply THREADS
#include <cstdlib>
#include <string>

#include "determinism_scene.h"
#include "slurry/transfer/parallel.h"

int main(int argc, char** argv) {
  if (argc != 3) return 2;
  slurry::parallel::ThreadLimit limit(std::atoi(argv[2]));
  const slurry::Scene s = slurry::test::determinism_scene(3, slurry::GridKind::Sparse);
  slurry::test::determinism_frame(s, 20, argv[1], [](const std::filesystem::path&) { return std::string(); });
  return 0;
}
