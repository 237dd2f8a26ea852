// What a run split over processes rests on, tested in one process (the runs under mpirun are
// tests/mpi): slab and box borders, the nodes a border block shares, particles packed for another rank, and frames that depend on the
// set of particles alone, not on the order they are stored in.
#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <random>

#include "determinism_scene.h"
#include "mpm/domain_split.h"
#include "slurry/transfer/lattice.h"
#include "slurry/engine/mpm/mpm_solver.h"

namespace slurry {
namespace {

TEST(BalancedCuts, SplitsAtTheMedianAndGivesEveryRankAColumn) {
  EXPECT_EQ(detail::balanced_cuts({0, 0, 10, 10, 10, 10, 0, 0}, 2), (std::vector<int>{0, 4, 8}));
  // All particles in one column: the other ranks still get a column each (particles move less
  // than a column per substep, so they only ever pass to a neighbour).
  EXPECT_EQ(detail::balanced_cuts({100, 0, 0, 0}, 4), (std::vector<int>{0, 1, 2, 3, 4}));
  EXPECT_EQ(detail::balanced_cuts({0, 0, 0, 100}, 3), (std::vector<int>{0, 2, 3, 4}));
  EXPECT_EQ(detail::balanced_cuts({5, 5, 5}, 1), (std::vector<int>{0, 3}));
}

TEST(BalancedCuts, NoSlabHoldsMoreThanTheMeanPlusOneColumn) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 500; ++trial) {
    const int columns = 1 + int(rng() % 40), ranks = 1 + int(rng() % unsigned(columns));
    std::vector<double> counts(static_cast<std::size_t>(columns));
    for (auto& c : counts) c = double(rng() % 3 == 0 ? 0 : rng() % 1000);
    const auto cuts = detail::balanced_cuts(counts, ranks);
    ASSERT_EQ(cuts.size(), std::size_t(ranks) + 1);
    ASSERT_EQ(cuts.front(), 0);
    ASSERT_EQ(cuts.back(), columns);
    const double total = std::accumulate(counts.begin(), counts.end(), 0.0);
    const double widest = *std::max_element(counts.begin(), counts.end());
    for (int r = 0; r < ranks; ++r) {
      ASSERT_LT(cuts[std::size_t(r)], cuts[std::size_t(r) + 1]) << "rank " << r << " has no column";
      // Each border lies within half a column's count of its target r / ranks of the particles,
      // or is forced (a one-column slab, or one that ends early): no slab holds more than the
      // mean plus the fullest column.
      double n = 0;
      for (int c = cuts[std::size_t(r)]; c < cuts[std::size_t(r) + 1]; ++c)
        n += counts[std::size_t(c)];
      EXPECT_LE(n, total / ranks + widest + 1e-9) << "trial " << trial << " rank " << r;
    }
  }
}

TEST(ProcessGrid, CutsACubeIntoBoxesAndAChannelIntoSlabs) {
  using I2 = Eigen::Vector2i;
  using I3 = Eigen::Vector3i;
  EXPECT_EQ(detail::process_grid<2>(4, I2(10, 10)), (std::vector<int>{2, 2}));
  EXPECT_EQ(detail::process_grid<2>(4, I2(40, 5)), (std::vector<int>{4, 1}));
  EXPECT_EQ(detail::process_grid<2>(4, I2(5, 40)), (std::vector<int>{1, 4}));
  EXPECT_EQ(detail::process_grid<3>(4, I3(10, 10, 10)), (std::vector<int>{2, 2, 1}));
  EXPECT_EQ(detail::process_grid<3>(8, I3(10, 10, 10)), (std::vector<int>{2, 2, 2}));
  EXPECT_EQ(detail::process_grid<3>(64, I3(20, 20, 20)), (std::vector<int>{4, 4, 4}));
  EXPECT_EQ(detail::process_grid<3>(2048, I3(125, 125, 125)), (std::vector<int>{16, 16, 8}));
  EXPECT_EQ(detail::process_grid<3>(8, I3(100, 5, 5)), (std::vector<int>{8, 1, 1}));
  // A prime count: slabs along the longest axis.
  EXPECT_EQ(detail::process_grid<3>(3, I3(4, 9, 4)), (std::vector<int>{1, 3, 1}));
  // No box of a block for every rank along some factorisation: refused (empty).
  EXPECT_TRUE(detail::process_grid<2>(7, I2(5, 5)).empty());
  EXPECT_EQ(detail::process_grid<2>(25, I2(5, 5)), (std::vector<int>{5, 5}));
}

