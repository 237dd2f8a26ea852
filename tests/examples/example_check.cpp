// example_check: runs one shipped example scene through the slurry CLI, as a user would, and
// checks what it wrote (tests/examples/CMakeLists.txt registers one ctest per scene).
//
//   example_check --cli PATH --scene SCENE.json --out DIR [--frames N]
//
// Asserts, and exits non-zero with a message naming the scene and frame on failure:
//  - the CLI exits 0, prints no warning (a drift warning says the run cannot be trusted), and
//    writes frames 0..N (N = --frames, else the scene's output.frames);
//  - every value in every frame is finite, and every particle is inside the domain (plus the
//    grid padding of three cells);
//  - the peak particle speed stays below what the scene's energy allows. A particle released
//    from rest falls at most the domain's extent H along gravity, so sqrt(2 g H) bounds the
//    speed gravity can give it; bodies and emitters start at |v0| at most, and a moving collider
//    can reflect a particle at up to twice its own speed. Elastic bodies can briefly concentrate
//    energy at an edge (the jelly cubes reach 1.45 sqrt(v0^2 + 2 g H) as they bounce apart), so
//    the bound is 2 sqrt(v0^2 + 2 g H) + 2 |v_collider| (a keyframed mesh collider: its fastest
//    point, translation plus turn rate times reach), which leaves room for the round-off
//    differences between instruction sets. An unstable run exceeds it by an order of magnitude
//    (sand_column_3d before its SVD fix: 47 m/s against a bound of 6.3 m/s). Liquids throw droplets: where a jet or a drop hits, the pressure
//    impulse flings a handful of particles (2 to 8 of 5 832 to 22 828 in the 2D FLIP examples)
//    faster than the bulk, so for liquids the bound applies to the 99.9th percentile of the
//    speeds of each frame, and the single fastest particle may reach three times it.
// The frames are removed when every check passed (the 3D FLIP dam break writes 2.6 GB).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <sys/wait.h>

#include <Eigen/Geometry>

#include "slurry/engine/geometry/triangle_mesh.h"
#include "slurry/io/ply.h"
#include "slurry/io/triangle_mesh_file.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"

namespace fs = std::filesystem;

namespace {

[[noreturn]] void fail(const std::string& msg) {
  std::fprintf(stderr, "example_check: FAILED: %s\n", msg.c_str());
  std::exit(1);
}

std::string quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

/// The speed bound of the file comment for a loaded scene.
double speed_bound(const slurry::Scene& s, int dim) {
  const Eigen::Vector3d g = s.solver.gravity;
  const double gn = g.head(dim).norm();
  double H = 0;
  if (gn > 0) {
    // Largest drop inside the domain along gravity: the extent of the domain's box projected
    // onto the gravity direction.
    const Eigen::Vector3d e = (s.domain.max - s.domain.min).cwiseAbs();
    for (int d = 0; d < dim; ++d) H += e[d] * std::abs(g[d]) / gn;
  }
  double v0 = 0, vc = 0;
  for (const auto& b : s.bodies) v0 = std::max(v0, b.velocity.head(dim).norm());
  for (const auto& e : s.emitters) v0 = std::max(v0, e.velocity.head(dim).norm());
  for (const auto& c : s.colliders) {
    double v = c.velocity.head(dim).norm();
    if (c.shape == slurry::ColliderShape::Mesh && c.keyframes.size() > 1) {
      // A keyframed mesh: its fastest point between two keys moves at |dc/dt| + omega R, R the
      // largest distance of a (scaled) vertex from the origin of the mesh's frame.
      double R = 0;
      for (const auto& x : slurry::io::read_triangle_mesh(s.resolve(c.mesh)).vertices)
        R = std::max(R, c.scale.cwiseProduct(x).norm());
      double fastest = 0;
      for (std::size_t k = 1; k < c.keyframes.size(); ++k) {
        const auto &a = c.keyframes[k - 1], &b = c.keyframes[k];
        const double span = b.time - a.time;
        const Eigen::AngleAxisd turn(slurry::geometry::euler_degrees(b.rotation) *
                                     slurry::geometry::euler_degrees(a.rotation).transpose());
        fastest = std::max(fastest, (b.translation - a.translation).norm() / span + turn.angle() / span * R);
      }
      v += fastest;
    }
    vc = std::max(vc, v);
  }
  return 2 * std::sqrt(v0 * v0 + 2 * gn * H) + 2 * vc;
}

}  // namespace

