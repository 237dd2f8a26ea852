// Race-free parallel transfers: the same results on any thread count, with either grid, and a
// sparse grid whose memory follows the particles. (The cross-backend comparison runs the TBB
// build of the determinism program; see CMakeLists.txt.)
#include <gtest/gtest.h>
#include <sys/resource.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "mpm/deformation_lanes.h"
#include "determinism_scene.h"
#include "slurry/io/ply.h"
#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/transfer/blocks.h"
#include "slurry/transfer/grid.h"
#include "slurry/transfer/parallel.h"
#include "slurry/transfer/sparse_grid.h"
#include "slurry/transfer/transfers.h"

namespace {

using slurry::Scene;

template <class V>
bool bitwise_equal(const std::vector<V>& a, const std::vector<V>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(V)) == 0);
}

template <class T, int Dim>
void expect_bitwise_equal(const slurry::Particles<T, Dim>& a, const slurry::Particles<T, Dim>& b, const char* what) {
  EXPECT_TRUE(bitwise_equal(a.x, b.x)) << what << ": positions differ";
  EXPECT_TRUE(bitwise_equal(a.v, b.v)) << what << ": velocities differ";
  EXPECT_TRUE(bitwise_equal(a.F, b.F)) << what << ": F differs";
  EXPECT_TRUE(bitwise_equal(a.C, b.C)) << what << ": C differs";
  EXPECT_TRUE(bitwise_equal(a.J, b.J)) << what << ": J differs";
  EXPECT_TRUE(bitwise_equal(a.plastic, b.plastic)) << what << ": plastic state differs";
  EXPECT_TRUE(bitwise_equal(a.id, b.id)) << what << ": storage orders differ";
}

template <class T, int Dim>
slurry::Particles<T, Dim> run(const Scene& s, int threads, int steps) {
  slurry::parallel::ThreadLimit limit(threads);
  slurry::MpmSolver<T, Dim> sim(s);
  const T dt = sim.stable_dt();
  for (int i = 0; i < steps; ++i) sim.step(dt);
  return sim.particles();
}

// Four materials (jelly, snow, sand, water) colliding in 3D: frames are bitwise equal with one
// and two threads. The scene has particles of several materials in the same blocks.
TEST(Determinism, ThreeDimensionalMultiMaterialSceneIsBitwiseEqualOnOneAndTwoThreads) {
  const Scene s = slurry::test::determinism_scene(3, slurry::GridKind::Sparse);
  const auto one = run<float, 3>(s, 1, 20);
  const auto two = run<float, 3>(s, 2, 20);
  ASSERT_GT(one.size(), 5000u);
  expect_bitwise_equal(one, two, "1 vs 2 threads");
  // The run did something: particles moved and deformed.
  slurry::MpmSolver<float, 3> start(s);
  double moved = 0;
  for (std::size_t p = 0; p < one.size(); ++p)
    moved = std::max(moved, double((one.x[p] - start.particles().x[one.id[p]]).norm()));
  std::printf("[ figure ] determinism scene: %zu particles, largest displacement %.4f m after 20 steps\n", one.size(), moved);
  EXPECT_GT(moved, 0.01);
}

TEST(Determinism, TwoDimensionalSceneIsBitwiseEqualOnOneAndTwoThreads) {
  const Scene s = slurry::test::determinism_scene(2, slurry::GridKind::Sparse);
  expect_bitwise_equal(run<double, 2>(s, 1, 40), run<double, 2>(s, 2, 40), "1 vs 2 threads (2D)");
}

// The sparse and the dense grid add the same contributions in the same order.
TEST(SparseGrid, SameResultAsTheDenseGrid) {
  for (int dim : {2, 3}) {
    const Scene sparse = slurry::test::determinism_scene(dim, slurry::GridKind::Sparse);
    const Scene dense = slurry::test::determinism_scene(dim, slurry::GridKind::Dense);
    if (dim == 3)
      expect_bitwise_equal(run<float, 3>(sparse, 2, 12), run<float, 3>(dense, 2, 12), "sparse vs dense (3D)");
    else
      expect_bitwise_equal(run<double, 2>(sparse, 2, 20), run<double, 2>(dense, 2, 20), "sparse vs dense (2D)");
  }
}

