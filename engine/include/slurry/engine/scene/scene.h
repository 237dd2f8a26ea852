#pragma once
/// \file scene.h
/// A scene: domain, solver settings, materials, bodies, boundaries, colliders and output.
///
/// Every struct field is named exactly as its key in the scene JSON file (docs/scene-reference.md;
/// the file is read by load_scene, slurry/io/scene_file.h); defaults are the values a key takes when it is absent. `validate()` checks
/// ranges and cross references and throws slurry::SceneError naming the source, the JSON path
/// (e.g. `materials[0].nu`), the value and what was expected. Vectors are stored with three
/// components; in 2D the third is ignored and the JSON arrays have two entries.
#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "slurry/engine/errors.h"

namespace slurry {

struct SceneFiles;  // scene_files.h

enum class Precision { Float, Double };
enum class TransferKind { PIC, FLIP, APIC, MLS };
enum class KernelKind { Linear, Quadratic, Cubic };
/// Which solver runs the scene: MPM (particles on a collocated grid), FLIP/APIC liquid
/// (particles on a staggered grid with pressure projection), or a Lagrangian FEM mesh.
enum class SolverType { MPM, FLIP, FEM };
/// Grid (MPM) or node (FEM) update: symplectic Euler, or linearly implicit backward Euler.
enum class Integrator { Explicit, Implicit };
/// Preconditioner of the implicit MPM grid solve's CG: inverse diagonal, inverse node blocks, or
/// zero fill-in incomplete Cholesky of the assembled matrix.
enum class ImplicitPreconditioner { Jacobi, BlockJacobi, IC0 };
enum class ElasticModel { CorotatedLinear, FixedCorotated, NeoHookean, StVK, HenckyStVK, Fluid };
enum class PlasticModel { None, Snow, DruckerPrager, VonMises };
enum class Shape { Box, Sphere, Cylinder, Mesh };
enum class Sampling { Regular, Jittered };
enum class ColliderShape { HalfSpace, Box, Sphere, Mesh };
/// Boundary conditions on grid velocity relative to the boundary's velocity:
/// sticky (v = v_b), slip (normal part removed), separate (normal part removed only when
/// approaching, tangential part reduced by Coulomb friction mu |v_n|).
enum class Condition { Sticky, Slip, Separate };
enum class PlyEncoding { Binary, Ascii };
/// Background grid storage: blocks allocated where particles are (sparse), or one box (dense);
/// auto: sparse, except for the implicit integrator, which runs on the dense grid.
enum class GridKind { Auto, Sparse, Dense };
/// FLIP particle advection through the grid velocity: forward Euler (order 1), explicit
/// midpoint (RK2), trapezoidal / Heun (RK2) or Kutta's third-order method (RK3).
enum class AdvectionScheme { Euler, Midpoint, Heun, RK3 };
/// Where the FLIP pressure solve puts the free surface (level_set.h). Cell: every liquid cell at
/// phi = -dx/2, the surface between a liquid cell and its air neighbour at the air's distance to
/// the particles. Subcell: the liquid's surface cells take phi from the air beside them, so the
/// surface sits at the particles' extent inside the cell, and nearly empty faces are left
/// unprojected where liquid behind them holds their cell (pressure.h). Auto: subcell for scenes
/// with surface tension or viscosity, whose jump and stress-free condition act at the surface,
/// cell otherwise.
enum class FreeSurface { Auto, Cell, Subcell };
/// Preconditioner of the FLIP pressure solve (PCG).
/// Multigrid: one V-cycle per iteration (McAdams et al. 2010), about 7 iterations at any size.
enum class PressurePreconditioner { None, Jacobi, MIC0, Multigrid };
/// What a run does when the health check fires (SimulationError): stop after the last good
/// frame, or roll back to the start of the frame and redo it with the substep halved.
enum class OnInstability { Stop, Retry };

struct DomainParams {
  Eigen::Vector3d min{0, 0, 0};  ///< lower corner (m)
  Eigen::Vector3d max{1, 1, 1};  ///< upper corner (m); rounded up to whole cells of dx
  double dx = 0.02;              ///< grid spacing (m), > 0
  /// MPM grid. "sparse": 4^3 (2D: 8^2) node blocks allocated each step where particles reach,
  /// memory follows the occupied volume; "dense": one array over the domain (same results);
  /// "auto": sparse, or dense for solver.integrator "implicit" (which needs it).
  GridKind grid = GridKind::Auto;
};

/// FLIP pressure projection: PCG on the Poisson system (relative residual tolerance).
struct PressureParams {
  PressurePreconditioner preconditioner = PressurePreconditioner::MIC0;  ///< "mic0", "multigrid", "jacobi", "none"
  double tolerance = 1e-6;   ///< relative residual |r| / |b|, (0, 1)
  int max_iterations = 1000; ///< PCG iterations per projection, >= 1
};

/// FLIP particle reseeding: after advection, fluid cells deep inside the liquid (every
/// neighbour fluid or solid) with fewer than min_per_cell particles get new ones, and every cell
/// with more than max_per_cell loses the surplus.
struct ReseedParams {
  int min_per_cell = 0;  ///< 0 turns adding off (holes are liquid by their labels anyway)
  /// 0 turns removal off (the default: a removed particle is liquid volume lost for good, and
  /// solver.volume_correction spreads bunched particles out instead); else > min_per_cell.
  int max_per_cell = 0;
};

/// MPM sleeping material ("model only what moves"): the particles of a grid block that have all
/// moved slower than `speed` and deformed slower than `strain_rate` (the norm of their velocity
/// gradient C) for `substeps` substeps in a row go to sleep: their velocity is set to zero, their
/// contribution to the grid is kept from their last scatter, and the stress update, the gather
/// and the plastic projection skip them. A sleeping block wakes when a node it reaches moves
/// faster than `wake_speed` after the grid update (something hit it or the ground moved) or a
/// particle enters or leaves it. Off (speed 0) by default; explicit MPM only.
struct SleepParams {
  double speed = 0;           ///< m/s; 0 turns sleeping off
  double strain_rate = 0.5;   ///< 1/s, > 0
  int substeps = 100;         ///< calm substeps in a row before a block sleeps, [1, 65535]
  double wake_speed = 0;      ///< m/s; 0 = 2 x speed
};

/// FLIP whitewater (solver.whitewater, flip/whitewater.h): secondary spray, foam and bubble
/// particles after Ihmsen et al. 2012, one-way coupled to the liquid. Each liquid cell generates
/// Phi_k (trapped_air_rate Phi_ta + wave_crest_rate Phi_wc) particles per second, each potential
/// Phi clamped to [0, 1] between its min and max. Off by default: nothing is allocated or run.
struct WhitewaterParams {
  bool enabled = false;
  std::int64_t seed = 1;              ///< of the generation's counter-based hash, [0, 2^32)
  double trapped_air_rate = 150;      ///< particles per second of a liquid cell at full potential, >= 0
  double wave_crest_rate = 200;       ///< the same for wave crests, >= 0
  double trapped_air_min = 1;         ///< m/s, >= 0: trapped-air potential below which nothing is generated
  double trapped_air_max = 4;         ///< m/s, > trapped_air_min: full potential
  double wave_crest_min = 0.1;        ///< dimensionless curvature measure, >= 0
  double wave_crest_max = 1;          ///< > wave_crest_min
  double kinetic_energy_min = 0.2;    ///< J/kg (|v|^2 / 2), >= 0
  double kinetic_energy_max = 3;      ///< J/kg, > kinetic_energy_min
  double lifetime_min = 1;            ///< s, foam lifetime drawn in [lifetime_min, lifetime_max], > 0
  double lifetime_max = 3;            ///< s, >= lifetime_min
  double spray_drag = 0.5;            ///< 1/s, linear air drag of spray, >= 0
  double bubble_buoyancy = 1;         ///< buoyant acceleration of bubbles in units of |gravity|, >= 0
  double bubble_drag = 40;            ///< 1/s, rate bubbles take the liquid's velocity, > 0
  double spray_distance = 0.5;        ///< cells: above the surface by more than this is spray, [0, 2]
  double bubble_depth = 1;            ///< cells: below the surface by more than this is a bubble, [0.25, 3]
  std::int64_t max_particles = 1000000;  ///< oldest removed beyond it, [0, 2^31 - 1]
};

struct SolverParams {
  SolverType type = SolverType::MPM;     ///< "mpm", "flip" or "fem"
  int dimension = 3;                     ///< 2 or 3
  Precision precision = Precision::Float;
  TransferKind transfer = TransferKind::MLS;
  KernelKind kernel = KernelKind::Quadratic;
  double flip_ratio = 0.95;  ///< FLIP share of the FLIP/PIC blend, [0, 1]; transfer "flip" only
  double cfl = 0.5;  ///< max particle displacement per substep in cells, (0, 1] (MPM), (0, 5] (FLIP)
  double elastic_cfl = 0.5;  ///< dt <= elastic_cfl dx / c with c = sqrt((lambda + 2 mu) / rho)
  Eigen::Vector3d gravity{0, -9.81, 0};  ///< m/s^2
  double max_dt = 1e-3;                  ///< upper bound on the substep (s)
  AdvectionScheme advection = AdvectionScheme::Midpoint;  ///< FLIP only
  FreeSurface free_surface = FreeSurface::Auto;           ///< FLIP only: "auto", "cell" or "subcell"
  PressureParams pressure;                                ///< FLIP only
  ReseedParams reseed;                                    ///< FLIP only
  /// FLIP only: share in [0, 1] of the particle over- or under-density of interior fluid cells
  /// that each pressure projection corrects (a target divergence), so that particles bunched by
  /// large steps spread out again instead of the liquid losing volume; 0 = off.
  double volume_correction = 0.5;
  Integrator integrator = Integrator::Explicit;  ///< "explicit" or "implicit" (MPM solids)
  double cg_tolerance = 1e-6;  ///< implicit: CG relative residual, (0, 1)
  int cg_max_iterations = 500;  ///< implicit: CG iteration cap, >= 1
  /// implicit MPM: "ic0" (block Jacobi where IC(0) breaks down), "block_jacobi" or "jacobi"
  ImplicitPreconditioner implicit_preconditioner = ImplicitPreconditioner::IC0;
  /// "stop": an unstable substep ends the run after the last good frame. "retry": the frame is
  /// redone from its start with the substep halved, up to max_retries halvings (run.h).
  OnInstability on_instability = OnInstability::Stop;
  int max_retries = 3;  ///< halvings per frame for on_instability "retry", [1, 30]
  SleepParams sleep;     ///< MPM only
  WhitewaterParams whitewater;  ///< FLIP only
};

struct MaterialParams {
  std::string name;
  ElasticModel model = ElasticModel::FixedCorotated;
  double density = 1000;  ///< kg/m^3 (per unit area in 2D)
  double E = 1e5;         ///< Young's modulus (Pa), solids
  double nu = 0.3;        ///< Poisson ratio in (-1, 0.5), solids
  double bulk_modulus = 1e5;  ///< K (Pa), fluid
  double gamma = 7;           ///< Tait exponent, fluid
  PlasticModel plasticity = PlasticModel::None;
  double critical_compression = 2.5e-2;  ///< snow theta_c
  double critical_stretch = 7.5e-3;      ///< snow theta_s
  double hardening = 10;                 ///< snow xi
  double friction_angle = 30;            ///< Drucker-Prager, degrees in (0, 90)
  double yield_stress = 1e4;             ///< von Mises (Pa)
  /// FEM only: Rayleigh stiffness-proportional damping beta (s), D = beta K; >= 0.
  double damping = 0;
  /// FLIP only: dynamic viscosity mu (Pa s) of the liquid, finite and >= 0; 0 = inviscid (the
  /// viscosity solve is skipped). Water 1e-3, honey 2-10, thick tar 1e3 and more.
  double viscosity = 0;
  /// FLIP only: surface tension sigma (N/m) of the liquid against air, finite and >= 0; 0 = none
  /// (skipped). Water 0.0728, ethanol 0.022, mercury 0.485. All liquids of a scene share one.
  double surface_tension = 0;
};

struct BodyParams {
  Shape shape = Shape::Box;
  Eigen::Vector3d min{0, 0, 0}, max{0, 0, 0};  ///< box
  Eigen::Vector3d center{0, 0, 0};             ///< sphere, cylinder (centre of the axis)
  double radius = 0;                           ///< sphere, cylinder
  double height = 0;                           ///< cylinder, along `axis`
  int axis = 1;                                ///< cylinder axis: 0, 1 or 2
  std::string material;                        ///< name of a material
  Eigen::Vector3d velocity{0, 0, 0};           ///< initial velocity (m/s)
  double particles_per_cell = 8;  ///< seeding density; spacing dx / ppc^(1/dimension)
  Sampling sampling = Sampling::Regular;
  std::uint64_t seed = 1;  ///< jittered sampling only
  /// FEM: TetGen mesh (path of the .node file, or of its stem; the .ele file sits beside it),
  /// relative to the scene file; empty: the body's shape is meshed by the solver. MPM and FLIP,
  /// shape "mesh" (3D): a closed triangle mesh (.obj or .ply) whose inside is filled.
  std::string mesh;
  /// Shape "mesh": placement of the mesh file's coordinates, x -> R (scale .* x) + translation,
  /// R from Euler angles in degrees about x, then y, then z (geometry/triangle_mesh.h).
  Eigen::Vector3d scale{1, 1, 1};
  Eigen::Vector3d rotation{0, 0, 0};
  Eigen::Vector3d translation{0, 0, 0};
};

struct BoundaryParams {
  Condition walls = Condition::Separate;  ///< on the six (four) domain faces
  double friction = 0;                    ///< Coulomb coefficient, condition "separate" only
  int thickness = 2;  ///< cells next to each face whose nodes the wall condition holds
};

/// One key of a mesh collider's rigid motion: its pose at `time` (translation, Euler degrees).
struct ColliderKeyframe {
  double time = 0;  ///< s; keys in increasing time
  Eigen::Vector3d translation{0, 0, 0};
  Eigen::Vector3d rotation{0, 0, 0};
};

struct ColliderParams {
  ColliderShape shape = ColliderShape::HalfSpace;
  /// "mesh" (3D): a closed triangle mesh (.obj or .ply, relative to the scene file), placed by
  /// scale, rotation (Euler degrees about x, y, z) and translation like a mesh body, and moved
  /// by `keyframes` (linear translation, slerp rotation; held before the first and after the
  /// last key; they replace translation and rotation) plus `velocity` times t.
  std::string mesh;
  Eigen::Vector3d scale{1, 1, 1};
  Eigen::Vector3d rotation{0, 0, 0};
  Eigen::Vector3d translation{0, 0, 0};
  std::vector<ColliderKeyframe> keyframes;
  Eigen::Vector3d point{0, 0, 0}, normal{0, 1, 0};  ///< half_space: solid where (x-point).n < 0
  Eigen::Vector3d min{0, 0, 0}, max{0, 0, 0};       ///< box
  Eigen::Vector3d center{0, 0, 0};                  ///< sphere
  double radius = 0;                                ///< sphere
  Eigen::Vector3d velocity{0, 0, 0};  ///< the collider translates at this velocity (m/s)
  Condition condition = Condition::Separate;
  double friction = 0;
};

/// FLIP only: an inflow region (box or sphere) kept full of liquid moving at `velocity` between
/// `start` and `end`: its cells are topped up to particles_per_cell (seeded random positions),
/// at most `rate` (m^3/s; m^2/s in 2D) of new liquid per second.
struct EmitterParams {
  Shape shape = Shape::Box;                     ///< "box" or "sphere"
  Eigen::Vector3d min{0, 0, 0}, max{0, 0, 0};  ///< box
  Eigen::Vector3d center{0, 0, 0};             ///< sphere
  double radius = 0;                           ///< sphere
  double rate = 0;                             ///< largest volume per second (m^3/s, m^2/s in 2D), > 0
  Eigen::Vector3d velocity{0, 0, 0};           ///< of the emitted liquid (m/s)
  double start = 0;                            ///< s
  double end = 1e30;                           ///< s, > start
  std::string material;                        ///< name of a material
  double particles_per_cell = 8;               ///< density of the emitted particles
  std::uint64_t seed = 1;                      ///< of the emission positions
};

/// The smallest voxel edge (m) of the OpenVDB outputs (surfaces and points): OpenVDB's scale
/// transforms refuse a voxel whose volume is below 3e-15 m^3 (3 x its double tolerance).
constexpr double kMinVoxelSize = 1.45e-5;

struct OutputParams {
  std::string directory = "frames";  ///< relative paths are relative to the working directory
  double fps = 24;
  int frames = 24;  ///< frames written after the initial one (frame 0)
  std::vector<std::string> attributes{"position"};  ///< position, velocity, material, J, plastic, id
  PlyEncoding format = PlyEncoding::Binary;
  /// The axis that is up in every file written (frames, surfaces, points): "y", the simulation's
  /// own axes (gravity along -y in the shipped scenes), or "z" for Z-up tools, the rotation by
  /// +90 degrees about x, (x, y, z) -> (x, -z, y), velocities alike; 3D scenes only. Checkpoints
  /// and stats.csv stay in the simulation's axes.
  std::string up_axis = "y";
  /// Effects-pipeline outputs beside each frame (written by the CLI built with slurry::io; the
  /// engine only validates them): the liquid's surface as any of "vdb" (a level set grid named
  /// "surface"), "ply" and "obj" (its triangle mesh); OpenVDB points with v, id and pscale.
  std::vector<std::string> surface;
  bool vdb_points = false;
  double surface_voxel_size = 0;      ///< m; 0 = domain.dx; at least kMinVoxelSize
  /// "anisotropic" (Yu & Turk 2013 kernels, volume kept) or "spheres" (union of spheres, then a
  /// closing); slurry/io/surface.h
  std::string surface_method = "anisotropic";
  int surface_smoothing = 0;          ///< Gaussian filter passes (of the field, or of the level set), [0, 100]
  bool surface_per_material = false;  ///< one surface per liquid material instead of one for all
  /// Drift warnings (stats.h): relative change of the total mass, of the volume, and growth of
  /// the total energy relative to the energy available, beyond which a frame is reported.
  double mass_drift = 1e-4;
  double volume_drift = 0.1;
  double energy_growth = 0.05;
  /// A checkpoint (the full solver state, run.h) is written beside the frames every this many
  /// frames; the last two are kept. 0 = none.
  int checkpoint_every = 10;
  /// A run split over MPI processes: each process writes its own particles to
  /// frame_NNNN.rankR.ply (no gather on one process) and `slurry merge DIR` joins them into the
  /// frame_NNNN.ply a single process writes. One process writes frame_NNNN.ply as always.
  bool per_rank = false;
  /// The run estimates its own discretization error: a shadow simulation of the same scene at
  /// twice domain.dx runs beside it (about 1/8 of the work in 3D, 1/4 in 2D; MPM walls keep their
  /// thickness in metres), and every row of stats.csv gets Richardson estimates of the error of
  /// the total energy and of each material's centroid, |Q(dx) - Q(2 dx)| / (2^p - 1) with p =
  /// error_order (run/error_estimate.h). MPM and FLIP in one process.
  bool error_estimate = false;
  /// p of the estimate: the observed order in dx of the quantity. 1.5 is the median of the
  /// orders the speed-against-accuracy study observed at the defaults (docs/accuracy.md).
  double error_order = 1.5;
};

/// Limits checked before a run allocates or steps (docs/scene-reference.md, `limits`): the estimated memory of
/// particles, grid and mesh, and the substeps a frame may take.
struct LimitsParams {
  /// Largest estimated memory use (GiB); 0 = the machine's physical memory.
  double memory_gb = 0;
  /// A frame needing more substeps than this is an error naming the limit (solver.max_dt,
  /// solver.cfl or solver.elastic_cfl) that makes the substep so small; >= 1.
  std::int64_t substeps_per_frame = 1000000;
};

/// What a scene will allocate, estimated from its parameters before anything is allocated.
struct ResourceEstimate {
  double particles = 0;  ///< particles its bodies seed (bounding lattice times the shape's volume fraction)
  double grid_nodes = 0; ///< nodes (MPM dense grid) or cells (FLIP) allocated up front
  double elements = 0;   ///< FEM elements meshed from box and sphere bodies
  double bytes = 0;      ///< all of it together
};

struct Scene {
  std::string source = "<scene>";  ///< the file it came from, for messages
  /// FNV-1a hash of the scene file's bytes (parse_scene's text; 0 for a scene built in code):
  /// checkpoints record it, so that a changed scene is not resumed by mistake.
  std::uint64_t source_hash = 0;
  DomainParams domain;
  SolverParams solver;
  std::vector<MaterialParams> materials;
  std::vector<BodyParams> bodies;
  BoundaryParams boundaries;
  std::vector<ColliderParams> colliders;
  std::vector<EmitterParams> emitters;  ///< FLIP only
  OutputParams output;
  LimitsParams limits;
  /// The mesh files the scene names, read (scene_files.h); null until io::read_scene_files() or
  /// make_simulation() reads them. The solvers take their meshes from here and open no file.
  std::shared_ptr<const SceneFiles> files;

