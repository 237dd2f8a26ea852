// Scene validation (every field range-checked, cross references resolved), resource estimates
// and the names of scene.h's enumerations. The JSON reader is io/src/scene_file.cpp.
#include "slurry/engine/scene/scene.h"
#include "slurry/engine/scene/quality.h"
#include "slurry/engine/scene/names.h"
#include "slurry/engine/scene/scene_files.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <utility>
#include <unistd.h>

namespace slurry {
namespace {

using namespace scene_names;

std::string fmt_num(double x) {
  std::ostringstream o;
  o.precision(12);
  o << x;
  return o.str();
}

[[noreturn]] void fail(const std::string& source, const std::string& path, const std::string& what) {
  throw SceneError(source + ": " + path + ": " + what);
}

/// Range checks shared by validate(): each names the path and what was expected.
struct Checker {
  const std::string& source;
  void positive(const std::string& path, double v) const {
    if (!(v > 0)) fail(source, path, "expected a number > 0, got " + fmt_num(v));
  }
  void non_negative(const std::string& path, double v) const {
    if (!(v >= 0)) fail(source, path, "expected a number >= 0, got " + fmt_num(v));
  }
  void in_range(const std::string& path, double v, double lo, double hi, bool lo_open, bool hi_open) const {
    const bool ok = (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
    if (!ok)
      fail(source, path,
           "expected a number in " + std::string(lo_open ? "(" : "[") + fmt_num(lo) + ", " + fmt_num(hi) +
               (hi_open ? ")" : "]") + ", got " + fmt_num(v));
  }
};

std::string vec_str(const Eigen::Vector3d& v, int dim) {
  std::string s = "[";
  for (int d = 0; d < dim; ++d) s += (d ? ", " : "") + fmt_num(v[d]);
  return s + "]";
}

/// The settings solver.type "fem" needs: co-rotated linear materials without plasticity, and
/// bodies that are a mesh file, a box or a sphere (meshed with spacing domain.dx).
void validate_fem(const Scene& s) {
  const Checker c{s.source};
  for (std::size_t i = 0; i < s.materials.size(); ++i) {
    const auto& m = s.materials[i];
    const std::string p = "materials[" + std::to_string(i) + "]";
    if (m.model != ElasticModel::CorotatedLinear)
      fail(s.source, p + ".model", "solver.type \"fem\" simulates \"corotated_linear\" only, got \"" +
                                       std::string(to_string(m.model)) + "\"");
    if (m.plasticity != PlasticModel::None)
      fail(s.source, p + ".plasticity", "solver.type \"fem\" has no plasticity (expected \"none\")");
    c.non_negative(p + ".damping", m.damping);
  }
  for (std::size_t i = 0; i < s.bodies.size(); ++i) {
    if (s.bodies[i].shape == Shape::Mesh)
      fail(s.source, "bodies[" + std::to_string(i) + "].shape",
           "solver.type \"fem\" reads a TetGen \"mesh\" for a \"box\" or \"sphere\" body; \"mesh\" bodies (triangle meshes) are "
           "filled with particles by \"mpm\" and \"flip\"");
    if (s.bodies[i].mesh.empty() && s.bodies[i].shape == Shape::Cylinder)
      fail(s.source, "bodies[" + std::to_string(i) + "].shape",
           "solver.type \"fem\" meshes \"box\" and \"sphere\" bodies; give a cylinder as a TetGen \"mesh\"");
  }
}

double wave_speed(const MaterialParams& m) {
  if (m.model == ElasticModel::Fluid) return std::sqrt(m.bulk_modulus / m.density);
  const double mu = m.E / (2 * (1 + m.nu)), lambda = m.E * m.nu / ((1 + m.nu) * (1 - 2 * m.nu));
  return std::sqrt((lambda + 2 * mu) / m.density);
}

/// A body's bounding box and the share of it the shape fills.
void body_extent(const BodyParams& b, int dim, Eigen::Vector3d& lo, Eigen::Vector3d& hi, double& fill) {
  lo = b.min;
  hi = b.max;
  fill = 1;
  if (b.shape == Shape::Box) return;
  lo = b.center.array() - b.radius;
  hi = b.center.array() + b.radius;
  const double pi = 3.14159265358979323846;
  fill = dim == 3 && b.shape == Shape::Sphere ? pi / 6 : pi / 4;
  if (b.shape == Shape::Cylinder) {
    lo[b.axis] = b.center[b.axis] - 0.5 * b.height;
    hi[b.axis] = b.center[b.axis] + 0.5 * b.height;
  }
}

/// Whether two bodies share volume: boxes by their intervals, spheres by their centres'
/// distance, anything with a cylinder by bounding boxes.
bool overlap(const BodyParams& a, const BodyParams& b, int dim) {
  Eigen::Vector3d alo, ahi, blo, bhi;
  double fill;
  body_extent(a, dim, alo, ahi, fill);
  body_extent(b, dim, blo, bhi, fill);
  for (int d = 0; d < dim; ++d)
    if (!(alo[d] < bhi[d] && blo[d] < ahi[d])) return false;
  const auto distance_to_box = [dim](const Eigen::Vector3d& c, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
    double d2 = 0;
    for (int d = 0; d < dim; ++d) {
      const double e = std::max({lo[d] - c[d], 0.0, c[d] - hi[d]});
      d2 += e * e;
    }
    return std::sqrt(d2);
  };
  if (a.shape == Shape::Sphere && b.shape == Shape::Sphere)
    return (a.center - b.center).head(dim).norm() < a.radius + b.radius;
  if (a.shape == Shape::Sphere && b.shape == Shape::Box) return distance_to_box(a.center, b.min, b.max) < a.radius;
  if (b.shape == Shape::Sphere && a.shape == Shape::Box) return distance_to_box(b.center, a.min, a.max) < b.radius;
  return true;
}

/// solver.whitewater (FLIP): every key range-checked, also while it is disabled, so that a
/// scene does not hold a bad value that only shows when it is turned on.
void validate_whitewater(const Scene& s) {
  const Checker c{s.source};
  const auto& w = s.solver.whitewater;
  const std::string p = "solver.whitewater.";
  if (w.seed < 0 || w.seed > 4294967295LL)
    fail(s.source, p + "seed", "expected an integer in [0, 4294967295], got " + std::to_string(w.seed));
  c.non_negative(p + "trapped_air_rate", w.trapped_air_rate);
  c.non_negative(p + "wave_crest_rate", w.wave_crest_rate);
  const auto range = [&](const char* lo_key, double lo, const char* hi_key, double hi) {
    c.non_negative(p + lo_key, lo);
    if (!(hi > lo))
      fail(s.source, p + hi_key,
           "expected a number greater than " + p + lo_key + " (" + fmt_num(lo) + "), got " + fmt_num(hi));
  };
  range("trapped_air_min", w.trapped_air_min, "trapped_air_max", w.trapped_air_max);
  range("wave_crest_min", w.wave_crest_min, "wave_crest_max", w.wave_crest_max);
  range("kinetic_energy_min", w.kinetic_energy_min, "kinetic_energy_max", w.kinetic_energy_max);
  c.positive(p + "lifetime_min", w.lifetime_min);
  if (!(w.lifetime_max >= w.lifetime_min))
    fail(s.source, p + "lifetime_max",
         "expected a number >= " + p + "lifetime_min (" + fmt_num(w.lifetime_min) + "), got " + fmt_num(w.lifetime_max));
  c.non_negative(p + "spray_drag", w.spray_drag);
  c.non_negative(p + "bubble_buoyancy", w.bubble_buoyancy);
  c.positive(p + "bubble_drag", w.bubble_drag);
  c.in_range(p + "spray_distance", w.spray_distance, 0, 2, false, false);
  c.in_range(p + "bubble_depth", w.bubble_depth, 0.25, 3, false, false);
  if (w.max_particles < 0 || w.max_particles > 2147483647LL)
    fail(s.source, p + "max_particles", "expected an integer in [0, 2147483647], got " + std::to_string(w.max_particles));
}

}  // namespace

std::string_view to_string(ElasticModel m) { return name_of(kElastic, m); }
std::string_view to_string(PlasticModel m) { return name_of(kPlastic, m); }
std::string_view to_string(TransferKind m) { return name_of(kTransfer, m); }
std::string_view to_string(KernelKind m) { return name_of(kKernel, m); }
std::string_view to_string(SolverType m) { return name_of(kSolverType, m); }
std::string_view to_string(Integrator m) { return name_of(kIntegrator, m); }
std::string_view to_string(ImplicitPreconditioner m) { return name_of(kImplicitPreconditioner, m); }
std::string_view to_string(AdvectionScheme m) { return name_of(kAdvection, m); }
std::string_view to_string(PressurePreconditioner m) { return name_of(kPreconditioner, m); }
std::string_view to_string(OnInstability m) { return name_of(kOnInstability, m); }

int Scene::material_index(std::string_view name) const {
  for (std::size_t i = 0; i < materials.size(); ++i)
    if (materials[i].name == name) return int(i);
  return -1;
}

void Scene::validate_flip() const {
  const Checker c{source};
  const int dim = solver.dimension;
  if (solver.transfer == TransferKind::MLS)
    fail(source, "solver.transfer", "solver.type \"flip\" takes \"pic\", \"flip\" or \"apic\", got \"mls\"");
  if (solver.kernel == KernelKind::Cubic)
    fail(source, "solver.kernel", "solver.type \"flip\" takes \"linear\" or \"quadratic\", got \"cubic\"");
  c.in_range("solver.pressure.tolerance", solver.pressure.tolerance, 0, 1, true, true);
  if (solver.pressure.max_iterations < 1 || solver.pressure.max_iterations > 1000000)
    fail(source, "solver.pressure.max_iterations",
         "expected an integer in [1, 1000000], got " + std::to_string(solver.pressure.max_iterations));
  if (solver.reseed.min_per_cell < 0 || solver.reseed.min_per_cell > 64)
    fail(source, "solver.reseed.min_per_cell",
         "expected an integer in [0, 64], got " + std::to_string(solver.reseed.min_per_cell));
  if (solver.reseed.max_per_cell != 0 &&
      (solver.reseed.max_per_cell <= solver.reseed.min_per_cell || solver.reseed.max_per_cell > 512))
    fail(source, "solver.reseed.max_per_cell",
         "expected 0 (off) or an integer in (min_per_cell = " + std::to_string(solver.reseed.min_per_cell) + ", 512], got " +
             std::to_string(solver.reseed.max_per_cell));
  validate_whitewater(*this);
  for (std::size_t i = 0; i < materials.size(); ++i) {
    const std::string p = "materials[" + std::to_string(i) + "]";
    if (materials[i].model != ElasticModel::Fluid)
      fail(source, p + ".model",
           "solver.type \"flip\" simulates liquids: expected \"fluid\", got \"" +
               std::string(to_string(materials[i].model)) + "\"");
    if (materials[i].plasticity != PlasticModel::None)
      fail(source, p + ".plasticity", "a \"fluid\" material takes no plasticity (expected \"none\")");
    if (!(std::isfinite(materials[i].viscosity) && materials[i].viscosity >= 0))
      fail(source, p + ".viscosity", "expected a finite number >= 0, got " + fmt_num(materials[i].viscosity));
    if (!(std::isfinite(materials[i].surface_tension) && materials[i].surface_tension >= 0))
      fail(source, p + ".surface_tension", "expected a finite number >= 0 (N/m), got " + fmt_num(materials[i].surface_tension));
    if (i > 0 && materials[i].surface_tension != materials[0].surface_tension)
      fail(source, p + ".surface_tension",
           "the FLIP solver takes one surface tension for all liquids: expected " + fmt_num(materials[0].surface_tension) +
               " (materials[0].surface_tension), got " + fmt_num(materials[i].surface_tension));
    if (i > 0 && materials[i].density != materials[0].density)
      fail(source, p + ".density",
           "the FLIP solver takes one density for all liquids: expected " + fmt_num(materials[0].density) +
               " (materials[0].density), got " + fmt_num(materials[i].density));
  }
  if (solver.free_surface == FreeSurface::Cell && materials[0].surface_tension > 0)
    fail(source, "solver.free_surface",
         "surface tension's pressure jump is imposed at the subcell surface: expected \"auto\" or \"subcell\" with "
         "materials[].surface_tension " + fmt_num(materials[0].surface_tension) + ", got \"cell\"");
  bool viscous = false;
  for (const auto& m : materials) viscous = viscous || m.viscosity > 0;
  // "sticky" is the no-slip wall of the viscous stress (flip/viscosity.h); an inviscid liquid has
  // no tangential stress to hold it with.
  if (boundaries.walls == Condition::Sticky && !viscous)
    fail(source, "boundaries.walls",
         "solver.type \"flip\" walls are free-slip: expected \"slip\" or \"separate\", got \"sticky\" (no-slip walls need a "
         "material with viscosity > 0)");
  if (boundaries.friction != 0)
    fail(source, "boundaries.friction", "solver.type \"flip\" walls are free-slip: expected 0, got " + fmt_num(boundaries.friction));
  for (std::size_t i = 0; i < colliders.size(); ++i) {
    const std::string p = "colliders[" + std::to_string(i) + "]";
    if (colliders[i].condition == Condition::Sticky)
      fail(source, p + ".condition", "solver.type \"flip\" colliders are free-slip: expected \"slip\" or \"separate\", got \"sticky\"");
    if (colliders[i].friction != 0)
      fail(source, p + ".friction", "solver.type \"flip\" colliders are free-slip: expected 0, got " + fmt_num(colliders[i].friction));
  }
  for (std::size_t i = 0; i < emitters.size(); ++i) {
    const auto& e = emitters[i];
    const std::string p = "emitters[" + std::to_string(i) + "]";
    if (material_index(e.material) < 0) {
      std::string known;
      for (const auto& m : materials) known += (known.empty() ? "\"" : ", \"") + m.name + "\"";
      fail(source, p + ".material", "expected the name of a material (" + known + "), got \"" + e.material + "\"");
    }
    Eigen::Vector3d lo = e.min, hi = e.max;
    if (e.shape == Shape::Box) {
      for (int d = 0; d < dim; ++d)
        if (!(e.max[d] > e.min[d]))
          fail(source, p + ".max", "expected every component greater than min " + vec_str(e.min, dim) +
                                       " (an empty box), got " + vec_str(e.max, dim));
    } else if (e.shape == Shape::Sphere) {
      c.positive(p + ".radius", e.radius);
      lo = e.center.array() - e.radius;
      hi = e.center.array() + e.radius;
    } else {
      fail(source, p + ".shape", std::string("expected \"box\" or \"sphere\", got \"") + (e.shape == Shape::Mesh ? "mesh" : "cylinder") + "\"");
    }
    for (int d = 0; d < dim; ++d)
      if (lo[d] < domain.min[d] || hi[d] > domain.max[d])
        fail(source, p, "the emitter spans " + vec_str(lo, dim) + " to " + vec_str(hi, dim) +
                            ", expected it inside the domain " + vec_str(domain.min, dim) + " to " +
                            vec_str(domain.max, dim));
    c.positive(p + ".rate", e.rate);
    c.non_negative(p + ".start", e.start);
    if (!(e.end > e.start))
      fail(source, p + ".end", "expected a time greater than start (" + fmt_num(e.start) + "), got " + fmt_num(e.end));
    c.in_range(p + ".particles_per_cell", e.particles_per_cell, 0, 512, true, false);
  }
  for (std::size_t i = 0; i < output.attributes.size(); ++i) {
    const auto& a = output.attributes[i];
    if (a == "J" || a == "plastic")
      fail(source, "output.attributes[" + std::to_string(i) + "]",
           "solver.type \"flip\" writes \"position\", \"velocity\", \"material\" and \"id\" (its liquid is incompressible), got \"" + a + "\"");
  }
}

void Scene::validate() const {
  const Checker c{source};
  const int dim = solver.dimension;
  if (dim != 2 && dim != 3) fail(source, "solver.dimension", "expected 2 or 3, got " + std::to_string(dim));
  // Solvers and integrators this build provides (each branch of the engine enables its own).
  const bool flip = solver.type == SolverType::FLIP;
  const bool fem = solver.type == SolverType::FEM;
  if (flip && solver.integrator != Integrator::Explicit)
    fail(source, "solver.integrator", "expected \"explicit\" for solver.type \"flip\" (\"implicit\" is for MPM solids and FEM)");
  if (solver.integrator == Integrator::Implicit && !fem)
    for (std::size_t i = 0; i < materials.size(); ++i)
      if (materials[i].model == ElasticModel::Fluid)
        fail(source, "solver.integrator",
             "\"implicit\" is for solids; materials[" + std::to_string(i) + "] (\"" + materials[i].name +
                 "\") is a \"fluid\", which runs with \"explicit\" only");
  for (std::size_t i = 0; i < bodies.size(); ++i) {
    const auto& b = bodies[i];
    const std::string p = "bodies[" + std::to_string(i) + "]";
    if (!b.mesh.empty() && !fem && b.shape != Shape::Mesh)
      fail(source, p + ".mesh", "a triangle mesh is filled with particles by \"shape\": \"mesh\" (TetGen meshes are for solver.type \"fem\")");
    if (b.shape == Shape::Mesh && !fem) {
      if (b.mesh.empty()) fail(source, p + ".mesh", "missing (expected the path of a closed triangle mesh, .obj or .ply)");
      if (dim != 3) fail(source, p + ".shape", "\"mesh\" bodies are 3D (solver.dimension is 2)");
      for (int d = 0; d < 3; ++d)
        if (!(std::abs(b.scale[d]) > 0))
          fail(source, p + ".scale[" + std::to_string(d) + "]", "expected a non-zero factor, got " + fmt_num(b.scale[d]));
    }
  }
  if (fem) validate_fem(*this);

  // Domain.
  c.positive("domain.dx", domain.dx);
  for (int d = 0; d < dim; ++d)
    if (!(domain.max[d] > domain.min[d]))
      fail(source, "domain.max", "expected every component greater than domain.min " + vec_str(domain.min, dim) +
                                     ", got " + vec_str(domain.max, dim));
  double nodes = 1, blocks = 1;
  for (int d = 0; d < dim; ++d) {
    const double n = std::ceil((domain.max[d] - domain.min[d]) / domain.dx - 1e-9);
    if (n < 4) fail(source, "domain.dx", "expected at least 4 cells along each axis, got " + fmt_num(n));
    nodes *= n + 7;
    blocks *= std::ceil((n + 7) / (dim == 3 ? 4 : 8));
  }
  const bool dense = domain.grid == GridKind::Dense || (domain.grid == GridKind::Auto && solver.integrator == Integrator::Implicit);
  if (domain.grid == GridKind::Sparse && solver.integrator == Integrator::Implicit)
    fail(source, "domain.grid", "expected \"dense\" or \"auto\" with solver.integrator \"implicit\" (its solve runs on the dense grid)");
  if (dense && nodes > 2.0e9)
    fail(source, "domain.dx",
         "the dense grid would have " + fmt_num(nodes) + " nodes (limit 2e9); use a larger dx or domain.grid \"sparse\"");
  // The sparse grid's page table holds one int32 per block of the domain (two tables: grid and
  // particle bins), so 2^28 blocks cost 2 GiB.
  if (blocks > double(1 << 28))
    fail(source, "domain.dx", "the sparse grid's page table would have " + fmt_num(blocks) + " blocks (limit 2^28); use a larger dx");

  // Float positions far from the origin. A float resolves a coordinate x only to its spacing
  // there, up to 2^-23 |x|: at 1e4 m that is 1e-3 m, a twentieth of a 2 cm cell, and slow
  // motions (under spacing / (2 dt)) do not move particles at all. Measured on a block landing
  // at dx = 1/32 m (tests/extremes/precision_test.cpp): shifted to 1e4 m its centre of mass ends
  // 0.13 cells off and its energy grows 5%; at 1e3 m, 0.004 cells. Coordinates are allowed up
  // to kMaxFloatCells cells, where the spacing is at most 1/256 of a cell.
  if (solver.precision == Precision::Float) {
    constexpr double kMaxFloatCells = 32768;
    double far = 0;
    for (int d = 0; d < dim; ++d) far = std::max({far, std::abs(domain.min[d]), std::abs(domain.max[d])});
    const auto g3 = [](double x) {
      char b[32];
      std::snprintf(b, sizeof b, "%.3g", x);
      return std::string(b);
    };
    if (far / domain.dx > kMaxFloatCells)
      fail(source, "solver.precision",
           "\"float\" resolves positions " + g3(far) + " m from the origin only to " + g3(far * 0x1p-23) +
               " m, " + g3(far * 0x1p-23 / domain.dx) + " of a cell of domain.dx = " + fmt_num(domain.dx) +
               " m; expected every domain coordinate within 32768 cells (" + g3(kMaxFloatCells * domain.dx) +
               " m) of the origin: use \"precision\": \"double\", or move the scene's origin into the domain");
  }

  // Solver.
  if (solver.transfer == TransferKind::MLS && solver.kernel == KernelKind::Linear)
    fail(source, "solver.kernel",
         "transfer \"mls\" needs kernel \"quadratic\" or \"cubic\" (its D_p^-1 is not constant for the linear kernel)");
  c.in_range("solver.flip_ratio", solver.flip_ratio, 0, 1, false, false);
  c.in_range("solver.volume_correction", solver.volume_correction, 0, 1, false, false);
  c.in_range("solver.cfl", solver.cfl, 0, flip ? 5 : 1, true, false);
  c.in_range("solver.elastic_cfl", solver.elastic_cfl, 0, 1, true, false);
  c.positive("solver.max_dt", solver.max_dt);
  c.in_range("solver.cg_tolerance", solver.cg_tolerance, 0, 1, true, true);
  if (solver.cg_max_iterations < 1)
    fail(source, "solver.cg_max_iterations", "expected an integer >= 1, got " + std::to_string(solver.cg_max_iterations));
  if (solver.max_retries < 1 || solver.max_retries > 30)
    fail(source, "solver.max_retries", "expected an integer in [1, 30], got " + std::to_string(solver.max_retries));

  if (flip) validate_flip();
  if (!flip && !emitters.empty()) fail(source, "emitters", "emitters need solver.type \"flip\"");

  // Materials.
  if (materials.empty()) fail(source, "materials", "expected at least one material");
  for (std::size_t i = 0; i < materials.size(); ++i) {
    const auto& m = materials[i];
    const std::string p = "materials[" + std::to_string(i) + "]";
    if (m.name.empty()) fail(source, p + ".name", "expected a non-empty name");
    for (std::size_t j = 0; j < i; ++j)
      if (materials[j].name == m.name) fail(source, p + ".name", "duplicate material name \"" + m.name + "\"");
    c.positive(p + ".density", m.density);
    if (!flip && m.surface_tension != 0)
      fail(source, p + ".surface_tension",
           "the surface tension of a liquid is a key of solver.type \"flip\" (expected 0, got " + fmt_num(m.surface_tension) + ")");
    if (!flip && m.viscosity != 0)
      fail(source, p + ".viscosity", "the viscosity of a liquid is a key of solver.type \"flip\" (expected 0, got " +
                                         fmt_num(m.viscosity) + ")");
    if (m.model == ElasticModel::Fluid) {
      c.positive(p + ".bulk_modulus", m.bulk_modulus);
      c.in_range(p + ".gamma", m.gamma, 1, 20, false, false);
      if (m.plasticity != PlasticModel::None)
        fail(source, p + ".plasticity", "a \"fluid\" material takes no plasticity (expected \"none\")");
    } else {
      c.positive(p + ".E", m.E);
      c.in_range(p + ".nu", m.nu, -1, 0.5, true, true);
    }
    switch (m.plasticity) {
      case PlasticModel::Snow:
        c.in_range(p + ".critical_compression", m.critical_compression, 0, 1, true, true);
        c.positive(p + ".critical_stretch", m.critical_stretch);
        c.non_negative(p + ".hardening", m.hardening);
        break;
      case PlasticModel::DruckerPrager:
        c.in_range(p + ".friction_angle", m.friction_angle, 0, 90, true, true);
        break;
      case PlasticModel::VonMises:
        c.positive(p + ".yield_stress", m.yield_stress);
        break;
      case PlasticModel::None:
        break;
    }
  }

  // Sleeping material.
  c.non_negative("solver.sleep.speed", solver.sleep.speed);
  c.non_negative("solver.sleep.wake_speed", solver.sleep.wake_speed);
  if (solver.sleep.speed > 0) {
    c.positive("solver.sleep.strain_rate", solver.sleep.strain_rate);
    if (solver.sleep.substeps < 1 || solver.sleep.substeps > 65535)
      fail(source, "solver.sleep.substeps", "expected an integer in [1, 65535], got " + std::to_string(solver.sleep.substeps));
    if (solver.type != SolverType::MPM)
      fail(source, "solver.sleep.speed", "sleeping material is for solver.type \"mpm\" (expected 0)");
    if (solver.integrator == Integrator::Implicit)
      fail(source, "solver.sleep.speed", "sleeping material is for the \"explicit\" integrator (expected 0 with \"implicit\")");
  }

  // Bodies.
  if (bodies.empty() && emitters.empty())
    fail(source, "bodies", flip ? "expected at least one body or emitter" : "expected at least one body");
  for (std::size_t i = 0; i < bodies.size(); ++i) {
    const auto& b = bodies[i];
    const std::string p = "bodies[" + std::to_string(i) + "]";
    if (material_index(b.material) < 0) {
      std::string known;
      for (const auto& m : materials) known += (known.empty() ? "\"" : ", \"") + m.name + "\"";
      fail(source, p + ".material", "expected the name of a material (" + known + "), got \"" + b.material + "\"");
    }
    c.positive(p + ".particles_per_cell", b.particles_per_cell);
    if (b.particles_per_cell > 512) fail(source, p + ".particles_per_cell", "expected at most 512, got " + fmt_num(b.particles_per_cell));
    if (!b.mesh.empty()) continue;  // a mesh body's extent is checked when the mesh is read
    Eigen::Vector3d lo = b.min, hi = b.max;
    for (std::size_t j = 0; j < i; ++j)
      if (bodies[j].mesh.empty() && overlap(b, bodies[j], dim))
        fail(source, p, "overlaps bodies[" + std::to_string(j) + "] (expected bodies that share no volume: the overlap would hold two sets of particles)");
    switch (b.shape) {
      case Shape::Box:
        for (int d = 0; d < dim; ++d)
          if (!(b.max[d] > b.min[d]))
            fail(source, p + ".max", "expected every component greater than min " + vec_str(b.min, dim) +
                                         " (an empty box), got " + vec_str(b.max, dim));
        break;
      case Shape::Sphere:
        c.positive(p + ".radius", b.radius);
        lo = b.center.array() - b.radius;
        hi = b.center.array() + b.radius;
        break;
      case Shape::Cylinder:
        c.positive(p + ".radius", b.radius);
        c.positive(p + ".height", b.height);
        if (b.axis < 0 || b.axis >= dim)
          fail(source, p + ".axis", "expected an axis index in [0, " + std::to_string(dim - 1) + "], got " + std::to_string(b.axis));
        lo = b.center.array() - b.radius;
        hi = b.center.array() + b.radius;
        lo[b.axis] = b.center[b.axis] - 0.5 * b.height;
        hi[b.axis] = b.center[b.axis] + 0.5 * b.height;
        break;
      case Shape::Mesh:
        break;  // unreachable: a mesh body names its file
    }
    for (int d = 0; d < dim; ++d)
      if (lo[d] < domain.min[d] || hi[d] > domain.max[d])
        fail(source, p, "the body spans " + vec_str(lo, dim) + " to " + vec_str(hi, dim) +
                            ", expected it inside the domain " + vec_str(domain.min, dim) + " to " +
                            vec_str(domain.max, dim));
    // A body narrower than one particle spacing (FEM: one cell) seeds a single row of particles
    // or one particle: almost surely a unit slip, never what the scene means.
    const double spacing = fem ? domain.dx : domain.dx / std::pow(b.particles_per_cell, 1.0 / dim);
    for (int d = 0; d < dim; ++d)
      if (hi[d] - lo[d] < spacing)
        fail(source, p, "the body is " + fmt_num(hi[d] - lo[d]) + " m across along axis " + std::to_string(d) +
                            ", expected at least one " + (fem ? "cell (domain.dx = " : "particle spacing (dx / particles_per_cell^(1/dimension) = ") +
                            fmt_num(spacing) + " m)");
  }

  // Boundaries and colliders.
  c.non_negative("boundaries.friction", boundaries.friction);
  if (boundaries.friction > 0 && boundaries.walls != Condition::Separate)
    fail(source, "boundaries.friction", "friction applies to walls \"separate\" only");
  if (boundaries.thickness < 1 || boundaries.thickness > 8)
    fail(source, "boundaries.thickness", "expected an integer in [1, 8], got " + std::to_string(boundaries.thickness));
  for (std::size_t i = 0; i < colliders.size(); ++i) {
    const auto& k = colliders[i];
    const std::string p = "colliders[" + std::to_string(i) + "]";
    c.non_negative(p + ".friction", k.friction);
    if (k.friction > 0 && k.condition != Condition::Separate)
      fail(source, p + ".friction", "friction applies to condition \"separate\" only");
    switch (k.shape) {
      case ColliderShape::HalfSpace:
        if (!(k.normal.head(dim).norm() > 0)) fail(source, p + ".normal", "expected a non-zero vector");
        break;
      case ColliderShape::Box:
        for (int d = 0; d < dim; ++d)
          if (!(k.max[d] > k.min[d]))
            fail(source, p + ".max", "expected every component greater than min " + vec_str(k.min, dim) + ", got " + vec_str(k.max, dim));
        break;
      case ColliderShape::Sphere:
        c.positive(p + ".radius", k.radius);
        break;
      case ColliderShape::Mesh:
        if (k.mesh.empty()) fail(source, p + ".mesh", "missing (expected the path of a closed triangle mesh, .obj or .ply)");
        if (dim != 3) fail(source, p + ".shape", "\"mesh\" colliders are 3D (solver.dimension is 2)");
        for (int d = 0; d < 3; ++d)
          if (!(std::abs(k.scale[d]) > 0))
            fail(source, p + ".scale[" + std::to_string(d) + "]", "expected a non-zero factor, got " + fmt_num(k.scale[d]));
        for (std::size_t j = 1; j < k.keyframes.size(); ++j)
          if (!(k.keyframes[j].time > k.keyframes[j - 1].time))
            fail(source, p + ".keyframes[" + std::to_string(j) + "].time",
                 "expected times in increasing order: " + fmt_num(k.keyframes[j].time) + " follows " + fmt_num(k.keyframes[j - 1].time));
        break;
    }
    if (k.shape != ColliderShape::Mesh && (!k.mesh.empty() || !k.keyframes.empty()))
      fail(source, p + (k.mesh.empty() ? ".keyframes" : ".mesh"), "\"mesh\" and \"keyframes\" belong to \"shape\": \"mesh\"");
  }

  // Output.
  c.positive("output.fps", output.fps);
  c.in_range("output.fps", output.fps, 1e-6, 1e6, false, false);
  if (output.frames < 0) fail(source, "output.frames", "expected an integer >= 0, got " + std::to_string(output.frames));
  if (output.directory.empty()) fail(source, "output.directory", "expected a non-empty path");
  c.in_range("output.error_order", output.error_order, 0, 8, true, false);
  if (output.error_estimate && solver.type == SolverType::FEM)
    fail(source, "output.error_estimate",
         "the shadow simulation at twice domain.dx is for solver.type \"mpm\" and \"flip\" (FEM has no grid), "
         "expected false");
  if (output.checkpoint_every < 0)
    fail(source, "output.checkpoint_every", "expected an integer >= 0 (0 = no checkpoints), got " + std::to_string(output.checkpoint_every));
  for (const auto& [key, value] : {std::pair<const char*, double>{"output.mass_drift", output.mass_drift},
                                   {"output.volume_drift", output.volume_drift},
                                   {"output.energy_growth", output.energy_growth}})
    if (!(value >= 0 && value <= 1e300)) fail(source, key, "expected a number >= 0, got " + fmt_num(value));
  bool position = false;
  for (const auto& a : output.attributes) position = position || a == "position";
  if (!position)
    fail(source, "output.attributes", "expected a list that includes \"position\" (a frame without positions is no frame), got " +
                                          std::to_string(output.attributes.size()) + " attributes without it");
  // Limits and the time-step floor: what can be known before the run.
  c.non_negative("limits.memory_gb", limits.memory_gb);
  if (limits.substeps_per_frame < 1)
    fail(source, "limits.substeps_per_frame", "expected an integer >= 1, got " + std::to_string(limits.substeps_per_frame));
  const double per_frame = double(limits.substeps_per_frame);
  if (frame_dt() / solver.max_dt > per_frame)
    fail(source, "solver.max_dt",
         fmt_num(solver.max_dt) + " s would take " + fmt_num(frame_dt() / solver.max_dt) + " substeps per frame of " +
             fmt_num(frame_dt()) + " s, more than limits.substeps_per_frame = " + std::to_string(limits.substeps_per_frame) +
             " (expected a larger solver.max_dt)");
  if (frame_dt() / elastic_dt() > per_frame)
    fail(source, "solver.elastic_cfl",
         "the elastic limit elastic_cfl dx / c = " + fmt_num(elastic_dt()) + " s would take " + fmt_num(frame_dt() / elastic_dt()) +
             " substeps per frame, more than limits.substeps_per_frame = " + std::to_string(limits.substeps_per_frame) +
             " (expected a larger solver.elastic_cfl or domain.dx, or a softer material)");
  for (std::size_t i = 0; i < output.attributes.size(); ++i) {
    const auto& a = output.attributes[i];
    const std::string p = "output.attributes[" + std::to_string(i) + "]";
    bool known = false;
    for (const auto& k : kAttributes) known = known || k == a;
    if (!known)
      fail(source, p, "expected one of \"position\", \"velocity\", \"material\", \"J\", \"plastic\", \"id\", got \"" + a + "\"");
    if (a == "id" && solver.type == SolverType::FEM)
      fail(source, p, "\"id\" (persistent particle ids) is written by solver.type \"mpm\" and \"flip\", not \"fem\" (its vertices keep their order)");
    for (std::size_t j = 0; j < i; ++j)
      if (output.attributes[j] == a) fail(source, p, "duplicate attribute \"" + a + "\"");
    if (a == "plastic") {
      bool any = false;
      for (const auto& m : materials) any = any || m.plasticity != PlasticModel::None;
      if (!any) fail(source, p, "\"plastic\" needs a material with plasticity; this scene has none");
    }
  }
  validate_pipeline_outputs();
}

void Scene::validate_pipeline_outputs() const {
  const auto has = [&](const char* a) { return std::find(output.attributes.begin(), output.attributes.end(), a) != output.attributes.end(); };
  for (std::size_t i = 0; i < output.surface.size(); ++i) {
    const auto& f = output.surface[i];
    const std::string p = "output.surface[" + std::to_string(i) + "]";
    if (f != "vdb" && f != "ply" && f != "obj") fail(source, p, "expected one of \"vdb\", \"ply\", \"obj\", got \"" + f + "\"");
    for (std::size_t j = 0; j < i; ++j)
      if (output.surface[j] == f) fail(source, p, "duplicate format \"" + f + "\"");
  }
  if (!output.surface.empty() && solver.dimension != 3)
    fail(source, "output.surface", "surfaces are made of 3D scenes only (solver.dimension is " + std::to_string(solver.dimension) + ")");
  if ((!output.surface.empty() || output.vdb_points) && solver.type == SolverType::FEM)
    fail(source, output.vdb_points ? "output.vdb_points" : "output.surface",
         "solver.type \"fem\" writes meshes, not particles: surfaces and VDB points are for \"mpm\" and \"flip\"");
  if (output.per_rank && (!output.surface.empty() || output.vdb_points))
    fail(source, "output.per_rank",
         std::string("per-rank frames hold part of the particles each, and ") +
             (output.vdb_points ? "output.vdb_points" : "output.surface") +
             " is made from whole frames: expected output.per_rank false, or no pipeline outputs (make them from the "
             "frames `slurry merge` joins, with `slurry surface`)");
  if (output.vdb_points && !(has("velocity") && has("id")))
    fail(source, "output.vdb_points", "the points carry velocity and a persistent id: expected \"velocity\" and \"id\" in output.attributes");
  if (!(output.surface_voxel_size >= 0 && output.surface_voxel_size <= 1e300))
    fail(source, "output.surface_voxel_size", "expected a length >= 0 (0: domain.dx), got " + fmt_num(output.surface_voxel_size));
  if (output.surface_voxel_size > 0 && (output.surface_voxel_size > 100 * domain.dx || output.surface_voxel_size < 0.01 * domain.dx))
    fail(source, "output.surface_voxel_size", "expected a length within [0.01, 100] x domain.dx (" + fmt_num(domain.dx) + "), got " +
                                                  fmt_num(output.surface_voxel_size));
  const double vdb_voxel = output.surface_voxel_size > 0 ? output.surface_voxel_size : domain.dx;
  if ((!output.surface.empty() || output.vdb_points) && !(vdb_voxel >= kMinVoxelSize))
    fail(source, output.surface_voxel_size > 0 ? "output.surface_voxel_size" : "domain.dx",
         "the voxel of the OpenVDB outputs is " + fmt_num(vdb_voxel) +
             " m, below the " + fmt_num(kMinVoxelSize) + " m OpenVDB can represent; expected a larger output.surface_voxel_size, or the scene in larger units");
  if (output.up_axis != "y" && output.up_axis != "z")
    fail(source, "output.up_axis", "expected \"y\" (the simulation's axes) or \"z\", got \"" + output.up_axis + "\"");
  if (output.up_axis == "z" && solver.dimension != 3)
    fail(source, "output.up_axis", "\"z\" needs a 3D scene (2D frames have no z column); expected \"y\"");
  if (output.surface_method != "anisotropic" && output.surface_method != "spheres")
    fail(source, "output.surface_method", "expected \"anisotropic\" or \"spheres\", got \"" + output.surface_method + "\"");
  if (output.surface_smoothing < 0 || output.surface_smoothing > 100)
    fail(source, "output.surface_smoothing", "expected an integer in [0, 100], got " + std::to_string(output.surface_smoothing));
  // An MPM surface of some of the materials selects particles by the frame's material column.
  if (!output.surface.empty() && solver.type == SolverType::MPM && materials.size() > 1 && !has("material")) {
    std::size_t fluids = 0;
    for (const auto& m : materials) fluids += m.model == ElasticModel::Fluid;
    if (output.surface_per_material || (fluids > 0 && fluids < materials.size()))
      fail(source, "output.surface", "the surface is of some materials only (" +
                                         std::string(output.surface_per_material ? "output.surface_per_material" : "the \"fluid\" ones") +
                                         "): expected \"material\" in output.attributes");
  }
  if (!output.surface.empty() && solver.type == SolverType::FLIP && output.surface_per_material && materials.size() > 1 && !has("material"))
    fail(source, "output.surface_per_material", "one surface per material: expected \"material\" in output.attributes");
}

std::filesystem::path Scene::resolve(const std::string& file) const {
  const std::filesystem::path p(file);
  if (p.is_absolute()) return p;
  return std::filesystem::path(source).parent_path() / p;
}

double Scene::elastic_dt() const {
  if (solver.type != SolverType::MPM || solver.integrator == Integrator::Implicit) return std::numeric_limits<double>::infinity();
  double c = 0;
  for (const auto& m : materials) c = std::max(c, wave_speed(m));
  const double kernel_factor = solver.kernel == KernelKind::Linear ? 0.25 : 1.0;  // as MpmSolver::stable_dt
  return c > 0 ? kernel_factor * solver.elastic_cfl * domain.dx / c : std::numeric_limits<double>::infinity();
}

namespace {
/// The particles (or, FEM, elements) body `b` of `scene` seeds, estimated before any is made. A
/// mesh body's count is its enclosed volume over the lattice cell once the mesh file is read
/// (Scene::files), 0 before: the file's size bounds what reading it allocates.
double body_items(const Scene& scene, const BodyParams& b) {
  const int dim = scene.solver.dimension;
  const bool fem = scene.solver.type == SolverType::FEM;
  if (!b.mesh.empty()) {
    if (fem || !scene.files) return 0;
    const auto it = scene.files->triangle_meshes.find(b.mesh);
    if (it == scene.files->triangle_meshes.end()) return 0;
    const double h = scene.domain.dx / std::cbrt(b.particles_per_cell);
    return std::abs(it->second.signed_volume() * b.scale.prod()) / (h * h * h);
  }
  Eigen::Vector3d lo, hi;
  double fill, lattice = 1;
  body_extent(b, dim, lo, hi, fill);
  const double h = fem ? scene.domain.dx : scene.domain.dx / std::pow(b.particles_per_cell, 1.0 / dim);
  for (int d = 0; d < dim; ++d) lattice *= std::max(1.0, std::round((hi[d] - lo[d]) / h));
  return fem ? lattice * (dim == 3 ? 6 : 2)  // box_mesh: 6 tetrahedra per cube, 2 triangles per square
             : lattice * fill;
}

/// The scene path of the body that seeds the most: "bodies[i]", or "bodies[i].mesh".
std::string largest_body(const Scene& scene) {
  std::size_t best = 0;
  double most = -1;
  for (std::size_t i = 0; i < scene.bodies.size(); ++i)
    if (const double n = body_items(scene, scene.bodies[i]); n > most) most = n, best = i;
  if (scene.bodies.empty()) return "bodies";
  return "bodies[" + std::to_string(best) + "]" + (scene.bodies[best].mesh.empty() ? "" : ".mesh");
}
}  // namespace

ResourceEstimate Scene::estimate() const {
  const int dim = solver.dimension;
  const bool fem = solver.type == SolverType::FEM, flip = solver.type == SolverType::FLIP;
  const double real = solver.precision == Precision::Double ? 8 : 4;
  ResourceEstimate e;
  for (const auto& b : bodies) (fem ? e.elements : e.particles) += body_items(*this, b);
  double cells = 1, nodes = 1;
  for (int d = 0; d < dim; ++d) {
    const double n = std::ceil((domain.max[d] - domain.min[d]) / domain.dx - 1e-9);
    cells *= n;
    nodes *= n + 7;
  }
  const bool dense = domain.grid == GridKind::Dense || (domain.grid == GridKind::Auto && solver.integrator == Integrator::Implicit);
  // Bytes per item: rough upper bounds of the solvers' channels (position, velocity, mass,
  // volume, F, C and the stress, bins; FLIP face velocities, weights, pressure, PCG and
  // multigrid vectors; FEM element matrices and, implicit, the assembled stiffness).
  const double particle_bytes = real * (2 * dim + 2 + (flip ? dim * dim : 3 * dim * dim)) + 16;
  if (flip) e.grid_nodes = cells;
  else if (!fem && dense) e.grid_nodes = nodes;
  const double node_bytes = flip ? real * (3 * dim + 8) + 4 : real * (2 + 2 * dim) * (solver.integrator == Integrator::Implicit ? 4 : 1);
  const double element_bytes = 200 + (solver.integrator == Integrator::Implicit ? 12.0 * (dim + 1) * dim * (dim + 1) * dim : 0);
  e.bytes = e.particles * particle_bytes + e.grid_nodes * node_bytes + e.elements * element_bytes;
  // FLIP whitewater at its cap: position, velocity, lifetime, id and type per particle, twice
  // over (vector growth), plus its per-cell velocity, depth, layers and counts (whitewater.h).
  if (flip && solver.whitewater.enabled)
    e.bytes += double(solver.whitewater.max_particles) * 2 * (real * (2 * dim + 1) + 4 + 1) + cells * (real * (dim + 1) + 6);
  return e;
}

double physical_memory_bytes() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? double(pages) * double(page) : 0;
}

void check_resources(const Scene& scene, double memory_gb) {
  const ResourceEstimate e = scene.estimate();
  const auto error = [&](const std::string& path, const std::string& what) {
    throw ResourceError(scene.source + ": " + path + ": " + what);
  };
  // Particle, vertex and element indices are 32-bit.
  if (e.particles > 2e9) error(largest_body(scene), "the bodies would seed " + fmt_num(e.particles) + " particles (limit 2e9); expected fewer or larger particles (particles_per_cell, domain.dx)");
  if (e.elements > 2e9) error(largest_body(scene), "the bodies would mesh " + fmt_num(e.elements) + " elements (limit 2e9); expected a larger domain.dx");
  std::string limit_name = "limits.memory_gb";
  double gb = memory_gb > 0 ? memory_gb : scene.limits.memory_gb;
  if (memory_gb > 0) limit_name = "--memory-limit";
  if (gb <= 0) {
    gb = physical_memory_bytes() / double(1 << 30);
    limit_name = "the machine's memory";
  }
  if (gb <= 0 || e.bytes <= gb * double(1 << 30)) return;
  const double p = e.particles, g = e.grid_nodes, m = e.elements;
  const std::string what = p >= g && p >= m ? fmt_num(p) + " particles seeded by the bodies"
                           : g >= m         ? fmt_num(g) + (scene.solver.type == SolverType::FLIP ? " grid cells" : " dense grid nodes")
                                            : fmt_num(m) + " mesh elements";
  char size[64];
  std::snprintf(size, sizeof size, "%.3g GiB, more than %.3g GiB (", e.bytes / double(1 << 30), gb);
  error(p >= g && p >= m ? largest_body(scene) : g >= m ? "domain.dx" : largest_body(scene),
        "the run would need about " + std::string(size) + limit_name + ") for " + what +
            "; expected a smaller scene, or raise the limit with limits.memory_gb or --memory-limit");
}

}  // namespace slurry
