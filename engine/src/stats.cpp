#include "slurry/engine/stats.h"

#include <cmath>
#include <cstdio>

namespace slurry {

namespace {
std::string g(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}
std::string pct(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g%%", 100 * v);
  return buf;
}
}  // namespace

std::vector<std::string> drift_warnings(const RunStats& first, const RunStats& now, const DriftTolerances& tol,
                                        double energy_scale) {
  std::vector<std::string> out;
  const std::string at = "frame " + std::to_string(now.frame) + " (t = " + g(now.time) + " s): ";
  if (first.mass > 0) {
    const double d = (now.mass - first.mass) / first.mass;
    if (!(std::abs(d) <= tol.mass))
      out.push_back(at + "total mass changed by " + pct(d) + " since frame " + std::to_string(first.frame) +
                    " (output.mass_drift " + pct(tol.mass) + ")");
  }
  if (first.volume > 0) {
    const double d = (now.volume - first.volume) / first.volume;
    if (!(std::abs(d) <= tol.volume))
      out.push_back(at + "volume changed by " + pct(d) + " since frame " + std::to_string(first.frame) +
                    " (output.volume_drift " + pct(tol.volume) + ")");
  }
  if (tol.check_energy && energy_scale > 0) {
    const double d = (now.energy() - first.energy()) / energy_scale;
    if (!(d <= tol.energy))
      out.push_back(at + "energy grew by " + pct(d) + " of the available energy " + g(energy_scale) +
                    " J since frame " + std::to_string(first.frame) + " (output.energy_growth " + pct(tol.energy) +
                    ")");
  }
  return out;
}

std::string stats_csv_header() {
  return "frame,time,substeps,particles,mass,momentum_x,momentum_y,momentum_z,angular_momentum_x,"
         "angular_momentum_y,angular_momentum_z,kinetic,potential,elastic,energy,volume,max_fluid_J_error,"
         "projected,cfl";
}

std::string stats_csv_row(const RunStats& s) {
  std::string r = std::to_string(s.frame) + "," + g(s.time) + "," + std::to_string(s.substeps) + "," +
                  std::to_string(s.particles) + "," + g(s.mass);
  for (int d = 0; d < 3; ++d) r += "," + g(s.momentum[d]);
  for (int d = 0; d < 3; ++d) r += "," + g(s.angular_momentum[d]);
  r += "," + g(s.kinetic) + "," + g(s.potential) + "," + g(s.elastic) + "," + g(s.energy()) + "," + g(s.volume) +
       "," + g(s.max_fluid_J_error) + "," + std::to_string(s.projected) + "," + g(s.cfl);
  return r;
}

}  // namespace slurry
