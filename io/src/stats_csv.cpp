// stats.csv: one row of RunStats per frame.
#include "slurry/io/stats_csv.h"

#include <cstdio>
#include <cstdlib>
#include <fstream>

#include "slurry/engine/errors.h"

namespace slurry::io {
namespace fs = std::filesystem;
namespace {
std::string g(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}
}  // namespace

std::string stats_csv_header(bool error_estimate) {
  return std::string("frame,time,substeps,particles,mass,momentum_x,momentum_y,momentum_z,angular_momentum_x,"
                     "angular_momentum_y,angular_momentum_z,kinetic,potential,elastic,energy,volume,max_fluid_J_error,"
                     "projected,cfl,surface") +
         (error_estimate ? ",error_energy,error_centroid" : "");
}

std::string stats_csv_row(const RunStats& s, bool error_estimate) {
  std::string r = std::to_string(s.frame) + "," + g(s.time) + "," + std::to_string(s.substeps) + "," +
                  std::to_string(s.particles) + "," + g(s.mass);
  for (int d = 0; d < 3; ++d) r += "," + g(s.momentum[d]);
  for (int d = 0; d < 3; ++d) r += "," + g(s.angular_momentum[d]);
  r += "," + g(s.kinetic) + "," + g(s.potential) + "," + g(s.elastic) + "," + g(s.energy()) + "," + g(s.volume) +
       "," + g(s.max_fluid_J_error) + "," + std::to_string(s.projected) + "," + g(s.cfl) + "," + g(s.surface);
  if (error_estimate) r += "," + g(s.error_energy) + "," + g(s.error_centroid);
  return r;
}

void truncate_stats_csv(const fs::path& file, int last) {
  std::ifstream in(file, std::ios::binary);
  if (!in) return;
  std::string kept, line;
  for (int i = 0; std::getline(in, line); ++i)
    if (i == 0 || (!line.empty() && std::atoi(line.c_str()) <= last)) kept += line + '\n';
  in.close();
  fs::path temp = file;
  temp += ".tmp";
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    out << kept;
    if (!out.flush()) throw IoError(file.string() + ": cannot rewrite the run statistics for the resumed run");
  }
  std::error_code ec;
  fs::rename(temp, file, ec);
  if (ec) throw IoError(file.string() + ": cannot rewrite the run statistics: " + ec.message());
}

}  // namespace slurry::io
