// The shadow simulation at twice dx and the Richardson estimates (error_estimate.h).
#include "slurry/engine/run/error_estimate.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <vector>

#include "slurry/engine/run/run.h"

namespace slurry {

Scene shadow_scene(const Scene& scene) {
  Scene s = scene;
  s.domain.dx *= 2;
  s.boundaries.thickness = std::max(1, (scene.boundaries.thickness + 1) / 2);
  s.output.error_estimate = false;
  s.output.surface.clear();
  s.output.vdb_points = false;
  s.solver.whitewater.enabled = false;  // secondary particles do not act on the liquid
  s.output.checkpoint_every = 0;
  s.output.per_rank = false;
  return s;
}

ErrorEstimator::ErrorEstimator(const Scene& scene) : ErrorEstimator(make_simulation(shadow_scene(scene)), scene) {}

ErrorEstimator::ErrorEstimator(std::unique_ptr<Solver> shadow, const Scene& scene)
    : shadow_(std::move(shadow)),
      dimension_(scene.solver.dimension),
      factor_(1 / (std::pow(2.0, scene.output.error_order) - 1)) {}

ErrorEstimator::~ErrorEstimator() = default;

void ErrorEstimator::advance_to(double t) { shadow_->advance_to(t); }

namespace {

/// Centroid of each material's particles (material index -> sum of positions, count).
std::map<int, std::pair<Eigen::Vector3d, double>> centroids(const Solver& s, int dim) {
  const Frame f = s.frame({"position", "material"});
  const auto& v = f.table("vertex");
  const char* axes[3] = {"x", "y", "z"};
  std::vector<double> x[3];
  for (int d = 0; d < dim; ++d) x[d] = v.column_as_double(axes[d]);
  const auto m = v.column_as_double("material");
  std::map<int, std::pair<Eigen::Vector3d, double>> c;
  for (std::size_t p = 0; p < m.size(); ++p) {
    auto& [sum, n] = c.try_emplace(int(m[p]), Eigen::Vector3d::Zero(), 0.0).first->second;
    for (int d = 0; d < dim; ++d) sum[d] += x[d][p];
    n += 1;
  }
  for (auto& [k, e] : c) e.first /= e.second;
  return c;
}

}  // namespace

void ErrorEstimator::estimate(const Solver& main, RunStats& stats) {
  const RunStats coarse = shadow_->take_stats();
  if (stats.mass > 0 && coarse.mass > 0)
    stats.error_energy = stats.mass * std::abs(stats.energy() / stats.mass - coarse.energy() / coarse.mass) * factor_;
  else
    stats.error_energy = 0;
  const auto fine_c = centroids(main, dimension_), coarse_c = centroids(*shadow_, dimension_);
  double worst = 0;
  for (const auto& [k, e] : fine_c)
    if (const auto it = coarse_c.find(k); it != coarse_c.end()) worst = std::max(worst, (e.first - it->second.first).norm());
  stats.error_centroid = worst * factor_;
}

}  // namespace slurry