// The TBB build of the determinism program writes the same PLY frame, byte for byte, as this
// (OpenMP) build on one and two threads.
TEST(Determinism, OpenMPAndTBBBackendsWriteTheSameFrame) {
#if defined(SLURRY_DETERMINISM_TBB) && defined(SLURRY_PARALLEL_OPENMP)
  const auto dir = std::filesystem::temp_directory_path() / ("slurry_backend_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const auto read = [](const std::filesystem::path& p) {
    std::ifstream f(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(f), {});
  };
  std::string reference;
  {
    const Scene s = slurry::test::determinism_scene(3, slurry::GridKind::Sparse);
    slurry::parallel::ThreadLimit limit(2);
    reference = slurry::test::determinism_frame(s, 20, dir / "openmp.ply", read);
  }
  for (int threads : {1, 2}) {
    const auto out = dir / ("tbb" + std::to_string(threads) + ".ply");
    const std::string cmd = std::string(SLURRY_DETERMINISM_TBB) + " " + out.string() + " " + std::to_string(threads);
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
    EXPECT_EQ(read(out), reference) << "TBB with " << threads << " threads vs OpenMP with 2";
  }
  EXPECT_GT(reference.size(), 10000u);
  // The FLIP path (face transfers, MIC(0) level scheduling, extrapolation, emitter, collider).
  std::string flip_reference;
  {
    slurry::parallel::ThreadLimit limit(2);
    flip_reference = slurry::test::flip_determinism_frame(30, dir / "openmp_flip.ply", read);
  }
  {
    slurry::parallel::ThreadLimit limit(1);
    EXPECT_EQ(slurry::test::flip_determinism_frame(30, dir / "openmp_flip1.ply", read), flip_reference)
        << "FLIP, OpenMP with 1 vs 2 threads";
  }
  for (int threads : {1, 2}) {
    const auto out = dir / ("tbb_flip" + std::to_string(threads) + ".ply");
    const std::string cmd =
        std::string(SLURRY_DETERMINISM_TBB) + " " + out.string() + " " + std::to_string(threads) + " flip";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
    EXPECT_EQ(read(out), flip_reference) << "FLIP: TBB with " << threads << " threads vs OpenMP with 2";
  }
  EXPECT_GT(flip_reference.size(), 100000u);
  std::printf("[ figure ] backends: MPM frame %zu bytes, FLIP frame %zu bytes, identical across OpenMP/TBB and 1/2 threads\n",
              reference.size(), flip_reference.size());
  std::filesystem::remove_all(dir);
#else
  GTEST_SKIP() << "built without the TBB determinism program (oneTBB not found or backend not OpenMP)";
#endif
}

// Binning: every particle once, bins in (block, material) order, stable within a bin, blocks
// grouped and coloured correctly, and the same order on one and two threads.
TEST(ParticleBins, StableCountingSortByBlockAndMaterial) {
  using IVec = Eigen::Vector3i;
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> coord(0, 63), mat(0, 2);
  std::vector<IVec> base(100000);
  std::vector<int> material(base.size());
  for (auto& b : base) b = IVec(coord(rng), coord(rng), coord(rng));
  for (auto& m : material) m = mat(rng);
  auto build = [&](int threads) {
    slurry::parallel::ThreadLimit limit(threads);
    slurry::transfer::ParticleBins<3> bins;
    bins.resize(IVec(64, 64, 64));
    bins.build(
        std::int64_t(base.size()), [&](std::int64_t p) { return base[std::size_t(p)]; },
        [&](std::int64_t p) { return material[std::size_t(p)]; }, 3);
    return bins;
  };
  const auto bins = build(1);
  const auto bins2 = build(2);
  std::vector<int> seen(base.size(), 0);
  std::int64_t prev_key = -1;
  std::size_t in_colours = 0;
  for (int c = 0; c < 8; ++c) {
    for (auto g : bins.colour(c)) {
      const auto& b = bins.bins()[bins.group_begin(g)].block;
      EXPECT_EQ(((b[0] & 1) << 2) | ((b[1] & 1) << 1) | (b[2] & 1), c);
      for (auto j = bins.group_begin(g); j < bins.group_begin(g + 1); ++j) EXPECT_EQ(bins.bins()[j].block, b);
    }
    in_colours += bins.colour(c).size();
  }
  EXPECT_EQ(in_colours, bins.groups());
  EXPECT_EQ(bins.groups(), 4096u);
  for (const auto& bin : bins.bins()) {
    const std::int64_t key = ((std::int64_t(bin.block[0]) * 16 + bin.block[1]) * 16 + bin.block[2]) * 3 + bin.material;
    EXPECT_GT(key, prev_key);
    prev_key = key;
    ASSERT_LT(bin.begin, bin.end);
    for (auto i = bin.begin; i < bin.end; ++i) {
      const auto p = bins.order()[i];
      ++seen[p];
      EXPECT_EQ(IVec(base[p] / 4), bin.block);
      EXPECT_EQ(material[p], int(bin.material));
      if (i > bin.begin) {
        EXPECT_LT(bins.order()[i - 1], p) << "not stable";
      }
    }
  }
  for (int s : seen) ASSERT_EQ(s, 1);
  EXPECT_EQ(std::memcmp(bins.order(), bins2.order(), base.size() * sizeof(std::uint32_t)), 0);
}

