// The harness of the extremes suite: runs a scene frame by frame through the
// public API and checks, after every frame, what every extreme case must keep:
//   - every position and velocity (and J) written in a frame is finite;
//   - every particle is inside the domain box;
//   - the energy the scene holds stays bounded: E(t) <= factor x E(0), where
//       E = kinetic + elastic + (potential - lowest potential the domain allows),
//     i.e. the energy relative to all the mass lying at the domain's lowest point along gravity
//     (plus a stated allowance where something does work on the scene: an emitter or a piston).
// A case either runs to its last frame or stops with a SimulationError / SceneError; the caller
// asserts which of the two is the correct outcome, and the figures are printed as one
// "[ extreme ]" line each (tests/extremes/README.md tabulates them).
#pragma once
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "slurry/engine/run/run.h"
#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/io/scene_file.h"

namespace extremes {

struct Outcome {
  bool stopped = false;     ///< a SimulationError or SceneError ended the run
  std::string message;      ///< its message
  int frames = 0;           ///< frames completed after frame 0
  std::int64_t substeps = 0;
  std::size_t particles = 0;
  double peak_speed = 0;    ///< largest particle speed in any frame (m/s)
  double energy_ratio = 0;  ///< largest E(t) / E(0) (E as in the file comment)
  double min_J = std::numeric_limits<double>::infinity();  ///< smallest J written (MPM)
  double max_J = 0;
  std::int64_t non_finite = 0;  ///< values that were not finite (must stay 0)
  double escape = 0;            ///< largest distance of a particle outside the domain (m)
  Eigen::Vector3d lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};  ///< particle bounding box, all frames
};

/// Energy relative to all mass at the lowest point of the domain along gravity.
inline double available_energy(const slurry::Scene& s, const slurry::RunStats& st) {
  const int dim = s.solver.dimension;
  double highest_gx = 0;  // max over the domain of g . x
  for (int d = 0; d < dim; ++d)
    highest_gx += std::max(s.solver.gravity[d] * s.domain.min[d], s.solver.gravity[d] * s.domain.max[d]);
  const double lowest_potential = -st.mass * highest_gx;
  return st.kinetic + st.elastic + (st.potential - lowest_potential);
}

/// Runs `scene` for `frames` frames. `inspect` sees every frame's vertex element (after the
/// harness's own checks).
inline Outcome run(const slurry::Scene& scene, int frames,
                   const std::function<void(const slurry::Table&)>& inspect = {}) {
  Outcome out;
  const int dim = scene.solver.dimension;
  std::vector<std::string> attributes{"position", "velocity"};
  if (scene.solver.type == slurry::SolverType::MPM) attributes.push_back("J");
  std::unique_ptr<slurry::Solver> sim;
  try {
    sim = slurry::make_simulation(scene);
  } catch (const slurry::SceneError& e) {
    out.stopped = true;
    out.message = e.what();
    return out;
  }
  double e0 = 0;
  for (int f = 0; f <= frames; ++f) {
    if (f > 0) {
      try {
        out.substeps += sim->advance_to(f * scene.frame_dt());
      } catch (const slurry::SimulationError& e) {
        out.stopped = true, out.message = e.what();
        break;
      } catch (const slurry::SceneError& e) {  // the time-step floor (substep limits)
        out.stopped = true, out.message = e.what();
        break;
      }
      out.frames = f;
    }
    const slurry::Frame data = sim->frame(attributes);
    const auto& v = data.table("vertex");
    out.particles = v.count;
    static const char* xn[3] = {"x", "y", "z"};
    static const char* vn[3] = {"vx", "vy", "vz"};
    std::vector<std::vector<double>> x(dim), u(dim);
    for (int d = 0; d < dim; ++d) x[d] = v.column_as_double(xn[d]), u[d] = v.column_as_double(vn[d]);
    std::vector<double> J;
    if (v.find("J")) J = v.column_as_double("J");
    for (std::size_t p = 0; p < v.count; ++p) {
      double s2 = 0;
      for (int d = 0; d < dim; ++d) {
        const double xp = x[d][p];
        if (!std::isfinite(xp) || !std::isfinite(u[d][p])) {
          ++out.non_finite;
          continue;
        }
        s2 += u[d][p] * u[d][p];
        out.lo[d] = std::min(out.lo[d], xp), out.hi[d] = std::max(out.hi[d], xp);
        out.escape = std::max({out.escape, scene.domain.min[d] - xp, xp - scene.domain.max[d]});
      }
      out.peak_speed = std::max(out.peak_speed, std::sqrt(s2));
      if (!J.empty()) {
        if (!std::isfinite(J[p])) ++out.non_finite;
        out.min_J = std::min(out.min_J, J[p]), out.max_J = std::max(out.max_J, J[p]);
      }
    }
    const slurry::RunStats st = sim->take_stats();
    const double e = available_energy(scene, st);
    if (!std::isfinite(e)) ++out.non_finite;
    if (f == 0) e0 = e;
    else if (e0 > 0) out.energy_ratio = std::max(out.energy_ratio, e / e0);
    if (inspect) inspect(v);
  }
  return out;
}

/// One line of figures per case, for tests/extremes/README.md.
inline void report(const std::string& name, const Outcome& o) {
  std::string what = o.stopped ? "stops: " + o.message.substr(0, 160) : "runs";
  std::printf("[ extreme ] %s | %s | frames %d, substeps %lld, particles %zu, peak speed %.4g m/s, energy ratio %.4g, "
              "J %.3g..%.3g\n",
              name.c_str(), what.c_str(), o.frames, (long long)o.substeps, o.particles, o.peak_speed, o.energy_ratio,
              std::isfinite(o.min_J) ? o.min_J : 0.0, o.max_J);
}

/// The checks of a case that must run to the end: all frames, finite, inside the domain,
/// energy at most `energy_factor` times its initial value.
inline void expect_runs(const std::string& name, const Outcome& o, int frames, double energy_factor) {
  report(name, o);
  EXPECT_FALSE(o.stopped) << name << ": " << o.message;
  EXPECT_EQ(o.frames, frames) << name;
  EXPECT_EQ(o.non_finite, 0) << name;
  EXPECT_LE(o.escape, 0.0) << name << ": a particle left the domain box";
  EXPECT_LE(o.energy_ratio, energy_factor) << name << ": energy grew";
  EXPECT_GT(o.particles, 0u) << name;
}

/// The checks of a case whose correct outcome is to stop with a message containing `expected`.
inline void expect_stops(const std::string& name, const Outcome& o, const std::string& expected) {
  report(name, o);
  EXPECT_TRUE(o.stopped) << name << " ran to the end (frames " << o.frames << ")";
  EXPECT_NE(o.message.find(expected), std::string::npos) << name << ": " << o.message;
  EXPECT_EQ(o.non_finite, 0) << name << ": a frame with non-finite values was produced";
}

}  // namespace extremes
