// Mass and rest volume stored once while uniform (particles.h): the storage follows
// the values (once while every particle has the same bits, per particle from the first that
// differs), and it changes no bit of a simulation, of its checkpoints or of its statistics.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "mpm/domain_split.h"
#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/io/scene_file.h"

namespace slurry {
namespace {

TEST(ScalarChannel, StoredOnceWhileUniformPerParticleFromTheFirstDifference) {
  ScalarChannel<float> c;
  for (std::size_t p = 0; p < 5; ++p) c.push_back(0.25f, p);
  EXPECT_TRUE(c.uniform());
  EXPECT_TRUE(c.values().empty());
  EXPECT_EQ(c.per_particle(), nullptr);
  EXPECT_EQ(c.bytes(), 0u);
  EXPECT_EQ(c[3], 0.25f);
  c.push_back(0.5f, 5);
  ASSERT_FALSE(c.uniform());
  ASSERT_EQ(c.values().size(), 6u);
  for (std::size_t p = 0; p < 5; ++p) EXPECT_EQ(c[p], 0.25f);
  EXPECT_EQ(c[5], 0.5f);
  EXPECT_EQ(c.per_particle(), c.values().data());
  c.push_back(0.25f, 6);  // per particle from then on
  EXPECT_FALSE(c.uniform());
  EXPECT_EQ(c.values().size(), 7u);

  // Equal means equal bits: 0 and -0 are stored per particle.
  ScalarChannel<double> z;
  z.push_back(0.0, 0);
  z.push_back(-0.0, 1);
  EXPECT_FALSE(z.uniform());

  // assign() stores once what is all equal, per particle otherwise; an empty set is uniform.
  z.assign({2.0, 2.0, 2.0});
  EXPECT_TRUE(z.uniform());
  EXPECT_EQ(z.value(), 2.0);
  z.assign({2.0, 3.0});
  EXPECT_FALSE(z.uniform());
  EXPECT_EQ(z[1], 3.0);
  z.assign({});
  EXPECT_TRUE(z.uniform());
}

TEST(Particles, UniformMassAndVolumeAreNeitherStoredNorMoved) {
  Particles<float, 3> P;
  P.channels.F = P.channels.C = true;
  for (int i = 0; i < 100; ++i)
    P.push_back(Eigen::Vector3f(float(i), 0, 0), Eigen::Vector3f::Zero(), 2.0f, 1e-3f, 0, 1);
  EXPECT_TRUE(P.m.uniform());
  EXPECT_TRUE(P.vol0.uniform());
  EXPECT_EQ(P.bytes(), P.x.capacity() * 12 + P.v.capacity() * 12 + P.F.capacity() * 36 +
                           P.C.capacity() * 36 + P.id.capacity() * 4);
  int visited = 0;
  P.for_each_channel([&](const auto&) { ++visited; });
  EXPECT_EQ(visited, 5);  // x, v, F, C, id

  // A particle of another mass: the mass is stored per particle (and moved), the volume not.
  P.push_back(Eigen::Vector3f::Zero(), Eigen::Vector3f::Zero(), 3.0f, 1e-3f, 0, 1);
  EXPECT_FALSE(P.m.uniform());
  EXPECT_TRUE(P.vol0.uniform());
  EXPECT_EQ(P.m.values().size(), P.size());
  EXPECT_EQ(P.m[0], 2.0f);
  EXPECT_EQ(P.m[100], 3.0f);
  visited = 0;
  P.for_each_channel([&](const auto&) { ++visited; });
  EXPECT_EQ(visited, 6);
  std::vector<std::uint8_t> drop(P.size(), 0);
  drop[0] = 1;
  detail::drop_particles(P, drop);
  EXPECT_EQ(P.m.values().size(), 100u);
  EXPECT_EQ(P.m[99], 3.0f);
  EXPECT_EQ(P.vol0[99], 1e-3f);
}

TEST(PackParticles, CarryHowMassAndVolumeAreStored) {
  auto make = [](float mass, float mass_of_last) {
    Particles<float, 2> P;
    for (int i = 0; i < 4; ++i)
      P.push_back(Eigen::Vector2f(float(i), 0), Eigen::Vector2f::Zero(),
                  i == 3 ? mass_of_last : mass, 0.5f, 0, 1);
    return P;
  };
  const auto uniform = make(2, 2), varying = make(2, 3);
  std::string u, v;
  detail::pack_particles(uniform, {1, 3}, u);
  detail::pack_particles(varying, {1, 3}, v);
  EXPECT_EQ(v.size(), u.size() + 2 * sizeof(float));  // the masses, per particle

  // An empty set takes the message's storage.
  Particles<float, 2> Q;
  detail::unpack_particles(u, Q);
  ASSERT_EQ(Q.size(), 2u);
  EXPECT_TRUE(Q.m.uniform());
  EXPECT_EQ(Q.m.value(), 2.0f);
  EXPECT_EQ(Q.vol0.value(), 0.5f);
  Particles<float, 2> R;
  detail::unpack_particles(v, R);
  EXPECT_FALSE(R.m.uniform());
  EXPECT_EQ(R.m[0], 2.0f);
  EXPECT_EQ(R.m[1], 3.0f);
  EXPECT_EQ(R.id[1], 3u);
  detail::unpack_particles(v, R);  // the same storage: appended
  EXPECT_EQ(R.m.values().size(), 4u);

  // A set with particles must store them as the message does: named, not misread.
  EXPECT_THROW(detail::unpack_particles(v, Q), SimulationError);
  EXPECT_THROW(detail::unpack_particles(u, R), SimulationError);
  std::string other;
  detail::pack_particles(make(5, 5), {0}, other);
  try {
    detail::unpack_particles(other, Q);
    ADD_FAILURE() << "a uniform mass of another value was accepted";
  } catch (const SimulationError& e) {
    EXPECT_NE(std::string(e.what()).find("mass"), std::string::npos) << e.what();
  }
  EXPECT_EQ(Q.size(), 2u);

  // empty_like: the storage without the particles.
  const auto E = varying.empty_like();
  EXPECT_EQ(E.size(), 0u);
  EXPECT_FALSE(E.m.uniform());
  EXPECT_TRUE(E.vol0.uniform());
  EXPECT_EQ(E.vol0.value(), 0.5f);
}

/// Jelly, snow and water of one density, seeded at one spacing (box sizes that are multiples of
/// it), thrown together: every particle has the same mass and rest volume, and the stress of
/// every branch (elastic, snow-hardened, fluid) is computed.
Scene one_density_scene(int dim, TransferKind transfer) {
  Scene s;
  s.source = "one density";
  s.solver.dimension = dim;
  s.solver.transfer = transfer;
  s.domain.dx = dim == 3 ? 1.0 / 16 : 1.0 / 32;
  MaterialParams jelly, snow, water;
  jelly.name = "jelly";
  jelly.E = 2e5;
  snow.name = "snow";
  snow.E = 1.4e5;
  snow.nu = 0.2;
  snow.plasticity = PlasticModel::Snow;
  water.name = "water";
  water.model = ElasticModel::Fluid;
  water.bulk_modulus = 5e4;
  s.materials = {jelly, snow, water};
  auto box = [&](const char* m, Eigen::Vector3d lo, Eigen::Vector3d hi, Eigen::Vector3d v) {
    BodyParams b;
    b.material = m;
    b.min = lo;
    b.max = hi;
    b.velocity = v;
    b.particles_per_cell = dim == 3 ? 8 : 4;
    b.sampling = Sampling::Jittered;
    return b;
  };
  s.bodies = {box("jelly", {0.25, 0.375, 0.25}, {0.5, 0.625, 0.5}, {2, 0, 0}),
              box("snow", {0.5625, 0.375, 0.25}, {0.8125, 0.625, 0.5}, {-2, 0, 0}),
              box("water", {0.125, 0.0625, 0.125}, {0.875, 0.1875, 0.875}, {0, 0, 0})};
  return s;
}

/// The state (every particle channel, time, limits; save_state) after `steps` substeps, and the
/// statistics, with mass and rest volume stored as seeded or per particle.
template <class T, int Dim>
std::string run(const Scene& s, bool per_particle, int steps) {
  MpmSolver<T, Dim> sim(s);
  auto& P = sim.particles();
  if (per_particle) {
    P.m.materialize(P.size());
    P.vol0.materialize(P.size());
  }
  for (int i = 0; i < steps; ++i) sim.step(sim.stable_dt());
  EXPECT_EQ(P.m.uniform(), !per_particle);
  std::string out;
  sim.save_state(out);
  const RunStats st = sim.take_stats();
  const double figures[] = {st.mass,
                            st.momentum[0],
                            st.momentum[1],
                            st.kinetic,
                            st.potential,
                            st.elastic,
                            st.volume,
                            double(sim.kinetic_energy()),
                            double(sim.elastic_energy())};
  out.append(reinterpret_cast<const char*>(figures), sizeof figures);
  return out;
}

TEST(UniformMass, SeedingStoresOnceWhatIsUniform) {
  {
    MpmSolver<float, 3> sim(one_density_scene(3, TransferKind::MLS));
    EXPECT_TRUE(sim.particles().m.uniform());
    EXPECT_TRUE(sim.particles().vol0.uniform());
  }
  Scene s = one_density_scene(2, TransferKind::MLS);
  s.materials[1].density = 400;  // snow: another mass, the same volume
  MpmSolver<float, 2> sim(s);
  const auto& P = sim.particles();
  EXPECT_FALSE(P.m.uniform());
  EXPECT_TRUE(P.vol0.uniform());
  double snow = 0, all = 0;
  for (std::size_t p = 0; p < P.size(); ++p) {
    all += double(P.m[p]);
    if (P.material[p] == 1) snow += double(P.m[p]);
  }
  EXPECT_NEAR(snow, 400 * 0.25 * 0.25, 1e-4);
  EXPECT_NEAR(all - snow, 1000 * (0.25 * 0.25 + 0.75 * 0.125), 1e-3);
}

TEST(UniformMass, StepsStatsAndStateAreBitwiseThoseOfPerParticleStorage) {
  for (const auto transfer : {TransferKind::MLS, TransferKind::APIC, TransferKind::FLIP}) {
    const std::string what = transfer == TransferKind::MLS    ? "MLS"
                             : transfer == TransferKind::APIC ? "APIC"
                                                              : "FLIP";
    EXPECT_TRUE((run<float, 3>(one_density_scene(3, transfer), false, 12) ==
                 run<float, 3>(one_density_scene(3, transfer), true, 12)))
        << "3D float " << what;
    EXPECT_TRUE((run<double, 3>(one_density_scene(3, transfer), false, 12) ==
                 run<double, 3>(one_density_scene(3, transfer), true, 12)))
        << "3D double " << what;
    EXPECT_TRUE((run<float, 2>(one_density_scene(2, transfer), false, 12) ==
                 run<float, 2>(one_density_scene(2, transfer), true, 12)))
        << "2D float " << what;
    EXPECT_TRUE((run<double, 2>(one_density_scene(2, transfer), false, 12) ==
                 run<double, 2>(one_density_scene(2, transfer), true, 12)))
        << "2D double " << what;
  }
  // The implicit update (its stiffness scales with the rest volume).
  Scene implicit = one_density_scene(2, TransferKind::APIC);
  implicit.materials.pop_back();
  implicit.bodies.pop_back();
  implicit.solver.integrator = Integrator::Implicit;
  EXPECT_TRUE((run<double, 2>(implicit, false, 6) == run<double, 2>(implicit, true, 6)))
      << "implicit";
}

TEST(UniformMass, CheckpointsKeepTheirFormatAndResumeStoredAsSeeded) {
  const Scene s = one_density_scene(3, TransferKind::MLS);
  MpmSolver<float, 3> a(s), b(s);
  b.particles().m.materialize(b.particles().size());
  std::string sa, sb;
  a.save_state(sa);
  b.save_state(sb);
  EXPECT_TRUE(sa == sb) << "a uniform mass is written as one value per particle";
  MpmSolver<float, 3> c(s);
  c.load_state(sb, "state");
  EXPECT_TRUE(c.particles().m.uniform());
  EXPECT_TRUE(c.particles().vol0.uniform());
  EXPECT_EQ(c.particles().m.value(), a.particles().m.value());
  for (int i = 0; i < 5; ++i) a.step(a.stable_dt()), c.step(c.stable_dt());
  sa.clear(), sb.clear();
  a.save_state(sa);
  c.save_state(sb);
  EXPECT_TRUE(sa == sb);

  // Masses that differ stay per particle, every value in place.
  Scene two = s;
  two.materials[1].density = 400;
  MpmSolver<float, 3> d(two), e(two);
  for (int i = 0; i < 3; ++i) d.step(d.stable_dt());
  std::string sd;
  d.save_state(sd);
  e.load_state(sd, "state");
  ASSERT_FALSE(e.particles().m.uniform());
  EXPECT_TRUE(e.particles().vol0.uniform());
  EXPECT_TRUE(e.particles().m.values() == d.particles().m.values());
  EXPECT_EQ(e.particles().vol0.value(), d.particles().vol0.value());
}

// Shipped scenes: sand (Hencky strain, Drucker-Prager) and the implicit update, each stepped with
// mass and rest volume stored once and stored per particle.
TEST(UniformMass, ExampleScenesStepBitwiseAsWithPerParticleStorage) {
  const std::string dir = SLURRY_EXAMPLES_DIR;
  const Scene sand = load_scene(dir + "/sand_column_2d.json");
  EXPECT_TRUE((run<float, 2>(sand, false, 100) == run<float, 2>(sand, true, 100)))
      << "sand_column_2d";
  const Scene bar = load_scene(dir + "/stiff_bar_implicit_3d.json");
  EXPECT_TRUE((run<float, 3>(bar, false, 3) == run<float, 3>(bar, true, 3)))
      << "stiff_bar_implicit_3d";
}

}  // namespace
}  // namespace slurry