int main(int argc, char** argv) {
  std::string cli, scene_path, out;
  int frames = -1;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--cli") cli = v;
    else if (k == "--scene") scene_path = v;
    else if (k == "--out") out = v;
    else if (k == "--frames") frames = std::stoi(v);
    else fail("unknown argument " + k);
  }
  if (cli.empty() || scene_path.empty() || out.empty()) fail("usage: --cli PATH --scene FILE --out DIR");
  fs::remove_all(out);
  fs::create_directories(out);

  const slurry::Scene scene = slurry::load_scene(scene_path);
  const int dim = scene.solver.dimension;
  const int last = frames >= 0 ? frames : scene.output.frames;
  const fs::path frame_dir = fs::path(out) / "frames";

  std::string cmd = quote(cli) + " run --quiet " + quote(scene_path) + " --out " + quote(frame_dir.string());
  if (frames >= 0) cmd += " --frames " + std::to_string(frames);
  const fs::path err_file = fs::path(out) / "stderr.txt";
  std::printf("%s\n", cmd.c_str());
  std::fflush(stdout);
  const int status = std::system((cmd + " 2> " + quote(err_file.string())).c_str());
  std::ostringstream err;
  err << std::ifstream(err_file).rdbuf();
  std::fputs(err.str().c_str(), stderr);
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
    fail(scene_path + ": the CLI exited with status " + std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : -1));
  if (err.str().find("warning") != std::string::npos)
    fail(scene_path + ": the CLI printed a warning (above); a shipped example must run without one");

  const double bound = speed_bound(scene, dim);
  const double pad = 3 * scene.domain.dx;
  const char* axes[3] = {"x", "y", "z"};
  const char* vel[3] = {"vx", "vy", "vz"};
  bool liquid = scene.solver.type == slurry::SolverType::FLIP;
  for (const auto& m : scene.materials) liquid = liquid || m.model == slurry::ElasticModel::Fluid;
  const double peak_bound = liquid ? 3 * bound : bound;
  double peak = 0, bulk = 0;
  int peak_frame = 0, bulk_frame = 0;
  std::size_t particles = 0;
  for (int f = 0; f <= last; ++f) {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%04d.ply", f);
    const fs::path file = frame_dir / name;
    if (!fs::exists(file)) fail(file.string() + ": missing (expected frames 0.." + std::to_string(last) + ")");
    const slurry::io::PlyData data = slurry::io::read_ply(file);
    const auto& v = data.table("vertex");
    particles = v.count;
    for (const auto& p : v.columns) {
      const auto col = v.column_as_double(p.name);
      for (std::size_t i = 0; i < col.size(); ++i)
        if (!std::isfinite(col[i]))
          fail(file.string() + ": property " + p.name + " of vertex " + std::to_string(i) + " is not finite");
    }
    for (int d = 0; d < dim; ++d) {
      const auto x = v.column_as_double(axes[d]);
      for (std::size_t i = 0; i < x.size(); ++i)
        if (x[i] < scene.domain.min[d] - pad || x[i] > scene.domain.max[d] + pad)
          fail(file.string() + ": vertex " + std::to_string(i) + " has " + axes[d] + " = " + std::to_string(x[i]) +
               ", outside the domain");
    }
    if (!v.find("vx")) continue;
    std::vector<double> s2(v.count, 0.0);
    for (int d = 0; d < dim; ++d) {
      const auto c = v.column_as_double(vel[d]);
      for (std::size_t i = 0; i < c.size(); ++i) s2[i] += c[i] * c[i];
    }
    for (std::size_t i = 0; i < s2.size(); ++i)
      if (std::sqrt(s2[i]) > peak) peak = std::sqrt(s2[i]), peak_frame = f;
    if (liquid && !s2.empty()) {
      const std::size_t k = std::min(s2.size() - 1, std::size_t(0.999 * double(s2.size())));
      std::nth_element(s2.begin(), s2.begin() + std::ptrdiff_t(k), s2.end());
      if (std::sqrt(s2[k]) > bulk) bulk = std::sqrt(s2[k]), bulk_frame = f;
    }
  }
  std::printf("%s: %d frames, %zu particles at the end, peak speed %.3g m/s (frame %d, bound %.3g m/s)",
              scene_path.c_str(), last + 1, particles, peak, peak_frame, peak_bound);
  if (liquid) std::printf(", 99.9th percentile %.3g m/s (frame %d, bound %.3g m/s)", bulk, bulk_frame, bound);
  std::printf("\n");
  if (!(peak <= peak_bound) || !(bulk <= bound)) {
    std::ostringstream msg;
    if (!(peak <= peak_bound))
      msg << scene_path << ": peak particle speed " << peak << " m/s at frame " << peak_frame << " exceeds the bound "
          << peak_bound;
    else
      msg << scene_path << ": 99.9th percentile of the particle speeds " << bulk << " m/s at frame " << bulk_frame
          << " exceeds the bound " << bound;
    msg << " m/s that gravity and the initial and collider speeds allow";
    fail(msg.str());
  }
  // FLIP whitewater: whitewater_NNNN.ply beside every frame, finite, inside the domain, types
  // 0 (spray), 1 (foam) or 2 (bubble), and some of it by the last frame.
  if (scene.solver.type == slurry::SolverType::FLIP && scene.solver.whitewater.enabled) {
    std::size_t most = 0, counts[3] = {0, 0, 0};
    for (int f = 0; f <= last; ++f) {
      char name[40];
      std::snprintf(name, sizeof name, "whitewater_%04d.ply", f);
      const fs::path file = frame_dir / name;
      if (!fs::exists(file)) fail(file.string() + ": missing (the scene enables solver.whitewater)");
      const slurry::io::PlyData data = slurry::io::read_ply(file);
      const auto& v = data.table("vertex");
      most = std::max(most, v.count);
      for (const auto& p : v.columns)
        for (const double x : v.column_as_double(p.name))
          if (!std::isfinite(x)) fail(file.string() + ": property " + p.name + " is not finite");
      for (int d = 0; d < dim; ++d)
        for (const double x : v.column_as_double(axes[d]))
          if (x < scene.domain.min[d] || x > scene.domain.max[d]) fail(file.string() + ": a particle outside the domain");
      for (const double t : v.column_as_double("type")) {
        if (t != 0 && t != 1 && t != 2) fail(file.string() + ": type " + std::to_string(t) + " (expected 0, 1 or 2)");
        if (f == last) ++counts[int(t)];
      }
    }
    std::printf("%s: whitewater at most %zu particles; last frame %zu spray, %zu foam, %zu bubbles\n", scene_path.c_str(), most,
                counts[0], counts[1], counts[2]);
    if (most == 0) fail(scene_path + ": whitewater enabled, but no frame holds any");
  }
  fs::remove_all(frame_dir);
  std::printf("example_check: passed\n");
  return 0;
}
