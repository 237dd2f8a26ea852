#pragma once
/// \file parallel.h
/// The one place where Slurry's loops meet a threading library (OpenMP, oneTBB, or none, chosen
/// at configure time with SLURRY_PARALLEL). Every parallel phase goes through `parallel_for`
/// over independent indices, so its result does not depend on the thread count; reductions
/// through `parallel_max` use an order-independent operation.
#include <algorithm>
#include <array>
#include <cstdint>
#include <thread>
#include <vector>

#if defined(SLURRY_PARALLEL_OPENMP)
#include <omp.h>
#elif defined(SLURRY_PARALLEL_TBB)
#include <tbb/blocked_range.h>
#include <tbb/task_arena.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <memory>
#endif

namespace slurry::parallel {

/// Name of the compiled-in backend.
inline const char* backend() {
#if defined(SLURRY_PARALLEL_OPENMP)
  return "OpenMP";
#elif defined(SLURRY_PARALLEL_TBB)
  return "TBB";
#else
  return "Serial";
#endif
}

/// The most worker threads a run accepts: 4 x the hardware threads (more only slows a run down).
/// The run loop, the CLI and the surface command all check a requested count against it.
inline int max_thread_count() { return 4 * int(std::max(1u, std::thread::hardware_concurrency())); }

#if defined(SLURRY_PARALLEL_TBB)
namespace detail {
/// The arena of the innermost ThreadLimit alive on this thread, or null.
inline tbb::task_arena*& current_arena() {
  thread_local tbb::task_arena* arena = nullptr;
  return arena;
}
/// Runs f in the current ThreadLimit's arena, if any.
template <class F>
void in_arena(F&& f) {
  if (tbb::task_arena* a = current_arena())
    a->execute(f);
  else
    f();
}
}  // namespace detail
#endif

/// Limits the worker threads of the parallel loops that the calling thread starts while this
/// object is alive (0 = leave the default); the previous limit returns when it dies. Nothing
/// process-wide is changed, so two threads of one program may run two simulations with their own
/// counts. OpenMP: the calling thread's nthreads ICV (omp_set_num_threads sets the ICV of the
/// current task only). oneTBB: a task_arena of that concurrency in which this thread's loops run.
/// run_scene makes one from RunOptions::threads.
class ThreadLimit {
 public:
  explicit ThreadLimit(int threads) {
    if (threads <= 0) return;
#if defined(SLURRY_PARALLEL_OPENMP)
    previous_ = omp_get_max_threads();
    omp_set_num_threads(threads);
#elif defined(SLURRY_PARALLEL_TBB)
    arena_ = std::make_unique<tbb::task_arena>(threads);
    previous_ = detail::current_arena();
    detail::current_arena() = arena_.get();
#endif
  }
  ~ThreadLimit() {
#if defined(SLURRY_PARALLEL_OPENMP)
    if (previous_ > 0) omp_set_num_threads(previous_);
#elif defined(SLURRY_PARALLEL_TBB)
    if (arena_) detail::current_arena() = previous_;
#endif
  }
  ThreadLimit(const ThreadLimit&) = delete;
  ThreadLimit& operator=(const ThreadLimit&) = delete;

