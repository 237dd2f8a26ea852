// The determinism scenes' frames, written by a build with another parallel backend (TBB):
//   determinism_tbb OUT.ply THREADS [flip]
#include <cstdlib>
#include <string>

#include "determinism_scene.h"
#include "slurry/transfer/parallel.h"

int main(int argc, char** argv) {
  if (argc != 3 && argc != 4) return 2;
  slurry::parallel::ThreadLimit limit(std::atoi(argv[2]));
  const auto no_read = [](const std::filesystem::path&) { return std::string(); };
  if (argc == 4) {
    if (std::string(argv[3]) != "flip") return 2;
    slurry::test::flip_determinism_frame(30, argv[1], no_read);
    return 0;
  }
  const slurry::Scene s = slurry::test::determinism_scene(3, slurry::GridKind::Sparse);
  slurry::test::determinism_frame(s, 20, argv[1], no_read);
  return 0;
}
