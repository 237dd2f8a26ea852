// A FLIP liquid split over processes (flip/split.h: boxes of cells, ghost particles, the pressure
// rows solved by PETSc's CG with hypre's BoomerAMG) against the same scene in one process (the
// solver's own multigrid-preconditioned CG), under mpirun -np N (ctest label "mpi").
//
//   flip_split_check SCENE FRAMES EXACT_FRAMES MAX_CELLS MEAN_CELLS [TOLERANCE [REFERENCE_TOLERANCE]]
//                    [--resume-at=F [--per-rank]]
//
// With --resume-at=F the split run saves its state after frame F (gathered on rank 0, the
// checkpoint's layout) and goes on from it in a new split simulation; rank 0 also loads it into
// a one-process simulation, and the check compares both with the uninterrupted one-process run.
// With --per-rank every process saves its own part instead (save_own_state, the parts of
// output.per_rank checkpoints), and both load the parts (load_state_parts).
//
// REFERENCE_TOLERANCE, if given, is the one-process run's pressure tolerance: under mpirun -np 1
// (no split) the check then measures how far two one-process runs drift apart that differ only
// in their pressure solves' tolerance, the yardstick for the split's distance.
//
// Every rank runs the split simulation; rank 0 also runs the scene alone. Both solve the
// pressure to the scene's relative residual (solver.pressure.tolerance, or TOLERANCE), so the
// two runs differ by what the two solvers leave, and that difference is carried on by the flow.
// After each frame rank 0 prints, per frame: the largest and the mean distance between a
// particle's positions in the two runs (in cells, particles matched by id), the liquid volume
// (RunStats::volume) and the largest |div u| of the last projection in each run. A splash
// amplifies any difference (two one-process runs whose tolerances are 1e-6 and 1e-7 drift as far
// apart as the split and one process do), so particle by particle the runs are compared over the
// first EXACT_FRAMES frames, and after them on average. The check fails (exit 1) when one of the
// first EXACT_FRAMES frames has a largest distance above MAX_CELLS, any frame a mean distance
// above MEAN_CELLS, the particle counts differ, the volumes differ by more than 0.5%, a split
// projection did not converge, its divergence exceeds the one-process run's by more than a
// factor 10 plus 1e-3 1/s, or the surface energy (surface tension) differs by more than 0.1%.
// With whitewater (solver.whitewater) the secondary particles of the first EXACT_FRAMES frames
// must also be the same (ids) and within MAX_CELLS of one process's.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/run/run.h"
#include "slurry/io/scene_file.h"
#include "slurry/mpi/mpi.h"

namespace {

struct Row {
  double max_cells = 0, mean_cells = 0;
};

template <class T, int Dim>
Row distance(const slurry::Solver& split, const slurry::Solver& one, double dx) {
  const auto a = split.particles_view<T, Dim>();
  const auto b = one.particles_view<T, Dim>();
  Row r;
  if (a.size() != b.size()) {
    r.max_cells = INFINITY;
    return r;
  }
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a.id(i) != b.id(i)) {
      r.max_cells = INFINITY;
      return r;
    }
    const double d = double((a.position(i) - b.position(i)).norm()) / dx;
    r.max_cells = std::max(r.max_cells, d);
    r.mean_cells += d;
  }
  if (a.size() > 0) r.mean_cells /= double(a.size());
  return r;
}

/// Secondary particles (solver.whitewater) of the two runs' frames (whitewater_frame_view: the
/// split run's gathered on rank 0): their counts and, when they hold the same ids, the largest
/// distance between a particle's positions, in cells.
struct Secondary {
  std::size_t split = 0, one = 0;
  bool same_ids = false;
  double max_cells = 0;
};

Secondary whitewater_distance(const slurry::Frame& a, const slurry::Frame& b, double dx, int dim) {
  Secondary r;
  const auto columns = [dim](const slurry::Frame& f) {
    std::vector<std::vector<double>> c;
    if (f.tables.empty()) return c;
    for (const char* name : {"id", "x", "y", "z"})
      if (name[0] == 'i' || (name[0] - 'x') < dim) c.push_back(f.tables[0].column_as_double(name));
    return c;
  };
  const auto ca = columns(a), cb = columns(b);
  r.split = ca.empty() ? 0 : ca[0].size();
  r.one = cb.empty() ? 0 : cb[0].size();
  r.same_ids = r.split == r.one && (ca.empty() || ca[0] == cb[0]);  // both in ascending id
  if (!r.same_ids) return r;
  for (std::size_t i = 0; i < r.split; ++i) {
    double d2 = 0;
    for (std::size_t k = 1; k < ca.size(); ++k) d2 += (ca[k][i] - cb[k][i]) * (ca[k][i] - cb[k][i]);
    r.max_cells = std::max(r.max_cells, std::sqrt(d2) / dx);
  }
  return r;
}

