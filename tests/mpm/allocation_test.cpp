// The substep allocates nothing once warmed up: every buffer (bins, grid blocks, stress) is kept
// between steps. This program replaces the global operator new to count allocations.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <new>

#include "determinism_scene.h"
#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/mpm/mpm_solver.h"
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
  slurry::MpmSolver<T, Dim> sim(s);
  const T dt = sim.stable_dt();
  for (int i = 0; i < 3; ++i) sim.step(dt);  // warm up: buffers reach their working size
  const long before = g_allocations.load();
  for (int i = 0; i < 8; ++i) sim.step(dt);
  return g_allocations.load() - before;
}

TEST(Allocation, WarmSubstepsAllocateNothing) {
  // Allocations are counted, so the counter itself must see the warm-up allocate.
  const long before = g_allocations.load();
  { slurry::MpmSolver<float, 2> sim(slurry::test::determinism_scene(2, slurry::GridKind::Sparse)); }
  EXPECT_GT(g_allocations.load(), before);
  for (int threads : {1, 2}) {
    EXPECT_EQ((allocations_per_step<float, 3>(slurry::GridKind::Sparse, slurry::TransferKind::MLS, threads)), 0);
    EXPECT_EQ((allocations_per_step<float, 3>(slurry::GridKind::Dense, slurry::TransferKind::FLIP, threads)), 0);
    EXPECT_EQ((allocations_per_step<double, 2>(slurry::GridKind::Sparse, slurry::TransferKind::APIC, threads)), 0);
  }
}

// The FLIP step (sort, face transfers, labels, level set, pressure PCG with its parallel dot
// products, extrapolation, advection) of a sloshing liquid, warm: no allocation either.
long flip_allocations_per_step(slurry::PressurePreconditioner preconditioner, int threads) {
  slurry::Scene s;
  s.source = "allocation";
  s.solver.type = slurry::SolverType::FLIP;
  s.solver.dimension = 2;
  s.solver.transfer = slurry::TransferKind::APIC;
  s.solver.kernel = slurry::KernelKind::Linear;
  s.solver.cfl = 2;
  s.solver.max_dt = 1.0 / 120;
  s.solver.pressure.preconditioner = preconditioner;
  s.domain.max = {1, 1, 0};
  s.domain.dx = 1.0 / 32;
  slurry::MaterialParams m;
  m.name = "water";
  m.model = slurry::ElasticModel::Fluid;
  s.materials = {m};
  slurry::BodyParams b;
  b.min = {0, 0, 0};
  b.max = {0.4, 0.7, 0};
  b.material = "water";
  b.particles_per_cell = 4;
  s.bodies = {b};
  slurry::parallel::ThreadLimit limit(threads);
  slurry::flip::FlipSolver<float, 2> sim(s);
  const float dt = float(s.solver.max_dt);
  for (int i = 0; i < 10; ++i) sim.step(dt);
  const long before = g_allocations.load();
  for (int i = 0; i < 5; ++i) sim.step(dt);
  return g_allocations.load() - before;
}

TEST(Allocation, WarmFlipSubstepsAllocateNothing) {
  for (int threads : {1, 2}) {
    EXPECT_EQ(flip_allocations_per_step(slurry::PressurePreconditioner::MIC0, threads), 0) << threads << " threads";
    EXPECT_EQ(flip_allocations_per_step(slurry::PressurePreconditioner::Multigrid, threads), 0) << threads << " threads";
  }
}

}  // namespace