// sort_within_bins orders every bin by rank, as a full sort does, whatever the bin's order
// before: in rank order already, mostly in order with a few particles out of place (its fast
// path: an ascending run kept in place and the others merged in), reversed, or shuffled.
TEST(ParticleBins, SortWithinBinsGivesTheFullSortsOrder) {
  using IVec = Eigen::Vector2i;
  std::mt19937 rng(11);
  const std::int64_t n = 40000;
  std::vector<IVec> base(static_cast<std::size_t>(n));
  std::uniform_int_distribution<int> coord(0, 63);
  for (auto& b : base) b = IVec(coord(rng), coord(rng));
  for (int pattern = 0; pattern < 4; ++pattern) {
    // Ranks: a permutation of 0..n-1 whose order within a bin follows the pattern (the counting
    // sort keeps storage order, so rank by storage index gives an ordered bin).
    std::vector<std::uint32_t> rank(static_cast<std::size_t>(n));
    for (std::int64_t p = 0; p < n; ++p) rank[std::size_t(p)] = std::uint32_t(p);
    if (pattern == 1) {  // a few out of place: 2% of the ranks swapped with random others
      std::uniform_int_distribution<std::int64_t> pick(0, n - 1);
      for (int k = 0; k < int(n / 50); ++k)
        std::swap(rank[std::size_t(pick(rng))], rank[std::size_t(pick(rng))]);
    } else if (pattern == 2) {
      std::reverse(rank.begin(), rank.end());
    } else if (pattern == 3) {
      std::shuffle(rank.begin(), rank.end(), rng);
    }
    slurry::transfer::ParticleBins<2> bins;
    bins.resize(IVec(64, 64));
    bins.build(
        n, [&](std::int64_t p) { return base[std::size_t(p)]; }, [](std::int64_t) { return 0; }, 1);
    std::vector<std::uint32_t> expect(bins.order(), bins.order() + n);
    for (const auto& bin : bins.bins())
      std::sort(expect.begin() + bin.begin, expect.begin() + bin.end,
                [&](std::uint32_t p, std::uint32_t q) { return rank[p] < rank[q]; });
    bins.sort_within_bins([&](std::uint32_t p) { return rank[p]; });
    EXPECT_EQ(std::memcmp(bins.order(), expect.data(), std::size_t(n) * sizeof(std::uint32_t)), 0)
        << "pattern " << pattern;
  }
}