TEST(BoxSplit, TilesTheLatticeWithOneNonEmptyBoxPerRank) {
  std::mt19937 rng(11);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector3i res(3 + int(rng() % 12), 3 + int(rng() % 12), 3 + int(rng() % 12));
    const int ranks = 1 + int(rng() % 12);
    const auto per_axis = detail::process_grid<3>(ranks, res);
    if (per_axis.empty()) continue;
    detail::BoxSplit<3> split(res, per_axis);
    // Particles in a ball in one corner: most boxes are balanced over few blocks.
    std::vector<double> lattice(std::size_t(res.prod()), 0.0);
    for (std::size_t j = 0; j < lattice.size(); ++j) {
      const auto b = transfer::lattice_coord<3>(std::int64_t(j), res);
      if (b.squaredNorm() < res.squaredNorm() / 4) lattice[j] = double(1 + rng() % 50);
    }
    split.cut(lattice);
    std::vector<int> owned(std::size_t(ranks), 0);
    for (std::size_t j = 0; j < lattice.size(); ++j) {
      const auto b = transfer::lattice_coord<3>(std::int64_t(j), res);
      const int r = split.owner(b);
      ASSERT_GE(r, 0);
      ASSERT_LT(r, ranks);
      Eigen::Vector3i lo, hi;
      split.box(r, lo, hi);
      ASSERT_TRUE((b.array() >= lo.array()).all() && (b.array() < hi.array()).all())
          << "trial " << trial << ": block " << b.transpose() << " owned by " << r << " outside its box";
      ++owned[std::size_t(r)];
    }
    for (int r = 0; r < ranks; ++r) {
      Eigen::Vector3i lo, hi;
      split.box(r, lo, hi);
      EXPECT_TRUE(((hi - lo).array() >= 1).all()) << "trial " << trial << ": rank " << r << " has an empty box";
      EXPECT_EQ(owned[std::size_t(r)], (hi - lo).prod()) << "trial " << trial << ": rank " << r;
    }
  }
}

TEST(BoxSplit, BalancesEachLevelByItsOwnCounts) {
  // 2 x 2 over 8 x 8 blocks, 20 particles in each block row along axis 0: the slabs split at 4.
  // In the lower slab they all lie in the first two columns along axis 1, in the upper slab they
  // are spread evenly: each slab's cut along axis 1 follows its own particles.
  detail::BoxSplit<2> split(Eigen::Vector2i(8, 8), {2, 2});
  std::vector<double> lattice(64, 0.0);
  for (int i = 0; i < 8; ++i)
    for (int j = 0; j < 8; ++j) lattice[std::size_t(i * 8 + j)] = i < 4 ? (j < 2 ? 10 : 0) : 2.5;
  split.cut(lattice);
  EXPECT_EQ(split.cuts[0], (std::vector<int>{0, 4, 8}));
  EXPECT_EQ(split.cuts[1], (std::vector<int>{0, 1, 8, 0, 4, 8}));
  EXPECT_EQ(split.owner(Eigen::Vector2i(3, 0)), 0);
  EXPECT_EQ(split.owner(Eigen::Vector2i(3, 1)), 1);
  EXPECT_EQ(split.owner(Eigen::Vector2i(4, 3)), 2);
  EXPECT_EQ(split.owner(Eigen::Vector2i(7, 4)), 3);
}