 private:
#if defined(SLURRY_PARALLEL_OPENMP)
  int previous_ = 0;
#elif defined(SLURRY_PARALLEL_TBB)
  std::unique_ptr<tbb::task_arena> arena_;
  tbb::task_arena* previous_ = nullptr;
#endif
};

/// Threads the calling thread's next parallel loop may use.
inline int max_threads() {
#if defined(SLURRY_PARALLEL_OPENMP)
  return omp_get_max_threads();
#elif defined(SLURRY_PARALLEL_TBB)
  if (tbb::task_arena* a = detail::current_arena()) return a->max_concurrency();
  return tbb::this_task_arena::max_concurrency();
#else
  return 1;
#endif
}

/// fn(i) for i in [begin, end), handed to threads `grain` indices at a time; the calls must be
/// independent.
template <class Fn>
void parallel_for_grain(std::int64_t begin, std::int64_t end, std::int64_t grain, Fn&& fn) {
  if (end <= begin) return;
#if defined(SLURRY_PARALLEL_OPENMP)
  // Dynamic chunks: on a shared machine a descheduled thread then holds up one chunk, not a
  // fixed half of the loop. Which thread runs an index never changes the result.
#pragma omp parallel for schedule(dynamic, grain)
  for (std::int64_t i = begin; i < end; ++i) fn(i);
#elif defined(SLURRY_PARALLEL_TBB)
  detail::in_arena([&] {
    tbb::parallel_for(tbb::blocked_range<std::int64_t>(begin, end, std::size_t(grain)),
                      [&](const tbb::blocked_range<std::int64_t>& r) {
                        for (std::int64_t i = r.begin(); i < r.end(); ++i) fn(i);
                      });
  });
#else
  (void)grain;
  for (std::int64_t i = begin; i < end; ++i) fn(i);
#endif
}

/// fn(i) for i in [begin, end) over cheap, independent calls (one particle, one node). Chunks of
/// at least 256 indices and at most a 32nd of a thread's share: few enough hand-outs that the
/// shared chunk counter is not contended, enough that a descheduled thread delays little.
template <class Fn>
void parallel_for(std::int64_t begin, std::int64_t end, Fn&& fn) {
  const std::int64_t share = (end - begin) / (32 * std::int64_t(std::max(1, max_threads())));
  parallel_for_grain(begin, end, std::max<std::int64_t>(256, share), fn);
}

/// fn(i) for i in [begin, end) where each call is a sizeable independent task (a block of
/// particles): handed out one at a time, so a few hundred tasks still balance.
template <class Fn>
void parallel_tasks(std::int64_t begin, std::int64_t end, Fn&& fn) {
  parallel_for_grain(begin, end, 1, fn);
}

/// How many neighbouring tasks (blocks of particles, stored one after the other) to hand to a
/// thread at a time: contiguous runs of up to 32, at least 8 hand-outs per thread. Handed out one
/// at a time, two threads alternated blocks: they then write the same cache lines at the edges
/// of each other's particle ranges (x, v, C, F), and each thread's prefetch streams restart at
/// every block (which of the two cost more was not measured). 3D G2P on two threads, 1 M
/// particles: 14.2 -> 12.9 ms per substep with runs of 16 or more; one thread unchanged
/// (BM_MlsStep, benchmarks/RESULTS.md, "3D MPM throughput").
inline std::int64_t task_run(std::int64_t tasks) {
  return std::clamp<std::int64_t>(tasks / (8 * std::int64_t(std::max(1, max_threads()))), 1, 32);
}

/// fn(i) for i in [begin, end), sizeable independent tasks that write neighbouring memory
/// (blocks of particles in storage order): handed out in runs of task_run(end - begin).
template <class Fn>
void parallel_task_runs(std::int64_t begin, std::int64_t end, Fn&& fn) {
  parallel_for_grain(begin, end, task_run(end - begin), fn);
}

/// fn(lo, hi) over contiguous chunks of [begin, end) (for loops that keep per-chunk state).
template <class Fn>
void parallel_chunks(std::int64_t begin, std::int64_t end, Fn&& fn) {
  if (end <= begin) return;
#if defined(SLURRY_PARALLEL_OPENMP)
  constexpr std::int64_t grain = 2048;
  const std::int64_t chunks = (end - begin + grain - 1) / grain;
#pragma omp parallel for schedule(dynamic, 1)
  for (std::int64_t c = 0; c < chunks; ++c) fn(begin + c * grain, std::min(end, begin + (c + 1) * grain));
#elif defined(SLURRY_PARALLEL_TBB)
  detail::in_arena([&] {
    tbb::parallel_for(tbb::blocked_range<std::int64_t>(begin, end, 1024),
                      [&](const tbb::blocked_range<std::int64_t>& r) { fn(r.begin(), r.end()); });
  });
#else
  fn(begin, end);
#endif
}

/// tile(a, b) for every tile of an na x nb grid in the order of a triangular solve over tiles:
/// tile (a, b) starts after (a - 1, b) and (a, b - 1) have finished (with `reverse`: after
/// (a + 1, b) and (a, b + 1)). A tile that reads only the tiles it waits for therefore sees the
/// values of a sequential sweep, whatever the thread count. OpenMP: one parallel region (not one
/// per anti-diagonal, which costs a thread wake-up each under OMP_WAIT_POLICY=passive); the rows a
/// of tiles are dealt to the threads in turn and a thread starts tile (a, b) once the previous row
/// has finished its tile b, told by that row's counter in `progress` (resized to na; release and
/// acquire, spinning then yielding). Other backends: one parallel loop per anti-diagonal a + b.
template <class Fn>
void wavefront(int na, int nb, bool reverse, std::vector<int>& progress, Fn&& tile) {
  if (na <= 0 || nb <= 0) return;
#if defined(SLURRY_PARALLEL_OPENMP)
  progress.assign(static_cast<std::size_t>(na), 0);
  int* done = progress.data();
#pragma omp parallel
  {
    const int threads = omp_get_num_threads(), me = omp_get_thread_num();
    for (int k = me; k < na; k += threads) {
      const int a = reverse ? na - 1 - k : k;
      const int* before = k > 0 ? done + (reverse ? a + 1 : a - 1) : nullptr;
      for (int m = 0; m < nb; ++m) {
        if (before) {
          for (int spins = 0; __atomic_load_n(before, __ATOMIC_ACQUIRE) <= m; ++spins)
            if (spins > 256) std::this_thread::yield();
        }
        tile(a, reverse ? nb - 1 - m : m);
        __atomic_store_n(done + a, m + 1, __ATOMIC_RELEASE);
      }
    }
  }
#else
  (void)progress;
  const int levels = na + nb - 1;
  for (int step = 0; step < levels; ++step) {
    const int level = reverse ? levels - 1 - step : step;
    const int a_lo = std::max(0, level - (nb - 1)), a_hi = std::min(na - 1, level);
    parallel_tasks(a_lo, a_hi + 1, [&](std::int64_t a) { tile(int(a), level - int(a)); });
  }
#endif
}

/// max over i of fn(lo, hi) chunk results, chunks of `grain` indices; max is order
/// independent, so so is the result.
template <class T, class Fn>
T parallel_max(std::int64_t begin, std::int64_t end, T init, Fn&& chunk_max, std::int64_t grain = 2048) {
  if (end <= begin) return init;
#if defined(SLURRY_PARALLEL_OPENMP)
  T result = init;
  const std::int64_t chunks = (end - begin + grain - 1) / grain;
#pragma omp parallel for schedule(dynamic, 1) reduction(max : result)
  for (std::int64_t c = 0; c < chunks; ++c)
    result = std::max(result, chunk_max(begin + c * grain, std::min(end, begin + (c + 1) * grain)));
  return result;
#elif defined(SLURRY_PARALLEL_TBB)
  T result = init;
  detail::in_arena([&] {
    result = tbb::parallel_reduce(
        tbb::blocked_range<std::int64_t>(begin, end, std::max<std::int64_t>(1, grain / 2)), init,
        [&](const tbb::blocked_range<std::int64_t>& r, T acc) {
          return std::max(acc, chunk_max(r.begin(), r.end()));
        },
        [](T a, T b) { return std::max(a, b); });
  });
  return result;
#else
  return std::max(init, chunk_max(begin, end));
#endif
}

/// Sum of chunk_sum(lo, hi) over the fixed chunks [begin + c grain, begin + (c + 1) grain) of
/// [begin, end), added in chunk order. The chunks do not depend on the thread count, so neither
/// do the bits of the result (unlike an OpenMP reduction(+)). Each chunk is one task: make grain
/// large enough to amortise it (or grain = 1 for a few heavy items).
template <class T, class Fn>
T parallel_sum(std::int64_t begin, std::int64_t end, std::int64_t grain, Fn&& chunk_sum) {
  if (end <= begin) return T(0);
  grain = std::max<std::int64_t>(grain, 1);
  const std::int64_t chunks = (end - begin + grain - 1) / grain;
  // The partial sums live on the stack up to 512 chunks (no allocation in a solver's inner
  // loop); beyond that on the heap.
  constexpr std::int64_t kStackChunks = 512;
  std::array<T, std::size_t(kStackChunks)> stack_partial;
  std::vector<T> heap_partial;
  T* partial = stack_partial.data();
  if (chunks > kStackChunks) {
    heap_partial.assign(static_cast<std::size_t>(chunks), T(0));
    partial = heap_partial.data();
  }
  const auto run = [&](std::int64_t c) {
    partial[static_cast<std::size_t>(c)] = chunk_sum(begin + c * grain, std::min(end, begin + (c + 1) * grain));
  };
#if defined(SLURRY_PARALLEL_OPENMP)
#pragma omp parallel for schedule(dynamic, 1)
  for (std::int64_t c = 0; c < chunks; ++c) run(c);
#elif defined(SLURRY_PARALLEL_TBB)
  detail::in_arena([&] {
    tbb::parallel_for(tbb::blocked_range<std::int64_t>(0, chunks, 1),
                      [&](const tbb::blocked_range<std::int64_t>& r) {
                        for (std::int64_t c = r.begin(); c < r.end(); ++c) run(c);
                      });
  });
#else
  for (std::int64_t c = 0; c < chunks; ++c) run(c);
#endif
  T sum = T(0);
  for (std::int64_t c = 0; c < chunks; ++c) sum += partial[c];
  return sum;
}

}  // namespace slurry::parallel