// ParticleBins::update gives what build() and sort_within_bins() give, step after step: bins
// (block, material, range), the order, the blocks and their colours. The steps move a few
// particles (to new blocks, emptying one), change materials and swap ranks; the path must be
// taken when few particles moved and refused (false) when too many did or the ranks changed.
TEST(ParticleBins, UpdateGivesTheFullBuildsBins) {
  using IVec = Eigen::Vector2i;
  using Bins = slurry::transfer::ParticleBins<2>;
  std::mt19937 rng(17);
  const std::int64_t n = 20000;
  std::vector<IVec> base(static_cast<std::size_t>(n));
  std::vector<int> material(static_cast<std::size_t>(n));
  std::vector<std::uint32_t> rank(static_cast<std::size_t>(n));
  std::uniform_int_distribution<int> start(0, 47), anywhere(0, 63),
      mat(0, 2);  // about 550 per block
  std::uniform_int_distribution<std::int64_t> pick(0, n - 1);
  for (std::int64_t p = 0; p < n; ++p) {
    base[std::size_t(p)] = IVec(start(rng), start(rng));
    material[std::size_t(p)] = mat(rng);
    rank[std::size_t(p)] = std::uint32_t(p);
  }
  std::shuffle(rank.begin(), rank.end(), rng);
  auto base_of = [&](std::int64_t p) { return base[std::size_t(p)]; };
  auto material_of = [&](std::int64_t p) { return material[std::size_t(p)]; };
  auto rank_of = [&](std::uint32_t p) { return rank[p]; };
  Bins updated;
  updated.resize(IVec(64, 64));
  EXPECT_FALSE(updated.update(n, base_of, material_of, rank_of)) << "no bins to update yet";
  updated.build(n, base_of, material_of, 3);
  updated.sort_within_bins(rank_of);
  int taken = 0, refused = 0;
  for (int step = 0; step < 60; ++step) {
    const int kind = step % 6;
    if (kind == 0 || kind == 1) {  // a few particles anywhere, some to blocks never occupied
      for (int k = 0; k < 300; ++k)
        base[std::size_t(pick(rng))] = IVec(anywhere(rng), anywhere(rng));
    } else if (kind == 2) {  // a neighbour cell for some (within the block or across a face)
      for (int k = 0; k < 500; ++k) {
        auto& b = base[std::size_t(pick(rng))];
        b = (b + IVec(anywhere(rng) % 3 - 1, anywhere(rng) % 3 - 1)).cwiseMax(0).cwiseMin(63);
      }
    } else if (kind == 3) {  // a whole block's particles leave it (its bins disappear)
      const IVec block = base[std::size_t(pick(rng))] / 8;
      for (auto& b : base)
        if (b / 8 == block) b = IVec(anywhere(rng), anywhere(rng));
      for (int k = 0; k < 50; ++k) material[std::size_t(pick(rng))] = mat(rng);
    } else if (kind == 4) {  // too many movers: refused
      for (int k = 0; k < n / 8; ++k)
        base[std::size_t(pick(rng))] = IVec(anywhere(rng), anywhere(rng));
    } else {  // two ranks swapped: the stayers' order changed, refused
      std::swap(rank[std::size_t(pick(rng))], rank[std::size_t(pick(rng))]);
    }
    const bool used = updated.update(n, base_of, material_of, rank_of);
    if (used) {
      ++taken;
    } else {
      ++refused;
      updated.build(n, base_of, material_of, 3);
      updated.sort_within_bins(rank_of);
    }
    if (kind <= 3) {
      EXPECT_TRUE(used) << "step " << step;
    }
    if (kind == 4) {
      EXPECT_FALSE(used) << "step " << step;
    }
    Bins full;
    full.resize(IVec(64, 64));
    full.build(n, base_of, material_of, 3);
    full.sort_within_bins(rank_of);
    ASSERT_EQ(std::memcmp(updated.order(), full.order(), std::size_t(n) * sizeof(std::uint32_t)), 0)
        << "step " << step;
    ASSERT_EQ(updated.bins().size(), full.bins().size()) << "step " << step;
    for (std::size_t b = 0; b < full.bins().size(); ++b) {
      const auto &u = updated.bins()[b], &f = full.bins()[b];
      ASSERT_TRUE(u.block == f.block && u.material == f.material && u.begin == f.begin &&
                  u.end == f.end)
          << "step " << step << " bin " << b;
    }
    ASSERT_EQ(updated.groups(), full.groups()) << "step " << step;
    for (std::size_t g = 0; g < full.groups(); ++g) {
      EXPECT_EQ(updated.group_begin(g), full.group_begin(g)) << "step " << step;
      EXPECT_EQ(updated.group_key(g), full.group_key(g)) << "step " << step;
    }
    EXPECT_EQ(updated.group_begin(full.groups()), full.group_begin(full.groups()))
        << "step " << step;
    for (int c = 0; c < 4; ++c)
      EXPECT_EQ(updated.colour(c), full.colour(c)) << "step " << step << " colour " << c;
  }
  EXPECT_GE(taken, 40);
  EXPECT_GE(refused, 10);
}