template <class T, int Dim>
const slurry::flip::ProjectionReport& projection(const slurry::Solver& s) {
  return dynamic_cast<const slurry::flip::FlipSolver<T, Dim>&>(s).last_projection();
}

template <class T, int Dim>
int check(slurry::mpi::Session& mpi, const slurry::Scene& scene, const slurry::Scene& reference, int frames, int exact,
          double max_cells, double mean_cells, int resume_at, bool per_rank) {
  auto split = slurry::make_simulation(scene, &mpi);
  std::unique_ptr<slurry::Solver> one;
  const bool root = mpi.rank() == 0;
  if (root) one = slurry::make_simulation(reference, nullptr);
  std::unique_ptr<slurry::Solver> solo;  // rank 0: the one-process run resumed from the split's state
  int failed = 0;
  if (root) {
    std::printf("%s on %d processes: largest and mean particle distance from the one-process run (cells), volume, max |div u|\n",
                scene.source.c_str(), mpi.size());
    std::printf("| frame | largest | mean | volume, 1 process (m^%d) | split | max div, 1 process (1/s) | split | split CG iterations |\n", Dim);
    std::printf("| --- | --- | --- | --- | --- | --- | --- | --- |\n");
  }
  for (int f = 1; f <= frames; ++f) {
    const double t = f * scene.frame_dt();
    split->advance_to(t);
    if (root) one->advance_to(t);
    if (f == resume_at) {
      const std::string what = "the split run's state at frame " + std::to_string(f);
      std::string state;
      if (per_rank)
        split->save_own_state([&state](const char* data, std::size_t size) { state.append(data, size); });
      else
        split->save_state(state);
      const std::vector<std::string> saved = mpi.all_gather(per_rank || root ? state : std::string());
      const auto load = [&](slurry::Solver& s) {
        if (per_rank)
          s.load_state_parts(int(saved.size()), [&saved](int i) { return saved[std::size_t(i)]; }, what);
        else
          s.load_state(saved[0], what);
      };
      if (saved[0].empty()) {
        if (root) std::printf("FAIL: frame %d: the split run saved an empty state\n", f);
        ++failed;
      }
      auto resumed = slurry::make_simulation(scene, &mpi);
      load(*resumed);
      split = std::move(resumed);
      if (root) {
        solo = slurry::make_simulation(reference, nullptr);
        load(*solo);
        std::printf("resumed at frame %d over %d processes and in one process (%s, %zu bytes on rank 0)\n", f, mpi.size(),
                    per_rank ? "per-process parts" : "gathered", saved[0].size());
      }
    }
    (void)split->frame({"position"});  // gathers every particle on rank 0 (particle_storage)
    const slurry::RunStats s = split->take_stats();
    const auto& ps = projection<T, Dim>(*split);
    if (solo && f > resume_at) solo->advance_to(t);
    const std::string status = split->solver_status();
    const slurry::Frame split_whitewater = split->whitewater_frame_view();  // every rank: a gather
    if (!root) continue;
    if (f == 1) std::printf("split: %s\n", status.c_str());
    const slurry::RunStats o = one->take_stats();
    const auto& po = projection<T, Dim>(*one);
    const Row r = distance<T, Dim>(*split, *one, scene.domain.dx);
    if (solo) {
      const Row q = distance<T, Dim>(*solo, *one, scene.domain.dx);
      std::printf("| %d, resumed in one process | %.3g | %.3g |  |  |  |  |  |\n", f, q.max_cells, q.mean_cells);
      if (f <= exact && !(q.max_cells <= max_cells)) std::printf("FAIL: frame %d: resumed in one process, %.3g cells apart\n", f, q.max_cells), ++failed;
      if (!(q.mean_cells <= mean_cells)) std::printf("FAIL: frame %d: resumed in one process, %.3g cells apart on average\n", f, q.mean_cells), ++failed;
    }
    std::printf("| %d | %.3g | %.3g | %.6g | %.6g | %.3g | %.3g | %d |\n", f, r.max_cells, r.mean_cells, o.volume, s.volume,
                po.max_divergence, ps.max_divergence, ps.iterations);
    if (f <= exact && !(r.max_cells <= max_cells)) std::printf("FAIL: frame %d: particles moved apart by %.3g cells (> %.3g)\n", f, r.max_cells, max_cells), ++failed;
    if (!(r.mean_cells <= mean_cells))
      std::printf("FAIL: frame %d: particles moved apart by %.3g cells on average (> %.3g)\n", f, r.mean_cells, mean_cells), ++failed;
    if (s.particles != o.particles) std::printf("FAIL: frame %d: %zu particles, one process %zu\n", f, s.particles, o.particles), ++failed;
    if (!(std::abs(s.volume - o.volume) <= 5e-3 * o.volume))
      std::printf("FAIL: frame %d: volume %.6g, one process %.6g\n", f, s.volume, o.volume), ++failed;
    if (!ps.converged) std::printf("FAIL: frame %d: the split pressure solve did not converge\n", f), ++failed;
    if (!(std::abs(s.surface - o.surface) <= 1e-3 * std::abs(o.surface)))
      std::printf("FAIL: frame %d: surface energy %.6g J, one process %.6g J\n", f, s.surface, o.surface), ++failed;
    if (!(ps.max_divergence <= 10 * po.max_divergence + 1e-3))
      std::printf("FAIL: frame %d: max |div u| %.3g, one process %.3g\n", f, ps.max_divergence, po.max_divergence), ++failed;
    if (scene.solver.whitewater.enabled) {
      const Secondary w = whitewater_distance(split_whitewater, one->whitewater_frame_view(), scene.domain.dx, Dim);
      std::printf("|   whitewater | %zu particles, one process %zu | %s |\n", w.split, w.one,
                  w.same_ids ? ("the same ids, largest distance " + std::to_string(w.max_cells) + " cells").c_str()
                             : "other ids");
      if (f <= exact && !(w.same_ids && w.max_cells <= max_cells))
        std::printf("FAIL: frame %d: whitewater %zu particles, one process %zu (%s, %.3g cells apart)\n", f, w.split, w.one,
                    w.same_ids ? "the same ids" : "other ids", w.max_cells), ++failed;
    }
  }
  if (root) {  // where the time went: rank 0 of the split run against the one-process run
    const auto& a = dynamic_cast<const slurry::flip::FlipSolver<T, Dim>&>(*split).phase_seconds();
    const auto& b = dynamic_cast<const slurry::flip::FlipSolver<T, Dim>&>(*one).phase_seconds();
    std::printf("phase seconds, rank 0 of the split run / one process:");
    for (int p = 0; p < slurry::flip::kPhaseCount; ++p)
      if (a[std::size_t(p)] + b[std::size_t(p)] > 0)
        std::printf(" %s %.3g / %.3g;", slurry::flip::phase_name(p), a[std::size_t(p)], b[std::size_t(p)]);
    std::printf("\n%s\n", failed ? "FAILED" : "passed");
  }
  double result = failed;
  mpi.max(&result, 1);
  return result > 0 ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  slurry::mpi::Session mpi(argc, argv);
  if (argc < 6) {
    if (mpi.rank() == 0)
      std::fprintf(stderr, "usage: flip_split_check SCENE FRAMES EXACT_FRAMES MAX_CELLS MEAN_CELLS [TOLERANCE [REFERENCE_TOLERANCE]]\n");
    return 2;
  }
  try {
    int resume_at = -1;
    bool per_rank = false;
    for (int a = 6; a < argc; ++a) {
      const std::string arg = argv[a];
      if (arg.rfind("--resume-at=", 0) == 0 || arg == "--per-rank") {
        for (int b = a; b < argc; ++b) {
          const std::string flag = argv[b];
          if (flag.rfind("--resume-at=", 0) == 0) resume_at = std::atoi(argv[b] + 12);
          if (flag == "--per-rank") per_rank = true;
        }
        argc = a;
        break;
      }
    }
    slurry::Scene scene = slurry::load_scene(argv[1]);
    scene.output.checkpoint_every = 0;
    if (argc > 6) scene.solver.pressure.tolerance = std::atof(argv[6]);
    slurry::Scene reference = scene;
    if (argc > 7) reference.solver.pressure.tolerance = std::atof(argv[7]);
    const int frames = std::atoi(argv[2]), exact = std::atoi(argv[3]);
    const double max_cells = std::atof(argv[4]), mean_cells = std::atof(argv[5]);
    const bool dbl = scene.solver.precision == slurry::Precision::Double;
    if (scene.solver.dimension == 2)
      return dbl ? check<double, 2>(mpi, scene, reference, frames, exact, max_cells, mean_cells, resume_at, per_rank)
                 : check<float, 2>(mpi, scene, reference, frames, exact, max_cells, mean_cells, resume_at, per_rank);
    return dbl ? check<double, 3>(mpi, scene, reference, frames, exact, max_cells, mean_cells, resume_at, per_rank)
               : check<float, 3>(mpi, scene, reference, frames, exact, max_cells, mean_cells, resume_at, per_rank);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rank %d: %s\n", mpi.rank(), e.what());
    return 1;
  }
}