TEST(PackParticles, RoundTripsEveryStoredChannel) {
  Particles<float, 3> P;
  P.channels.F = P.channels.C = P.channels.plastic = P.channels.material = true;
  for (int i = 0; i < 10; ++i) {
    P.push_back(Eigen::Vector3f(float(i), 1, 2), Eigen::Vector3f(0, float(i), 0), 0.5f * float(i),
                1e-3f, std::uint16_t(i % 3), 1.0f + float(i));
    P.F.back()(0, 1) = float(i);
    P.C.back()(2, 2) = -float(i);
  }
  std::string bytes;
  detail::pack_particles(P, {7, 2, 9}, bytes);
  Particles<float, 3> Q;
  Q.channels = P.channels;
  detail::unpack_particles(bytes, Q);
  ASSERT_EQ(Q.size(), 3u);
  EXPECT_TRUE(Q.J.empty());  // not stored: not sent
  const std::uint32_t which[] = {7, 2, 9};
  for (std::size_t k = 0; k < 3; ++k) {
    const auto p = which[k];
    EXPECT_EQ(Q.x[k], P.x[p]);
    EXPECT_EQ(Q.v[k], P.v[p]);
    EXPECT_EQ(Q.m[k], P.m[p]);
    EXPECT_EQ(Q.F[k], P.F[p]);
    EXPECT_EQ(Q.C[k], P.C[p]);
    EXPECT_EQ(Q.plastic[k], P.plastic[p]);
    EXPECT_EQ(Q.material[k], P.material[p]);
    EXPECT_EQ(Q.id[k], P.id[p]);
  }
  std::vector<std::uint8_t> drop(P.size(), 0);
  drop[0] = drop[5] = 1;
  detail::drop_particles(P, drop);
  ASSERT_EQ(P.size(), 8u);
  EXPECT_EQ(P.id[0], 1u);
  EXPECT_EQ(P.id[4], 6u);
  EXPECT_EQ(P.F.size(), 8u);
  bytes.pop_back();
  EXPECT_THROW(detail::unpack_particles(bytes, Q), SimulationError);  // truncated
}

/// Particles in ascending id order, as bytes of every channel, for bitwise comparison.
template <class T, int Dim>
std::string by_id(const Particles<T, Dim>& P) {
  std::vector<std::uint32_t> order(P.size());
  for (std::size_t p = 0; p < P.size(); ++p) order[P.id[p]] = std::uint32_t(p);
  std::string bytes;
  detail::pack_particles(P, order, bytes);
  return bytes;
}

// A rank holds its particles in an order of its own (arrivals from the neighbours are appended,
// leavers removed); its bins order them by id, so the substeps it takes are those of one
// process. Here: the storage shuffled mid-run, then the same steps, bitwise the same particles.
TEST(StorageOrder, ShufflingTheParticlesChangesNoBit) {
  for (const int dim : {2, 3}) {
    const Scene s = test::determinism_scene(dim, GridKind::Sparse);
    auto run = [&](bool shuffle) {
      auto steps = [&](auto& sim) {
        for (int i = 0; i < 12; ++i) {
          if (shuffle && i == 5) {  // mid-run: between two periodic re-sorts
            auto& P = sim.particles();
            std::vector<std::uint32_t> perm(P.size());
            std::iota(perm.begin(), perm.end(), 0u);
            std::shuffle(perm.begin(), perm.end(), std::mt19937(11));
            std::string bytes;
            detail::pack_particles(P, perm, bytes);
            detail::truncate_particles(P, 0);
            detail::unpack_particles(bytes, P);
          }
          sim.step(sim.stable_dt());
        }
        return by_id(sim.particles());
      };
      if (dim == 2) {
        MpmSolver<float, 2> sim(s);
        return steps(sim);
      }
      MpmSolver<float, 3> sim(s);
      return steps(sim);
    };
    const std::string plain = run(false), shuffled = run(true);
    EXPECT_EQ(plain.size(), shuffled.size());
    EXPECT_TRUE(plain == shuffled) << dim << "D: a shuffled storage changed the particles";
  }
}

}  // namespace
}  // namespace slurry