// ParticleBins::update on 3D float positions (PositionBases, ChannelValues): where a bin's
// particles are stored one after the other it checks them 8 at a time (blocks.h,
// still_in_place). Its verdict must be the per-particle one: the test moves single particles
// across a block face along each axis, at every place of a bin (each lane of the 8 and the
// tail), puts particles within a few ulps of the faces, where a rounding different from
// PositionBases's would put them in the other block, changes one material and swaps two ranks.
// After each change the updated bins must equal a full build's.
template <int Order>
void check_vector_bin_check() {
  using Vec = Eigen::Vector3f;
  using IVec = Eigen::Vector3i;
  using Bins = slurry::transfer::ParticleBins<3>;
  std::mt19937 rng(23 + Order);
  const int cells = 24;  // 24^3 nodes: 6^3 blocks of 4^3
  const float inv_dx = 15.3f, dx = 1 / inv_dx;  // x inv_dx rounds: not a power of two
  const Vec origin(-0.3f, 0.1f, -0.05f);
  const std::int64_t n = 6000;  // about 100 per block over 2 materials: full chunks of 8 and tails
  std::vector<Vec> x(static_cast<std::size_t>(n));
  std::vector<std::uint16_t> material(static_cast<std::size_t>(n));
  std::vector<std::uint32_t> rank(static_cast<std::size_t>(n));
  // Positions whose stencil stays inside the lattice for every kernel order.
  std::uniform_real_distribution<float> u(4.0f * dx, (cells - 5) * dx);
  std::uniform_int_distribution<int> mat(0, 1);
  for (std::int64_t p = 0; p < n; ++p) {
    x[std::size_t(p)] = origin + Vec(u(rng), u(rng), u(rng));
    material[std::size_t(p)] = std::uint16_t(mat(rng));
    rank[std::size_t(p)] = std::uint32_t(p);
  }
  std::shuffle(rank.begin(), rank.end(), rng);
  const slurry::transfer::PositionBases<Order, float, 3> base_of{x.data(), origin, inv_dx};
  const slurry::transfer::ChannelValues<std::uint16_t> material_of{material.data()};
  const slurry::transfer::ChannelValues<std::uint32_t, false> rank_of{rank.data()};
  Bins bins;
  bins.resize(IVec::Constant(cells));
  bins.build(n, base_of, material_of, 2);
  bins.sort_within_bins(rank_of);
  // Stores the particles in bin order, as MpmSolver::reorder_particles does.
  auto reorder = [&] {
    auto permute = [&](auto& channel) {
      auto copy = channel;
      for (std::int64_t i = 0; i < n; ++i) channel[std::size_t(i)] = copy[bins.order()[i]];
    };
    permute(x), permute(material), permute(rank);
    bins.reset_order();
  };
  // The update against a full build; false when update() refused (then the bins are rebuilt).
  auto check = [&](const std::string& what) {
    const bool used = bins.update(n, base_of, material_of, rank_of);
    if (!used) {
      bins.build(n, base_of, material_of, 2);
      bins.sort_within_bins(rank_of);
    }
    Bins full;
    full.resize(IVec::Constant(cells));
    full.build(n, base_of, material_of, 2);
    full.sort_within_bins(rank_of);
    EXPECT_EQ(std::memcmp(bins.order(), full.order(), std::size_t(n) * sizeof(std::uint32_t)), 0) << what;
    EXPECT_EQ(bins.bins().size(), full.bins().size()) << what;
    for (std::size_t b = 0; b < std::min(bins.bins().size(), full.bins().size()); ++b) {
      const auto &a = bins.bins()[b], &f = full.bins()[b];
      EXPECT_TRUE(a.block == f.block && a.material == f.material && a.begin == f.begin && a.end == f.end)
          << what << ": bin " << b;
    }
    reorder();
    return used;
  };
  reorder();
  EXPECT_TRUE(check("nothing moved"));
  auto largest_bin = [&] {
    std::size_t largest = 0;
    for (std::size_t b = 0; b < bins.bins().size(); ++b)
      if (bins.bins()[b].end - bins.bins()[b].begin > bins.bins()[largest].end - bins.bins()[largest].begin)
        largest = b;
    return largest;
  };
  // One particle across a face, for every place in the largest bin and every axis.
  {
    const std::size_t largest = largest_bin();
    const std::uint32_t len = bins.bins()[largest].end - bins.bins()[largest].begin;
    ASSERT_GE(len, 17u) << "two chunks of 8 and a tail";
    for (std::uint32_t j = 0; j < len; ++j)
      for (int d = 0; d < 3; ++d) {
        const auto bin = bins.bins()[largest];
        ASSERT_EQ(bins.order()[bin.begin], bin.begin) << "stored in bin order";
        const std::uint32_t p = bin.begin + j;
        const Vec before = x[p];
        const std::uint32_t id = rank[p];
        x[p][d] += (bin.block[d] % 2 == 0 ? 4.0f : -4.0f) * dx;  // into a neighbour block
        ASSERT_NE(base_of(p)[d] >> 2, bin.block[d]);
        EXPECT_TRUE(check("particle " + std::to_string(j) + " of " + std::to_string(len) + ", axis " +
                          std::to_string(d)));
        // Back where it was (stored elsewhere since the re-sort): a move into the block it left.
        x[std::size_t(std::find(rank.begin(), rank.end(), id) - rank.begin())] = before;
        EXPECT_TRUE(check("moved back"));
      }
  }
  // Within a few ulps of block faces: the node coordinate at which the base's block changes.
  {
    std::uniform_int_distribution<std::int64_t> pick(0, n - 1);
    std::uniform_int_distribution<int> ulps(-3, 3), face(2, cells / 4 - 2), axis(0, 2);
    for (int round = 0; round < 20; ++round) {
      for (int k = 0; k < 150; ++k) {
        auto& y = x[std::size_t(pick(rng))];
        const int d = axis(rng);
        // base(g) = 4 f at g = 4 f (linear), 4 f + 1/2 (quadratic), 4 f + 1 (cubic), in cells.
        const float g = 4.0f * float(face(rng)) + (Order == 2 ? 0.5f : Order == 3 ? 1.0f : 0.0f);
        float v = origin[d] + g * dx;
        for (int s = ulps(rng); s != 0; s += s > 0 ? -1 : 1) v = std::nextafter(v, s > 0 ? 1.0f : -1.0f);
        y[d] = v;
      }
      check("near the faces, round " + std::to_string(round));
    }
  }
  // The quadratic kernel's base is floor(fma(x - origin, inv_dx, -1/2)) as GCC compiles
  // PositionBases with FMA; rounded twice instead, it puts some positions next to a face in the
  // other block. One particle at a time at such a position, inside its bin's block by the
  // double rounding and outside by PositionBases: the check must see it move.
  if constexpr (Order == 2) {
    auto fused = [&](float v, int d) { return int(std::floor(std::fma(v - origin[d], inv_dx, -0.5f))); };
    auto twice = [&](float v, int d) {
      volatile float t = (v - origin[d]) * inv_dx;
      return int(std::floor(t - 0.5f));
    };
    int found = 0;
    for (int trial = 0; trial < 400 && found < 12; ++trial) {
      const auto bin = bins.bins()[std::size_t(trial * 7919) % bins.bins().size()];
      const std::uint32_t p = bin.begin + std::uint32_t(trial) % (bin.end - bin.begin);
      const int d = trial % 3, face = 4 * (bin.block[d] + (trial / 3) % 2);  // lower or upper face
      float v = origin[d] + (float(face) + 0.5f) * dx;
      for (int k = 0; k < 32; ++k) v = std::nextafter(v, -1.0f);
      for (int k = 0; k < 64; ++k, v = std::nextafter(v, 1.0f)) {
        if ((twice(v, d) >> 2) != bin.block[d] || (fused(v, d) >> 2) == bin.block[d]) continue;
        x[p][d] = v;
        ASSERT_EQ(base_of(p)[d], fused(v, d)) << "PositionBases rounds as one fused multiply-add";
        ++found;
        EXPECT_TRUE(check("one particle " + std::to_string(k - 32) + " ulps from a face")) << found;
        break;
      }
    }
    EXPECT_GE(found, 12) << "positions where the two roundings give different blocks";
  }
  // A material changed; two ranks swapped within a bin (the update must refuse).
  {
    const auto bin = bins.bins()[bins.bins().size() / 2];
    material[bin.begin + 3] = std::uint16_t(1 - material[bin.begin + 3]);
    EXPECT_TRUE(check("a material"));
    const auto other = bins.bins()[largest_bin()];
    ASSERT_GE(other.end - other.begin, 12u);
    std::swap(rank[other.begin + 2], rank[other.begin + 10]);
    EXPECT_FALSE(check("two ranks swapped"));
  }
}

