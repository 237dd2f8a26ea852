// Session::solve_spd: a row-distributed SPD system solved by PETSc (KSPCG, PCHYPRE BoomerAMG).
#include <mpi.h>

#include <climits>
#include <stdexcept>
#include <string>
#include <vector>

#include "slurry/mpi/mpi.h"

#ifdef SLURRY_MPI_WITH_PETSC
#include <petscksp.h>
#endif

namespace slurry::mpi {

#ifdef SLURRY_MPI_WITH_PETSC
namespace {

void check(PetscErrorCode code, const char* what) {
  if (code == 0) return;
  const char* text = nullptr;
  PetscErrorMessage(code, &text, nullptr);
  throw std::runtime_error(std::string("PETSc: ") + what + " failed: " + (text ? text : "error " + std::to_string(code)));
}

// Destroys PETSc objects on every path out of solve_spd.
struct Objects {
  Mat A = nullptr;
  Vec b = nullptr, x = nullptr, r = nullptr;
  KSP ksp = nullptr;
  MatNullSpace null_space = nullptr;
  ~Objects() {
    if (null_space) MatNullSpaceDestroy(&null_space);
    if (ksp) KSPDestroy(&ksp);
    if (r) VecDestroy(&r);
    if (x) VecDestroy(&x);
    if (b) VecDestroy(&b);
    if (A) MatDestroy(&A);
  }
};

}  // namespace

DistributedSolve Session::solve_spd(const DistributedSystem& S, std::vector<double>& x, double rtol,
                                    int max_iterations) {
  if (!petsc_) {
    // The engine's own handlers (SIGINT, SIGTERM: stop after the frame) stay in place.
    check(PetscOptionsSetValue(nullptr, "-no_signal_handler", nullptr), "PetscOptionsSetValue");
    check(PetscInitializeNoArguments(), "PetscInitialize");
    petsc_ = true;
    // hypre's advice for 3D Laplacians (hypre user's manual, BoomerAMG): strong threshold 0.5,
    // HMIS coarsening with extended+i interpolation truncated to 4 entries a row, and aggressive
    // coarsening on the finest level. On a FLIP dam break's pressure (150 x 100 x 75 cells, 2
    // processes) it halved the setup and solve against PETSc's defaults (Falgout coarsening,
    // classical interpolation), at 10 iterations instead of 5. PETSC_OPTIONS overrides each.
    const char* defaults[][2] = {{"-pc_hypre_boomeramg_strong_threshold", "0.5"},
                                 {"-pc_hypre_boomeramg_coarsen_type", "HMIS"},
                                 {"-pc_hypre_boomeramg_interp_type", "ext+i"},
                                 {"-pc_hypre_boomeramg_P_max", "4"},
                                 {"-pc_hypre_boomeramg_agg_nl", "1"}};
    for (const auto& d : defaults) {
      PetscBool set = PETSC_FALSE;
      check(PetscOptionsHasName(nullptr, nullptr, d[0], &set), "PetscOptionsHasName");
      if (!set) check(PetscOptionsSetValue(nullptr, d[0], d[1]), "PetscOptionsSetValue");
    }
  }
  const std::size_t n = S.rhs.size();
  if (S.row_start.size() != n + 1 || S.row_start.front() != 0 ||
      std::size_t(S.row_start.back()) != S.columns.size() || S.columns.size() != S.values.size())
    throw std::invalid_argument("solve_spd: row_start, columns and values do not describe rhs.size() rows");
  // Rank r's rows follow rank r - 1's: the first row is the sum of the lower ranks' counts.
  long long rows = (long long)n, before = 0, total = 0;
  check(MPI_Exscan(&rows, &before, 1, MPI_LONG_LONG, MPI_SUM, MPI_COMM_WORLD), "MPI_Exscan");
  if (rank_ == 0) before = 0;
  check(MPI_Allreduce(&rows, &total, 1, MPI_LONG_LONG, MPI_SUM, MPI_COMM_WORLD), "MPI_Allreduce");
  if (before != S.first)
    throw std::invalid_argument("solve_spd: rank " + std::to_string(rank_) + " holds rows from " +
                                std::to_string(S.first) + ", expected " + std::to_string(before) +
                                " (after the lower ranks' rows)");
  if (total > (long long)PETSC_MAX_INT)
    throw std::invalid_argument("solve_spd: " + std::to_string(total) +
                                " rows exceed this PETSc's 32-bit indices");
  for (const auto c : S.columns)
    if (c < 0 || c >= total)
      throw std::invalid_argument("solve_spd: column " + std::to_string(c) + " outside the " +
                                  std::to_string(total) + " rows");
  Objects o;
  // Rows with their diagonal-block and off-diagonal-block counts, for the preallocation.
  std::vector<PetscInt> diagonal(n), off(n), columns(S.columns.size());
  for (std::size_t i = 0; i < n; ++i)
    for (auto k = S.row_start[i]; k < S.row_start[i + 1]; ++k) {
      const auto c = S.columns[std::size_t(k)];
      columns[std::size_t(k)] = PetscInt(c);
      (c >= S.first && c < S.first + (long long)n ? diagonal[i] : off[i])++;
    }
  check(MatCreate(PETSC_COMM_WORLD, &o.A), "MatCreate");
  check(MatSetSizes(o.A, PetscInt(n), PetscInt(n), PETSC_DETERMINE, PETSC_DETERMINE), "MatSetSizes");
  check(MatSetType(o.A, MATAIJ), "MatSetType");
  check(MatSeqAIJSetPreallocation(o.A, 0, diagonal.data()), "MatSeqAIJSetPreallocation");
  check(MatMPIAIJSetPreallocation(o.A, 0, diagonal.data(), 0, off.data()), "MatMPIAIJSetPreallocation");
  for (std::size_t i = 0; i < n; ++i) {
    const PetscInt row = PetscInt(S.first + (long long)i);
    const auto k = S.row_start[i];
    check(MatSetValues(o.A, 1, &row, PetscInt(S.row_start[i + 1] - k), columns.data() + k,
                       S.values.data() + k, INSERT_VALUES),
          "MatSetValues");
  }
  check(MatAssemblyBegin(o.A, MAT_FINAL_ASSEMBLY), "MatAssemblyBegin");
  check(MatAssemblyEnd(o.A, MAT_FINAL_ASSEMBLY), "MatAssemblyEnd");
  check(MatCreateVecs(o.A, &o.x, &o.b), "MatCreateVecs");
  x.resize(n, 0.0);
  PetscScalar* at = nullptr;
  check(VecGetArray(o.b, &at), "VecGetArray");
  for (std::size_t i = 0; i < n; ++i) at[i] = S.rhs[i];
  check(VecRestoreArray(o.b, &at), "VecRestoreArray");
  check(VecGetArray(o.x, &at), "VecGetArray");
  for (std::size_t i = 0; i < n; ++i) at[i] = x[i];
  check(VecRestoreArray(o.x, &at), "VecRestoreArray");
  if (S.constant_null_space) {
    check(MatNullSpaceCreate(PETSC_COMM_WORLD, PETSC_TRUE, 0, nullptr, &o.null_space), "MatNullSpaceCreate");
    check(MatSetNullSpace(o.A, o.null_space), "MatSetNullSpace");
    check(MatNullSpaceRemove(o.null_space, o.b), "MatNullSpaceRemove");
  }
  check(KSPCreate(PETSC_COMM_WORLD, &o.ksp), "KSPCreate");
  check(KSPSetOperators(o.ksp, o.A, o.A), "KSPSetOperators");
  check(KSPSetType(o.ksp, KSPCG), "KSPSetType");
  PC pc = nullptr;
  check(KSPGetPC(o.ksp, &pc), "KSPGetPC");
  check(PCSetType(pc, PCHYPRE), "PCSetType");
  check(PCHYPRESetType(pc, "boomeramg"), "PCHYPRESetType");
  check(KSPSetNormType(o.ksp, KSP_NORM_UNPRECONDITIONED), "KSPSetNormType");
  check(KSPSetTolerances(o.ksp, rtol, 0.0, PETSC_DEFAULT, max_iterations), "KSPSetTolerances");
  check(KSPSetInitialGuessNonzero(o.ksp, PETSC_TRUE), "KSPSetInitialGuessNonzero");
  check(KSPSetFromOptions(o.ksp), "KSPSetFromOptions");
  check(KSPSolve(o.ksp, o.b, o.x), "KSPSolve");
  DistributedSolve out;
  PetscInt iterations = 0;
  KSPConvergedReason reason;
  check(KSPGetIterationNumber(o.ksp, &iterations), "KSPGetIterationNumber");
  check(KSPGetConvergedReason(o.ksp, &reason), "KSPGetConvergedReason");
  out.iterations = int(iterations);
  out.converged = reason > 0;
  // The true relative residual, whatever norm the options chose.
  check(VecDuplicate(o.b, &o.r), "VecDuplicate");
  PetscReal rn = 0, bn = 0;
  check(MatMult(o.A, o.x, o.r), "MatMult");
  check(VecAYPX(o.r, -1.0, o.b), "VecAYPX");
  check(VecNorm(o.r, NORM_2, &rn), "VecNorm");
  check(VecNorm(o.b, NORM_2, &bn), "VecNorm");
  out.residual = bn > 0 ? double(rn / bn) : double(rn);
  const PetscScalar* result = nullptr;
  check(VecGetArrayRead(o.x, &result), "VecGetArrayRead");
  for (std::size_t i = 0; i < n; ++i) x[i] = double(result[i]);
  check(VecRestoreArrayRead(o.x, &result), "VecRestoreArrayRead");
  return out;
}

void Session::finalize_petsc() {
  if (petsc_) PetscFinalize();
  petsc_ = false;
}

#else

DistributedSolve Session::solve_spd(const DistributedSystem& A, std::vector<double>& x, double rtol,
                                    int max_iterations) {
  return Communicator::solve_spd(A, x, rtol, max_iterations);
}

void Session::finalize_petsc() {}

#endif

}  // namespace slurry::mpi
