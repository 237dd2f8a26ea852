// solver.quality presets (quality.h): a preset sets its knobs, explicit keys in the scene win,
// the seeding density of bodies follows the preset unless a body gives its own, and an unknown
// name is an error listing the allowed ones.
#include <gtest/gtest.h>

#include <string>

#include "slurry/engine/scene/quality.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"

namespace {

std::string mpm_scene(const std::string& solver, const std::string& body_extra = "") {
  return R"({"solver": {"dimension": 2)" + solver + R"(},
    "materials": [{"name": "jelly"}],
    "bodies": [{"min": [0.4, 0.4], "max": [0.6, 0.6], "material": "jelly")" + body_extra + R"(}]})";
}

std::string flip_scene(const std::string& solver) {
  return R"({"solver": {"dimension": 2, "type": "flip")" + solver + R"(},
    "materials": [{"name": "water", "model": "fluid"}],
    "bodies": [{"min": [0, 0], "max": [0.5, 0.5], "material": "water"}]})";
}

TEST(Quality, PresetsSetTheirKnobsMpm) {
  const slurry::Scene none = slurry::parse_scene(mpm_scene(""), "none.json");
  for (std::string_view q : slurry::kQualityPresets) {
    const slurry::Scene s = slurry::parse_scene(mpm_scene(R"(, "quality": ")" + std::string(q) + "\""), "q.json");
    // What the parser gives must be exactly what apply_quality does to the unset scene.
    slurry::Scene expected = none;
    const double ppc = slurry::apply_quality(expected, q);
    EXPECT_EQ(s.solver.precision, expected.solver.precision) << q;
    EXPECT_EQ(s.solver.transfer, expected.solver.transfer) << q;
    EXPECT_EQ(s.solver.kernel, expected.solver.kernel) << q;
    EXPECT_EQ(s.solver.cfl, expected.solver.cfl) << q;
    EXPECT_EQ(s.solver.elastic_cfl, expected.solver.elastic_cfl) << q;
    EXPECT_EQ(s.solver.max_dt, expected.solver.max_dt) << q;
    EXPECT_EQ(s.bodies[0].particles_per_cell, ppc) << q;
  }
  // The values docs/accuracy.md documents for MPM.
  const auto preview = slurry::parse_scene(mpm_scene(R"(, "quality": "preview")"), "p.json");
  const auto production = slurry::parse_scene(mpm_scene(R"(, "quality": "production")"), "p.json");
  const auto reference = slurry::parse_scene(mpm_scene(R"(, "quality": "reference")"), "r.json");
  EXPECT_EQ(preview.bodies[0].particles_per_cell, 4);
  EXPECT_EQ(production.bodies[0].particles_per_cell, none.bodies[0].particles_per_cell);
  for (const auto* s : {&preview, &production}) {
    EXPECT_EQ(s->solver.precision, none.solver.precision);
    EXPECT_EQ(s->solver.transfer, none.solver.transfer);
    EXPECT_EQ(s->solver.kernel, none.solver.kernel);
    EXPECT_EQ(s->solver.elastic_cfl, none.solver.elastic_cfl);
    EXPECT_EQ(s->solver.max_dt, none.solver.max_dt);
  }
  EXPECT_EQ(reference.solver.precision, slurry::Precision::Double);
  EXPECT_EQ(reference.solver.elastic_cfl, none.solver.elastic_cfl);
  EXPECT_EQ(reference.solver.max_dt, none.solver.max_dt);
  EXPECT_EQ(reference.bodies[0].particles_per_cell, 16);
}

TEST(Quality, PresetsSetTheirKnobsFlip) {
  const auto preview = slurry::parse_scene(flip_scene(R"(, "quality": "preview")"), "p.json");
  const auto production = slurry::parse_scene(flip_scene(R"(, "quality": "production")"), "p.json");
  const auto reference = slurry::parse_scene(flip_scene(R"(, "quality": "reference")"), "r.json");
  // A FLIP preset also sets the transfer, which a FLIP scene must otherwise give.
  for (const auto* s : {&preview, &production, &reference}) {
    EXPECT_EQ(s->solver.transfer, slurry::TransferKind::APIC);
    EXPECT_EQ(s->solver.pressure.preconditioner, slurry::PressurePreconditioner::Multigrid);
  }
  EXPECT_EQ(preview.solver.max_dt, 1.0 / 60);
  EXPECT_EQ(preview.solver.cfl, 2);
  EXPECT_EQ(preview.solver.kernel, slurry::KernelKind::Quadratic);
  EXPECT_EQ(preview.solver.pressure.tolerance, 1e-4);
  EXPECT_EQ(preview.bodies[0].particles_per_cell, 4);
  for (const auto* s : {&production, &reference}) {
    EXPECT_EQ(s->solver.max_dt, 1.0 / 240);
    EXPECT_EQ(s->solver.cfl, 1);
    EXPECT_EQ(s->solver.kernel, slurry::KernelKind::Linear);
    EXPECT_EQ(s->bodies[0].particles_per_cell, 8);
  }
  EXPECT_EQ(production.solver.precision, slurry::Precision::Float);
  EXPECT_EQ(production.solver.pressure.tolerance, 1e-6);
  EXPECT_EQ(reference.solver.precision, slurry::Precision::Double);
  EXPECT_EQ(reference.solver.pressure.tolerance, 1e-8);
}

TEST(Quality, ExplicitKeysWin) {
  const auto s = slurry::parse_scene(
      mpm_scene(R"(, "quality": "reference", "precision": "float", "transfer": "pic", "elastic_cfl": 0.7, "cfl": 0.9)",
                R"(, "particles_per_cell": 3)"),
      "x.json");
  EXPECT_EQ(s.solver.precision, slurry::Precision::Float);
  EXPECT_EQ(s.solver.transfer, slurry::TransferKind::PIC);
  EXPECT_EQ(s.solver.elastic_cfl, 0.7);
  EXPECT_EQ(s.solver.cfl, 0.9);
  EXPECT_EQ(s.bodies[0].particles_per_cell, 3);
  // A key given before "quality" in the file wins too: the preset is applied before any key.
  const auto f = slurry::parse_scene(flip_scene(R"(, "max_dt": 0.002, "quality": "preview", "pressure": {"tolerance": 1e-7})"),
                                     "f.json");
  EXPECT_EQ(f.solver.max_dt, 0.002);
  EXPECT_EQ(f.solver.pressure.tolerance, 1e-7);
}

TEST(Quality, UnknownPresetNamesTheAllowedOnes) {
  try {
    slurry::parse_scene(mpm_scene(R"(, "quality": "ultra")"), "u.json");
    FAIL() << "an unknown preset was accepted";
  } catch (const slurry::SceneError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("u.json: solver.quality: expected one of \"preview\", \"production\", \"reference\", got \"ultra\""),
              std::string::npos)
        << msg;
  }
  EXPECT_THROW(slurry::parse_scene(mpm_scene(R"(, "quality": 2)"), "n.json"), slurry::SceneError);
  const std::string fem = R"({"solver": {"dimension": 2, "type": "fem", "quality": "preview"},
    "materials": [{"name": "rubber", "model": "corotated_linear"}],
    "bodies": [{"min": [0.4, 0.4], "max": [0.6, 0.6], "material": "rubber"}]})";
  EXPECT_THROW(slurry::parse_scene(fem, "fem.json"), slurry::SceneError);
}

}  // namespace