// G2P's queued deformation update (deformation_lanes.h: 8 particles at a time in AVX2 lanes)
// must give the bits of its one-particle form, called as the gather calls it (out of line), on
// queues of 16 and a short last one, with exact zeros of both signs among the gradients and
// identity-like F (zeros whose sign the roundings decide). Swapping the order of the fused
// multiply-adds, or rounding dt g and the identity separately, changes bits here.
TEST(SolidStateUpdate, QueuedLanesMatchTheOneParticleFormBitwise) {
  using Update = slurry::detail::SolidStateUpdate<float, 3>;
  if constexpr (!Update::kBatched) GTEST_SKIP() << "no AVX2/FMA lanes in this build";
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1, 1);
  constexpr int n = 1000;
  std::vector<Eigen::Matrix3f> F(n), G(n);
  std::vector<std::int64_t> ids(n);
  for (int i = 0; i < n; ++i) {
    ids[std::size_t(i)] = i;
    F[std::size_t(i)] = Eigen::Matrix3f::Identity();
    if (i % 3 != 0)
      for (int e = 0; e < 9; ++e) F[std::size_t(i)](e) += 0.3f * u(rng);
    for (int e = 0; e < 9; ++e) G[std::size_t(i)](e) = 40 * u(rng);
    if (i % 5 == 0) G[std::size_t(i)](1) = 0.0f;
    if (i % 7 == 0) G[std::size_t(i)](3) = -0.0f;
  }
  std::shuffle(ids.begin(), ids.end(), rng);
  std::vector<Eigen::Matrix3f> F_one = F;
  const Update lanes{F.data(), 1e-3f}, one{F_one.data(), 1e-3f};
  for (int j0 = 0; j0 < n; j0 += 16) {
    const int q = std::min(16, n - j0);  // 62 queues of 16, then 8
    lanes.batch(ids.data() + j0, G.data() + j0, q);
    for (int j = j0; j < j0 + q; ++j) slurry::transfer::detail::call_out_of_line(one, ids[std::size_t(j)], G[std::size_t(j)]);
  }
  int differ = 0;
  for (int i = 0; i < n; ++i) differ += std::memcmp(F[std::size_t(i)].data(), F_one[std::size_t(i)].data(), sizeof(Eigen::Matrix3f)) != 0;
  EXPECT_EQ(differ, 0) << "of " << n << " particles";
  EXPECT_NE(F[0], Eigen::Matrix3f::Identity());  // it did update
}

