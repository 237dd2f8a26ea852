#pragma once
// The scenes the FLIP tests build: one liquid in a 2D double-precision FLIP domain [0, w] x [0, h]
// (linear kernel, cfl 1, pressure tolerance 1e-8) and boxes of it.
#include <cmath>
#include <cstddef>
#include <string>

#include "slurry/engine/errors.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"

namespace slurry_test {

/// One liquid `name` of density 1000 and dynamic viscosity `viscosity`; bodies are the caller's.
inline slurry::Scene liquid_scene(double w, double h, double dx, slurry::TransferKind transfer, double max_dt,
                                  const char* name, double viscosity = 0) {
  slurry::Scene s;
  s.source = "test";
  s.solver.type = slurry::SolverType::FLIP;
  s.solver.dimension = 2;
  s.solver.precision = slurry::Precision::Double;
  s.solver.transfer = transfer;
  s.solver.kernel = slurry::KernelKind::Linear;
  s.solver.cfl = 1;
  s.solver.max_dt = max_dt;
  s.solver.pressure.tolerance = 1e-8;
  s.domain.max = {w, h, 0};
  s.domain.dx = dx;
  slurry::MaterialParams m;
  m.name = name;
  m.model = slurry::ElasticModel::Fluid;
  m.density = 1000;
  m.viscosity = viscosity;
  s.materials = {m};
  return s;
}

/// A box [x0, x1] x [y0, y1] of `material`, seeded at `ppc` particles per cell.
inline slurry::BodyParams liquid_box(double x0, double y0, double x1, double y1, const char* material,
                                     double ppc = 4) {
  slurry::BodyParams b;
  b.shape = slurry::Shape::Box;
  b.min = {x0, y0, 0};
  b.max = {x1, y1, 0};
  b.material = material;
  b.particles_per_cell = ppc;
  return b;
}

/// Sets the particles' velocity (and APIC's affine vectors) to the linear standing wave of mode k
/// in water of depth h: the potential flow phi = (a / k) cos(k x) cosh(k y), a = amplitude
/// omega / sinh(k h), so u = -a sin(kx) cosh(ky), v = a cos(kx) sinh(ky).
template <class Particles>
void standing_wave_velocity(Particles& P, double k, double h, double omega, double amplitude) {
  const double a = amplitude * omega / std::sinh(k * h);
  for (std::size_t p = 0; p < P.size(); ++p) {
    const double x = P.x[p][0], y = P.x[p][1];
    P.v[p] = {-a * std::sin(k * x) * std::cosh(k * y), a * std::cos(k * x) * std::sinh(k * y)};
    if (P.affine) {
      P.c[0][p] = {-a * k * std::cos(k * x) * std::cosh(k * y), -a * k * std::sin(k * x) * std::sinh(k * y)};
      P.c[1][p] = {-a * k * std::sin(k * x) * std::sinh(k * y), a * k * std::cos(k * x) * std::cosh(k * y)};
    }
  }
}

/// A 2D scene file's text: `solver` (a JSON object), `materials` (JSON objects, the first named
/// "a"), one box of "a"; for the bad-key tests.
inline std::string material_scene_text(const std::string& solver, const std::string& materials) {
  return R"({"domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05}, "solver": )" + solver + R"(, "materials": [)" +
         materials + R"(], "bodies": [{"shape": "box", "min": [0, 0], "max": [1, 0.4], "material": "a"}]})";
}

/// The SceneError parse_scene() throws for `text` (as "bad.json"), or "accepted".
inline std::string scene_error(const std::string& text) {
  try {
    slurry::parse_scene(text, "bad.json");
  } catch (const slurry::SceneError& e) {
    return std::string(e.what());
  }
  return std::string("accepted");
}

}  // namespace slurry_test
