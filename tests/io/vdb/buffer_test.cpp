// The surfacer's pool of large buffers (io/src/vdb/buffer.h): a freed mapping is reused by the
// next allocation it fits, small ones are not pinned to large mappings, the pool keeps at most
// kPoolBytes, and release_buffer_pool returns what it keeps.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>

#include "slurry/io/surface.h"
#include "vdb/buffer.h"

namespace {

using namespace slurry::io::detail;

constexpr std::size_t kMiB = std::size_t(1) << 20;

TEST(BufferPool, AFreedMappingIsReusedByTheNextAllocationItFits) {
  release_buffer_pool();
  const float* first = nullptr;
  {
    UninitVector<float> a(40 * kMiB / sizeof(float));
    first = a.data();
    EXPECT_EQ(std::uintptr_t(first) % (2 * kMiB), 0u) << "aligned to a huge page";
    EXPECT_EQ(buffer_pool_bytes(), 0u);
  }
  EXPECT_EQ(buffer_pool_bytes(), 40 * kMiB);
  {
    UninitVector<float> b(39 * kMiB / sizeof(float));  // rounds up to the same 40 MiB
    EXPECT_EQ(b.data(), first);
    EXPECT_EQ(buffer_pool_bytes(), 0u);
  }
  EXPECT_EQ(release_buffer_pool(), 40 * kMiB);
  EXPECT_EQ(buffer_pool_bytes(), 0u);
}

TEST(BufferPool, ValueInitializedBuffersAreZeroOnAReusedMapping) {
  release_buffer_pool();
  const std::size_t n = 8 * kMiB / sizeof(std::int32_t);
  const std::int32_t* first = nullptr;
  {
    UninitVector<std::int32_t> dirty(n);
    std::fill(dirty.begin(), dirty.end(), 7);
    first = dirty.data();
  }
  Buffer<std::int32_t> clean(n);
  EXPECT_EQ(clean.data(), first);
  EXPECT_EQ(std::count(clean.begin(), clean.end(), 0), std::ptrdiff_t(n));
}

TEST(BufferPool, ASmallBufferDoesNotTakeAMappingMoreThanTwiceItsSize) {
  release_buffer_pool();
  { UninitVector<char> big(64 * kMiB); }
  {
    UninitVector<char> small(8 * kMiB);
    EXPECT_EQ(buffer_pool_bytes(), 64 * kMiB) << "the 64 MiB mapping stays in the pool";
  }
  EXPECT_EQ(buffer_pool_bytes(), 72 * kMiB);
  {
    UninitVector<char> buffers[2] = {UninitVector<char>(8 * kMiB), UninitVector<char>(8 * kMiB)};
    EXPECT_EQ(buffer_pool_bytes(), 64 * kMiB) << "the first 8 MiB from the pool, the second fresh";
  }
  release_buffer_pool();
}

TEST(BufferPool, SmallBuffersDoNotUseThePool) {
  release_buffer_pool();
  { UninitVector<char> a(kLargeBytes - 1); }
  EXPECT_EQ(buffer_pool_bytes(), 0u);
  { UninitVector<char> b(kLargeBytes); }
  EXPECT_EQ(buffer_pool_bytes(), kLargeBytes);
  release_buffer_pool();
}

TEST(BufferPool, KeepsAtMostItsLimitDroppingTheLargestFirst) {
  release_buffer_pool();
  // Mapped but never touched: address space only.
  const std::size_t big = kPoolBytes / 2 + 64 * kMiB, small = kPoolBytes / 4;
  void* a = pool_allocate(big);
  void* b = pool_allocate(big);
  void* c = pool_allocate(small);
  pool_free(c);
  pool_free(a);
  EXPECT_EQ(buffer_pool_bytes(), small + big);
  pool_free(b);  // over the limit: one of the two large mappings goes
  EXPECT_EQ(buffer_pool_bytes(), small + big);
  EXPECT_LE(buffer_pool_bytes(), kPoolBytes);
  EXPECT_EQ(release_buffer_pool(), small + big);
}

TEST(BufferPool, SurfacingKeepsItsLargeBuffersUntilReleased) {
  release_buffer_pool();
  // 125 k particles at spacing 0.01 m: the kernels alone take 7 MB.
  slurry::io::PointCloud cloud;
  for (int i = 0; i < 50; ++i)
    for (int j = 0; j < 50; ++j)
      for (int k = 0; k < 50; ++k)
        cloud.position.push_back({0.01f * (float(i) + 0.5f), 0.01f * (float(j) + 0.5f), 0.01f * (float(k) + 0.5f)});
  const slurry::io::Surface first = slurry::io::surface_mesh(cloud, slurry::io::SurfaceParams{0.02, 0.01});
  const std::size_t kept = buffer_pool_bytes();
  EXPECT_GE(kept, 8 * kMiB);
  const slurry::io::Surface second = slurry::io::surface_mesh(cloud, slurry::io::SurfaceParams{0.02, 0.01});
  EXPECT_EQ(buffer_pool_bytes(), kept) << "the second frame reuses the first's buffers";
  EXPECT_EQ(second.mesh.vertices, first.mesh.vertices);
  EXPECT_EQ(slurry::io::release_surfacing_memory(), kept);
  EXPECT_EQ(buffer_pool_bytes(), 0u);
}

}  // namespace