TEST(ParticleBins, VectorBinCheckMatchesThePerParticleOne) {
  check_vector_bin_check<1>();
  check_vector_bin_check<2>();
  check_vector_bin_check<3>();
}

// A patch added to and read back from a sparse grid lands on the same nodes as in a dense grid,
// including patches that straddle block boundaries and reach the lattice's end.
TEST(SparseGrid, PatchesMatchTheDenseGrid) {
  using Vec = Eigen::Vector3d;
  using IVec = Eigen::Vector3i;
  const IVec res(19, 21, 23);
  slurry::transfer::SparseGrid<double, 3> sparse(Vec::Zero(), 0.1, res);
  slurry::transfer::DenseGrid<double, 3> dense(Vec::Zero(), 0.1, res);
  using Bin = slurry::transfer::ParticleBins<3>::Bin;
  std::vector<Bin> bins;
  for (int a = 0; a < 5; ++a)
    for (int b = 0; b < 6; ++b)
      for (int c = 0; c < 6; ++c)
        if ((a + 2 * b + c) % 3 == 0) bins.push_back({IVec(a, b, c), 0, 0, 0});
  sparse.activate(bins);
  dense.activate(bins);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  for (const auto& bin : bins) {
    slurry::transfer::Patch<double, 3, 2> patch(bin.block, Vec::Zero(), 0.1, 10);
    for (auto& n : patch.nodes) n = Eigen::Vector4d(u(rng), u(rng), u(rng), u(rng));
    // Nodes beyond the lattice never receive particle contributions.
    for (int a = 0; a < patch.extent; ++a)
      for (int b = 0; b < patch.extent; ++b)
        for (int c = 0; c < patch.extent; ++c)
          if (((patch.first + IVec(a, b, c)).array() >= res.array()).any())
            patch.nodes[std::size_t((a * patch.extent + b) * patch.extent + c)].setZero();
    sparse.add_patch(patch);
    dense.add_patch(patch);
  }
  double total_sparse = 0, total_dense = 0;
  for (int i = 0; i < res[0]; ++i)
    for (int j = 0; j < res[1]; ++j)
      for (int k = 0; k < res[2]; ++k) {
        const auto& d = dense.node(dense.index(IVec(i, j, k)));
        const auto* s = sparse.find(IVec(i, j, k));
        if (!s) {
          EXPECT_EQ(d.norm(), 0.0) << "a dense node with contributions has no sparse block";
          continue;
        }
        EXPECT_EQ(*s, d);
        total_sparse += s->sum();
        total_dense += d.sum();
      }
  EXPECT_EQ(total_sparse, total_dense);
  EXPECT_NE(total_dense, 0.0);
  for (const auto& bin : bins) {
    slurry::transfer::Patch<double, 3, 2> ps(bin.block, Vec::Zero(), 0.1, 10), pd(bin.block, Vec::Zero(), 0.1, 10);
    sparse.read_patch(ps);
    dense.read_patch(pd);
    for (int k = 0; k < ps.count; ++k) ASSERT_EQ(ps.nodes[std::size_t(k)], pd.nodes[std::size_t(k)]);
  }
}

