// The substep allocates nothing once warmed up: every buffer (bins, grid blocks, stress) is kept
// between steps. This program replaces the global operator new to count allocations.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <new>

#include "determinism_scene.h"
#include "slurry/engine/simulation.h"
#include "slurry/transfer/parallel.h"

namespace {
std::atomic<long> g_allocations{0};
}

void* operator new(std::size_t n) {
  ++g_allocations;
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return operator new(n); }
void* operator new(std::size_t n, std::align_val_t a) {
  ++g_allocations;
  const std::size_t al = std::size_t(a);
  if (void* p = std::aligned_alloc(al, (n + al - 1) / al * al)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n, std::align_val_t a) { return operator new(n, a); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }

namespace {

template <class T, int Dim>
long allocations_per_step(slurry::GridKind grid, slurry::TransferKind transfer, int threads) {
  slurry::Scene s = slurry::test::determinism_scene(Dim, grid);
  s.solver.transfer = transfer;
  slurry::parallel::ThreadLimit limit(threads);
  slurry::Simulation<T, Dim> sim(s);
  const T dt = sim.stable_dt();
  for (int i = 0; i < 3; ++i) sim.step(dt);  // warm up: buffers reach their working size
  const long before = g_allocations.load();
  for (int i = 0; i < 8; ++i) sim.step(dt);
  return g_allocations.load() - before;
}

TEST(Allocation, WarmSubstepsAllocateNothing) {
  // Allocations are counted, so the counter itself must see the warm-up allocate.
  const long before = g_allocations.load();
  { slurry::Simulation<float, 2> sim(slurry::test::determinism_scene(2, slurry::GridKind::Sparse)); }
  EXPECT_GT(g_allocations.load(), before);
  for (int threads : {1, 2}) {
    EXPECT_EQ((allocations_per_step<float, 3>(slurry::GridKind::Sparse, slurry::TransferKind::MLS, threads)), 0);
    EXPECT_EQ((allocations_per_step<float, 3>(slurry::GridKind::Dense, slurry::TransferKind::FLIP, threads)), 0);
    EXPECT_EQ((allocations_per_step<double, 2>(slurry::GridKind::Sparse, slurry::TransferKind::APIC, threads)), 0);
  }
}

}  // namespace
