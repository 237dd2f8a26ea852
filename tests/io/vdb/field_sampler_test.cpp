// The direct sampler of the anisotropic field's blocks (io/src/vdb/field_sampler.h) against
// OpenVDB's BoxSampler on a tree of the same blocks, built as the surfacer builds it: the same
// float at every point, bit for bit (the surfacer's droplet test reads either). Its test of a
// sample against a bound, which skips the interpolation where the corners decide, agrees with the
// sample.
#include <gtest/gtest.h>

#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>

#include <cmath>
#include <cstring>
#include <random>

#include "vdb/anisotropic.h"
#include "vdb/field_sampler.h"

namespace {

using slurry::io::PointCloud;
using slurry::io::detail::anisotropic_field;
using slurry::io::detail::FieldBlocks;
using slurry::io::detail::FieldSampler;

/// A jittered slab of particles at spacing s around the origin (negative coordinates included)
/// and a few spray particles above it.
PointCloud cloud(double s) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-0.3f * float(s), 0.3f * float(s));
  PointCloud c;
  for (double x = -0.1; x < 0.1; x += s)
    for (double y = -0.03; y < 0.02; y += s)
      for (double z = -0.08; z < 0.06; z += s) c.position.push_back({float(x) + u(rng), float(y) + u(rng), float(z) + u(rng)});
  for (int k = 0; k < 5; ++k) c.position.push_back({float(0.02 * k - 0.04), float(0.05 + 0.01 * k), 0.0f});
  return c;
}

openvdb::FloatGrid::Ptr tree_of(const FieldBlocks& f, double h) {
  openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(0.0f);
  grid->setTransform(openvdb::math::Transform::createLinearTransform(h));
  using Leaf = openvdb::FloatTree::LeafNodeType;
  for (std::size_t b = 0; b < f.origin.size(); ++b) {
    const auto& o = f.origin[b];
    auto* leaf = new Leaf(openvdb::Coord(o[0], o[1], o[2]), 0.0f, true);
    std::copy_n(f.value.data() + b * Leaf::SIZE, Leaf::SIZE, leaf->buffer().data());
    grid->tree().addLeaf(leaf);
  }
  return grid;
}

TEST(FieldSampler, MatchesOpenVdbsBoxSamplerBitForBit) {
  openvdb::initialize();
  for (const double h : {0.02, 0.013, 0.0071}) {
    const double s = 0.01;
    const PointCloud c = cloud(s);
    const FieldBlocks f = anisotropic_field(c, h, s);
    ASSERT_GT(f.origin.size(), 4u);
    const FieldSampler direct(f, h);
    ASSERT_TRUE(direct.usable());
    const auto grid = tree_of(f, h);
    const openvdb::FloatGrid::ConstAccessor acc = grid->getConstAccessor();
    const openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler> box(
        acc, grid->transform());
    std::vector<std::array<float, 3>> at = c.position;  // the particles themselves
    std::mt19937 rng(9);
    std::uniform_real_distribution<float> u(-0.2f, 0.2f);
    for (int k = 0; k < 20000; ++k) at.push_back({u(rng), u(rng) * 0.5f, u(rng)});  // inside, beside, outside
    for (int i = -40; i <= 40; ++i)  // on voxel centres and block edges, and just off them
      for (const float e : {0.0f, 1e-4f, -1e-4f, 0.5f})
        at.push_back({float((i + e) * h), float((i / 3 + e) * h), float((-i + e) * h)});
    int nonzero = 0, differ = 0;
    for (const auto& p : at) {
      const float a = direct.sample(p), b = box.wsSample(openvdb::Vec3R(p[0], p[1], p[2]));
      nonzero += a != 0.0f;
      if (std::memcmp(&a, &b, sizeof a) != 0 && ++differ <= 5)
        ADD_FAILURE() << "h " << h << " at (" << p[0] << ", " << p[1] << ", " << p[2] << "): " << a << " vs OpenVDB " << b;
    }
    EXPECT_EQ(differ, 0) << "h " << h;
    EXPECT_GT(nonzero, int(c.size())) << "most samples inside the field";
  }
}

TEST(FieldSampler, ScatteredBlocksLeaveTheTreeToTheCaller) {
  PointCloud c;
  for (int k = 0; k < 8; ++k) c.position.push_back({0.01f * float(k % 2), 0.01f * float(k / 2 % 2), 0.01f * float(k / 4)});
  c.position.push_back({40.0f, 30.0f, 20.0f});  // a particle far away: a box of blocks mostly empty
  const FieldBlocks f = anisotropic_field(c, 0.02, 0.01);
  EXPECT_FALSE(FieldSampler(f, 0.02).usable());
  c.position.pop_back();
  EXPECT_TRUE(FieldSampler(anisotropic_field(c, 0.02, 0.01), 0.02).usable());
}

// below(p, bound) is double(sample(p)) < bound at every point: at bounds far from the sample (where
// the corners decide), at the sample itself, a float ulp either side of it, and just below it.
TEST(FieldSampler, BelowAgreesWithTheSample) {
  const double h = 0.013, s = 0.01;
  const PointCloud c = cloud(s);
  const FieldBlocks f = anisotropic_field(c, h, s);
  const FieldSampler direct(f, h);
  ASSERT_TRUE(direct.usable());
  std::vector<std::array<float, 3>> at = c.position;
  std::mt19937 rng(4);
  std::uniform_real_distribution<float> u(-0.2f, 0.2f);
  for (int k = 0; k < 20000; ++k) at.push_back({u(rng), u(rng) * 0.5f, u(rng)});
  int differ = 0, below = 0, checks = 0;
  for (const auto& p : at) {
    const float v = direct.sample(p);
    for (const double bound : {0.0, 0.015, 0.1, 0.5, 2.0, double(v), double(std::nextafter(v, 10.0f)),
                               double(std::nextafter(v, -10.0f)), 0.999 * double(v), 0.99999 * double(v)}) {
      if (bound < 0) continue;
      const bool want = double(v) < bound;
      differ += direct.below(p, bound) != want;
      below += want;
      ++checks;
    }
  }
  EXPECT_EQ(differ, 0);
  EXPECT_GT(below, checks / 5);
  EXPECT_LT(below, checks * 4 / 5);
}

}  // namespace