// A thin sheet of particles in a 1024^3-cell domain: the dense grid would need 1031^3 nodes
// (17 GB in float), the sparse grid allocates blocks near the sheet only. The test process
// (one test per process under ctest) must stay under 600 MB peak resident memory.
TEST(SparseGrid, ThinSheetInA1024CubedDomainStaysUnder600MB) {
  Scene s = slurry::test::determinism_scene(3, slurry::GridKind::Sparse);
  s.domain.dx = 1.0 / 1024;
  s.materials.resize(1);
  slurry::BodyParams b;
  b.material = s.materials[0].name;
  b.min = {0.375, 0.5, 0.375};
  b.max = {0.625, 0.5 + 1.0 / 1024, 0.625};
  b.velocity = {0.0, -0.5, 0.0};
  b.particles_per_cell = 8;
  s.bodies = {b};
  slurry::MpmSolver<float, 3> sim(s);
  const float dt = sim.stable_dt();
  for (int i = 0; i < 3; ++i) sim.step(dt);
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  const double peak_mb = double(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
  const double bytes_per_particle = double(sim.bytes()) / double(sim.particle_count());
  std::printf("[ figure ] thin sheet in 1024^3: %zu particles, peak RSS %.0f MB, engine bytes/particle %.0f\n",
              sim.particle_count(), peak_mb, bytes_per_particle);
  EXPECT_GT(sim.particle_count(), 500000u);
  EXPECT_LT(peak_mb, 600.0);
  EXPECT_GT(sim.particles().v[0][1], -0.6f);
}

}  // namespace
