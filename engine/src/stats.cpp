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

}  // namespace slurry