  /// Throws SceneError for the first invalid field.
  void validate() const;
  /// The checks particular to solver.type "flip" (called by validate()).
  void validate_flip() const;
  /// The checks of output.surface, output.vdb_points and their parameters (called by validate()).
  void validate_pipeline_outputs() const;
  /// Index of the material named `name`, or -1.
  int material_index(std::string_view name) const;
  /// The frame duration 1 / output.fps.
  double frame_dt() const { return 1.0 / output.fps; }
  /// The allocation the scene will make (see ResourceEstimate).
  ResourceEstimate estimate() const;
  /// A mesh file named in the scene, relative to the scene file's directory unless absolute.
  std::filesystem::path resolve(const std::string& file) const;
  /// The smallest explicit elastic substep elastic_cfl dx / c over the materials (c the wave
  /// speed), or +infinity where no elastic limit applies (implicit, FLIP, FEM).
  double elastic_dt() const;
};

/// The machine's physical memory in bytes (0 if unknown).
double physical_memory_bytes();
/// Throws ResourceError if the scene's estimate exceeds `memory_gb` GiB (0: limits.memory_gb,
/// and if that is 0 too, the machine's physical memory). Names the largest consumer.
void check_resources(const Scene& scene, double memory_gb = 0);

/// Largest nesting depth of a scene file's JSON, and largest scene file (bytes).
inline constexpr int kMaxSceneDepth = 64;
inline constexpr std::size_t kMaxSceneBytes = std::size_t(64) << 20;

/// Names used in scene files, for messages.
std::string_view to_string(ElasticModel);
std::string_view to_string(PlasticModel);
std::string_view to_string(TransferKind);
std::string_view to_string(KernelKind);
std::string_view to_string(SolverType);
std::string_view to_string(Integrator);
std::string_view to_string(ImplicitPreconditioner);
std::string_view to_string(AdvectionScheme);
std::string_view to_string(PressurePreconditioner);
std::string_view to_string(OnInstability);

}  // namespace slurry
