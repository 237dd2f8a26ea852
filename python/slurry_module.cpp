// The Python module `slurry` (pybind11): scenes from a file or a dict, simulations stepped from
// Python with their particles as NumPy arrays that read the solver's memory (no copy), whole runs
// with a Python callback per frame, the liquid's surface as NumPy arrays. docs/python.md
// describes every call with an example.
//
// Lifetimes: a particle array's memory belongs to the simulation; the array keeps the Python
// Simulation object alive, but its contents are valid only until the simulation takes its next
// substep (the solvers re-sort and reallocate their particles), so the arrays are read-only and
// the documentation says to copy what must outlive a step. Long calls (advance_to, run_scene)
// release the GIL; run_scene takes it back for the callback. Ctrl-C during a call from the main
// thread stops it between substeps and raises KeyboardInterrupt; a StopToken stops it from any
// thread (Blender's add-on runs scenes in a worker thread and cancels through one).
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "slurry/engine/errors.h"
#include "slurry/engine/run/run.h"
#include "slurry/engine/solver.h"
#include "slurry/io/scene_file.h"
#include "substep.h"
#ifdef SLURRY_PYTHON_WITH_OPENVDB
#include "slurry/io/pipeline.h"
#include "slurry/io/surface.h"
#endif

namespace py = pybind11;

namespace {

using slurry::Scene;
using slurry::Solver;

/// How a call was stopped: by SIGINT (Ctrl-C) or by a StopToken.
constexpr std::sig_atomic_t kStoppedBySigint = SIGINT;
constexpr std::sig_atomic_t kStoppedByToken = 1;

/// SIGINT while C++ runs without the GIL: the handler sets the flag of the call in progress
/// (polled between substeps, RunOptions::stop, and between advance_to's frames). Installed only
/// by calls from the main thread, where Python handles signals; the previous handler comes back
/// afterwards.
volatile std::sig_atomic_t* g_sigint_target = nullptr;
extern "C" void on_sigint(int) {
  if (g_sigint_target) *g_sigint_target = kStoppedBySigint;
}

bool on_main_thread() {
  const py::module_ threading = py::module_::import("threading");
  return threading.attr("current_thread")().is(threading.attr("main_thread")());
}

/// A request to stop a call (run_scene, advance_to) from another thread or a callback. While a
/// call runs, the token points at that call's stop flag; both are touched with the GIL held
/// (request() is called from Python; the call attaches and detaches before it releases and after
/// it takes back the GIL), so the pointer never dangles.
struct StopToken {
  bool requested = false;
  volatile std::sig_atomic_t* target = nullptr;
  void request() {
    requested = true;
    if (target) *target = kStoppedByToken;
  }
};

/// The stop flag of one call, set by SIGINT (main thread only) or by the call's StopToken.
class StopFlag {
 public:
  explicit StopFlag(StopToken* token) : token_(token) {
    if (token_) {
      token_->target = &flag_;
      if (token_->requested) flag_ = kStoppedByToken;
    }
    if (on_main_thread()) {
      sigint_ = true;
      g_sigint_target = &flag_;
      previous_ = std::signal(SIGINT, on_sigint);
    }
  }
  ~StopFlag() {
    if (sigint_) {
      std::signal(SIGINT, previous_);
      g_sigint_target = nullptr;
    }
    if (token_) token_->target = nullptr;
  }
  StopFlag(const StopFlag&) = delete;
  StopFlag& operator=(const StopFlag&) = delete;
  volatile std::sig_atomic_t* flag() { return &flag_; }
  bool stopped() const { return flag_ != 0; }
  /// Raises KeyboardInterrupt if SIGINT stopped the call.
  void raise_if_interrupted() const {
    if (flag_ == kStoppedBySigint) {
      PyErr_SetNone(PyExc_KeyboardInterrupt);
      throw py::error_already_set();
    }
  }

 private:
  volatile std::sig_atomic_t flag_ = 0;
  StopToken* token_;
  bool sigint_ = false;
  void (*previous_)(int) = SIG_DFL;
};

/// Progress of a long call, with the GIL held: `progress` is None (nothing), a callable
/// progress(done, total), or True (a tqdm bar if tqdm is installed, else one line on stderr
/// rewritten in place).
class Progress {
 public:
  Progress(const py::object& progress, double total, const char* unit) : total_(total), unit_(unit) {
    if (progress.is_none() || (py::isinstance<py::bool_>(progress) && !progress.cast<bool>())) return;
    if (py::isinstance<py::bool_>(progress)) {
      try {
        bar_ = py::module_::import("tqdm").attr("tqdm")(py::arg("total") = total, py::arg("unit") = unit);
      } catch (const py::error_already_set&) {
        text_ = true;  // no tqdm
      }
      return;
    }
    if (!PyCallable_Check(progress.ptr())) throw py::type_error("progress: expected None, True or a callable progress(done, total)");
    callback_ = progress;
  }
  ~Progress() {
    if (bar_) {
      try {
        bar_.attr("close")();
      } catch (const py::error_already_set&) {
      }
    }
    if (text_ && shown_) std::fputc('\n', stderr);
  }
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;
  void operator()(double done) {
    if (callback_) callback_(done, total_);
    if (bar_) bar_.attr("update")(done - done_);
    if (text_) {
      std::fprintf(stderr, "\r%g / %g %s", done, total_, unit_);
      std::fflush(stderr);
      shown_ = true;
    }
    done_ = done;
  }

 private:
  double total_, done_ = 0;
  const char* unit_;
  py::object callback_, bar_;
  bool text_ = false, shown_ = false;
};

/// A scene from a Python dict (the scene file's keys) or a JSON string, validated as a file is.
Scene scene_from(const py::object& spec, const std::string& source) {
  std::string text;
  if (py::isinstance<py::str>(spec)) {
    text = spec.cast<std::string>();
  } else if (py::isinstance<py::dict>(spec)) {
    text = py::module_::import("json").attr("dumps")(spec).cast<std::string>();
  } else {
    throw py::type_error("scene: expected a dict of the scene file's keys or a JSON string, got " +
                         std::string(py::str(py::type::of(spec).attr("__name__"))));
  }
  return slurry::parse_scene(text, source);
}

/// The Python face of a simulation: the solver and the scene it was built from.
struct Simulation {
  Scene scene;
  std::unique_ptr<Solver> solver;
};

/// A read-only NumPy array over `count` items of `shape` (after the first axis), elements of
/// `itemsize` bytes at `data`, kept alive by `owner`. Eigen's fixed-size vectors and matrices are
/// packed (a Vector3f is 12 bytes) and matrices column-major, so F[p, r, c] = F_p(r, c).
py::object view(const py::object& owner, const void* data, std::size_t count, std::vector<py::ssize_t> inner,
               bool column_major, const py::dtype& dtype) {
  if (!data) return py::none();
  const py::ssize_t item = dtype.itemsize();
  std::vector<py::ssize_t> shape{py::ssize_t(count)}, strides;
  py::ssize_t per = 1;
  for (py::ssize_t n : inner) per *= n;
  shape.insert(shape.end(), inner.begin(), inner.end());
  strides.push_back(per * item);
  if (inner.size() == 1) strides.push_back(item);
  if (inner.size() == 2) {
    if (column_major) strides.push_back(item), strides.push_back(inner[0] * item);
    else strides.push_back(inner[1] * item), strides.push_back(item);
  }
  py::array a(dtype, shape, strides, data, owner);
  py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

py::dtype real_dtype(const slurry::ParticleStorage& s) {
  return s.precision == slurry::Precision::Double ? py::dtype::of<double>() : py::dtype::of<float>();
}

/// A read-only property: the storage channel `member` of the simulation as a view (`rank` 0: one
/// value per particle, 1: a vector of the dimension, 2: a matrix), None where it is not stored.
template <class Member>
auto channel(Member member, int rank, py::dtype (*type)(const slurry::ParticleStorage&)) {
  return [member, rank, type](py::object self) -> py::object {
    const auto st = self.cast<Simulation&>().solver->particle_storage();
    const std::vector<py::ssize_t> inner(std::size_t(rank), py::ssize_t(st.dimension));
    return view(self, st.*member, st.count, inner, rank == 2, type(st));
  };
}

py::dtype material_dtype(const slurry::ParticleStorage&) { return py::dtype::of<std::uint16_t>(); }

/// The storage index of each particle in ascending id order: the permutation of the solver's
/// particle view (Solver::particles_view).
template <class T, int Dim>
std::vector<std::uint32_t> id_order(const Solver& solver) {
  const auto view = solver.particles_view<T, Dim>();
  std::vector<std::uint32_t> order(view.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = std::uint32_t(view.slot(i));
  return order;
}

py::dict stats_dict(const slurry::RunStats& s) {
  py::dict d;
  d["frame"] = s.frame;
  d["time"] = s.time;
  d["substeps"] = s.substeps;
  d["particles"] = s.particles;
  d["mass"] = s.mass;
  d["momentum"] = std::vector<double>{s.momentum[0], s.momentum[1], s.momentum[2]};
  d["angular_momentum"] = std::vector<double>{s.angular_momentum[0], s.angular_momentum[1], s.angular_momentum[2]};
  d["kinetic"] = s.kinetic;
  d["potential"] = s.potential;
  d["elastic"] = s.elastic;
  d["surface"] = s.surface;
  d["energy"] = s.energy();
  d["volume"] = s.volume;
  d["max_fluid_J_error"] = s.max_fluid_J_error;
  d["projected"] = s.projected;
  d["cfl"] = s.cfl;
  // output.error_estimate (run_scene's frames only): the run's estimate of its own error.
  if (!std::isnan(s.error_energy)) d["error_energy"] = s.error_energy;
  if (!std::isnan(s.error_centroid)) d["error_centroid"] = s.error_centroid;
  return d;
}

/// A frame's tables as dicts of NumPy arrays (copies: a frame's columns may borrow particle memory).
py::dict frame_dict(const slurry::Frame& f) {
  py::dict out;
  for (const slurry::Table& t : f.tables) {
    py::dict cols;
    std::vector<std::string> names;
    for (const auto& c : t.columns) names.push_back(c.name);
    for (const auto& r : t.refs) names.push_back(r.name);
    for (const auto& name : names) {
      const std::vector<double> v = t.column_as_double(name);
      cols[py::str(name)] = py::array_t<double>(py::ssize_t(v.size()), v.data());
    }
    out[py::str(t.name)] = cols;
  }
  return out;
}

#ifdef SLURRY_PYTHON_WITH_OPENVDB
/// The surface of the current particles, as output.surface would mesh this frame: the scene's
/// surfacing parameters (io::frame_outputs), its liquid's particles, io::surface_mesh.
py::dict surface_dict(const Simulation& s, std::optional<double> voxel_size, std::optional<std::string> method,
                      std::optional<int> smoothing) {
  namespace io = slurry::io;
  if (s.scene.solver.dimension != 3 || s.scene.solver.type == slurry::SolverType::FEM)
    throw slurry::SceneError(s.scene.source + ": surface: expected a 3D MPM or FLIP scene (" +
                             std::to_string(s.scene.solver.dimension) + "D " +
                             std::string(slurry::to_string(s.scene.solver.type)) + ")");
  io::FrameOutputs outputs = io::frame_outputs(s.scene);
  if (voxel_size) outputs.params.voxel_size = *voxel_size;
  if (smoothing) outputs.params.smoothing = *smoothing;
  if (method) {
    if (*method != "anisotropic" && *method != "spheres")
      throw py::value_error("surface: method: expected \"anisotropic\" or \"spheres\", got \"" + *method + "\"");
    outputs.params.method = *method == "spheres" ? io::SurfaceMethod::Spheres : io::SurfaceMethod::Anisotropic;
  }
  try {
    outputs.params.validate();
  } catch (const std::invalid_argument& e) {
    throw py::value_error(std::string("surface: ") + e.what());
  }
  // Every group's materials together (one surface), as the frame's material column selects them.
  std::vector<int> materials;
  for (const auto& g : outputs.groups) materials.insert(materials.end(), g.materials.begin(), g.materials.end());
  io::TriangleMesh mesh;
  {
    py::gil_scoped_release release;
    std::vector<std::string> attributes{"position", "velocity"};
    if (!materials.empty()) attributes.push_back("material");
    const slurry::Frame frame = s.solver->frame(attributes);
    io::PointCloud cloud;
    if (materials.empty()) {
      cloud = io::point_cloud(frame);
    } else {
      for (int m : materials) {
        io::PointCloud c = io::point_cloud(frame, m);
        cloud.position.insert(cloud.position.end(), c.position.begin(), c.position.end());
        cloud.velocity.insert(cloud.velocity.end(), c.velocity.begin(), c.velocity.end());
      }
    }
    if (cloud.size() > 0) mesh = io::surface_mesh(cloud, outputs.params).mesh;
  }
  const auto rows = [](const auto& v, auto zero) {
    using E = decltype(zero);
    py::array_t<E> a({py::ssize_t(v.size()), py::ssize_t(3)});
    if (!v.empty()) std::copy(&v[0][0], &v[0][0] + 3 * v.size(), a.mutable_data());
    return a;
  };
  py::dict d;
  d["vertices"] = rows(mesh.vertices, float());
  d["faces"] = rows(mesh.triangles, std::int32_t());
  d["velocities"] = mesh.velocities.empty() ? rows(std::vector<std::array<float, 3>>(mesh.vertices.size()), float())
                                            : rows(mesh.velocities, float());
  return d;
}
#endif

}  // namespace

PYBIND11_MODULE(slurry, m) {
  m.doc() = "Slurry: MPM, FLIP/APIC and co-rotated FEM simulation from Python (docs/python.md)";

  static py::exception<slurry::SceneError> scene_error(m, "SceneError", PyExc_ValueError);
  static py::exception<slurry::ResourceError> resource_error(m, "ResourceError", PyExc_MemoryError);
  static py::exception<slurry::IoError> io_error(m, "IoError", PyExc_OSError);
  static py::exception<slurry::SimulationError> simulation_error(m, "SimulationError", PyExc_RuntimeError);
  // Most derived first: ResourceError is an IoError in C++.
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const slurry::SceneError& e) {
      scene_error(e.what());
    } catch (const slurry::ResourceError& e) {
      resource_error(e.what());
    } catch (const slurry::IoError& e) {
      io_error(e.what());
    } catch (const slurry::SimulationError& e) {
      simulation_error(e.what());
    }
  });

  py::class_<Scene>(m, "Scene", "A validated scene (the scene file's keys, docs/scene-reference.md).")
      .def_property_readonly("source", [](const Scene& s) { return s.source; })
      .def_property_readonly("dimension", [](const Scene& s) { return s.solver.dimension; })
      .def_property_readonly("frames", [](const Scene& s) { return s.output.frames; })
      .def_property_readonly("fps", [](const Scene& s) { return s.output.fps; })
      .def_property_readonly("frame_dt", &Scene::frame_dt)
      .def_property_readonly("solver_type", [](const Scene& s) { return std::string(slurry::to_string(s.solver.type)); },
                             "\"mpm\", \"flip\" or \"fem\".")
      .def_property_readonly("directory", [](const Scene& s) { return s.output.directory; },
                             "output.directory (relative to the working directory).")
      .def_property_readonly("up_axis", [](const Scene& s) { return s.output.up_axis; },
                             "output.up_axis: \"y\" (files in the simulation's axes) or \"z\".")
      .def_property_readonly("surface", [](const Scene& s) { return s.output.surface; },
                             "output.surface: the surface formats written per frame.")
      .def("__repr__", [](const Scene& s) {
        return "<slurry.Scene " + s.source + ": " + std::to_string(s.solver.dimension) + "D, " +
               std::to_string(s.output.frames) + " frames at " + std::to_string(s.output.fps) + " fps>";
      });

  m.def("load_scene", &slurry::load_scene, py::arg("path"),
        "Reads, parses and validates a scene file. Raises SceneError naming the JSON path, or IoError.");
  m.def("parse_scene", &scene_from, py::arg("scene"), py::arg("source") = "<python>",
        "A scene from a dict of the scene file's keys (or a JSON string), validated as a file is; "
        "errors name `source` and the JSON path.");

  py::class_<Simulation>(m, "Simulation", "A simulation built from a scene (make_simulation).")
      .def_property_readonly("time", [](const Simulation& s) { return s.solver->time(); }, "Simulated time (s).")
      .def_property_readonly("steps", [](const Simulation& s) { return s.solver->steps(); }, "Substeps taken.")
      .def_property_readonly("particle_count", [](const Simulation& s) { return s.solver->particle_count(); })
      .def_property_readonly("scene", [](const Simulation& s) { return s.scene; })
      .def(
          "advance_to",
          [](Simulation& s, double t, const py::object& progress, StopToken* stop) {
            StopFlag flag(stop);
            const double t0 = s.solver->time();
            Progress shown(progress, std::max(0.0, t - t0), "s");
            std::int64_t steps = 0;
            // In pieces of one frame, so that Ctrl-C or a StopToken stops within a frame's
            // worth of substeps and progress is shown once a frame. Each piece ends at a later
            // time than the last, so the loop ends at t.
            const double piece = s.scene.frame_dt();
            for (double next = s.solver->time(); next < t && !flag.stopped();) {
              next = std::min(t, std::max(next, s.solver->time()) + piece);
              {
                py::gil_scoped_release release;
                steps += s.solver->advance_to(next);
              }
              shown(s.solver->time() - t0);
            }
            flag.raise_if_interrupted();
            return steps;
          },
          py::arg("t"), py::arg("progress") = py::none(), py::arg("stop") = nullptr,
          "Steps the simulation to time t (s); returns the substeps taken. Releases the GIL. progress: "
          "None, True (a tqdm bar if installed) or progress(done_seconds, total_seconds), called once a frame; "
          "stop: a StopToken that ends the call early (at a frame's end), from another thread.")
      .def(
          "step",
          [](Simulation& s, std::optional<double> dt) {
            const double length = dt ? *dt : s.solver->dt_scale() * slurry::python::stable_dt(*s.solver);
            if (!(length > 0) || !std::isfinite(length))
              throw py::value_error("step: expected a substep length > 0, got " + std::to_string(length));
            py::gil_scoped_release release;
            // advance_to an end at most one stable substep away takes exactly one substep that
            // lands on it (substeps.h), with the solver's own checks.
            s.solver->advance_to(s.solver->time() + length);
            return s.solver->time();
          },
          py::arg("dt") = py::none(),
          "Takes one substep: of the solver's stable length (times its dt scale), or of `dt` seconds if "
          "given (more than one substep if dt exceeds the stable length). Returns the new time (s).")
      .def_property_readonly(
          "stable_dt", [](const Simulation& s) { return slurry::python::stable_dt(*s.solver); },
          "The length (s) of the next substep the solver would take now (its CFL and elastic limits).")
#ifdef SLURRY_PYTHON_WITH_OPENVDB
      .def("surface", &surface_dict, py::arg("voxel_size") = py::none(), py::arg("method") = py::none(),
           py::arg("smoothing") = py::none(),
           "The liquid's surface of the current particles, as output.surface meshes it (slurry::io::surface_mesh): "
           "{'vertices': (n, 3) float32, 'faces': (m, 3) int32, 'velocities': (n, 3) float32}, in the simulation's "
           "axes. voxel_size (m), method ('anisotropic' or 'spheres') and smoothing override the scene's output keys.")
#endif
      .def(
          "stats", [](Simulation& s) { return stats_dict(s.solver->take_stats()); },
          "The scene-level figures now (mass, momentum, energies, volume, CFL): a dict.")
      .def(
          "frame",
          [](const Simulation& s, const std::vector<std::string>& attributes) {
            return frame_dict(s.solver->frame(attributes));
          },
          py::arg("attributes") = std::vector<std::string>{"position", "velocity", "id"},
          "The frame a run would write, as {table: {column: array}} (copies).")
      .def_property_readonly("positions", channel(&slurry::ParticleStorage::x, 1, real_dtype),
                             "Positions (n, dim), storage order, read-only, no copy: valid until the next substep.")
      .def_property_readonly("velocities", channel(&slurry::ParticleStorage::v, 1, real_dtype),
                             "Velocities (n, dim), storage order, read-only, no copy.")
      .def_property_readonly(
          "ids",
          [](py::object self) -> py::object {
            const auto st = self.cast<Simulation&>().solver->particle_storage();
            if (!st.id) {  // the storage index is the id
              py::array_t<std::uint32_t> a(py::ssize_t(st.count));
              for (std::size_t i = 0; i < st.count; ++i) a.mutable_at(py::ssize_t(i)) = std::uint32_t(i);
              return std::move(a);
            }
            return view(self, st.id, st.count, {}, false, py::dtype::of<std::uint32_t>());
          },
          "Persistent ids (n,), storage order (no copy when the solver stores ids).")
      .def_property_readonly("materials", channel(&slurry::ParticleStorage::material, 0, material_dtype),
                             "Material index per particle (n,), or None when every particle is material 0.")
      .def_property_readonly("F", channel(&slurry::ParticleStorage::F, 2, real_dtype),
                             "Elastic deformation gradients (n, dim, dim) of MPM solids, or None.")
      .def_property_readonly("J", channel(&slurry::ParticleStorage::J, 0, real_dtype),
                             "Volume ratio (n,) of MPM fluids, or None.")
      .def_property_readonly("plastic", channel(&slurry::ParticleStorage::plastic, 0, real_dtype),
                             "Plastic state (n,) of MPM plastic materials, or None.")
      .def(
          "id_order",
          [](const Simulation& s) {
            const auto st = s.solver->particle_storage();
            const bool dbl = st.precision == slurry::Precision::Double;
            const std::vector<std::uint32_t> order =
                st.dimension == 2 ? (dbl ? id_order<double, 2>(*s.solver) : id_order<float, 2>(*s.solver))
                                  : (dbl ? id_order<double, 3>(*s.solver) : id_order<float, 3>(*s.solver));
            return py::array_t<std::uint32_t>(py::ssize_t(order.size()), order.data());
          },
          "The storage indices in ascending id order: positions[sim.id_order()] is in id order (a copy).");

  m.def(
      "make_simulation",
      [](const Scene& scene) {
        Simulation s{scene, nullptr};
        {
          py::gil_scoped_release release;
          s.solver = slurry::make_simulation(scene);
        }
        return s;
      },
      py::arg("scene"), "Builds the solver the scene asks for (reading its mesh files).");

#ifdef SLURRY_PYTHON_WITH_OPENVDB
  m.def("release_surfacing_memory", &slurry::io::release_surfacing_memory,
        "Returns to the system the buffers that surfacing (Simulation.surface) keeps for its next call, "
        "and the bytes released: for a session that surfaces no more frames. run_scene returns them itself "
        "when it ends.");
#endif

  py::class_<StopToken>(m, "StopToken",
                        "Stops a run_scene or advance_to call from another thread or a callback: the call ends "
                        "after the frame it is computing (run_scene: written, with a checkpoint for resume).")
      .def(py::init<>())
      .def("request", &StopToken::request, "Asks the call that holds this token to stop (thread-safe).")
      .def_property_readonly("requested", [](const StopToken& t) { return t.requested; });

  m.def(
      "run_scene",
      [](const Scene& scene, std::optional<std::string> directory, std::optional<int> frames, int threads,
         bool write_files, std::function<void(py::dict)> on_frame, bool resume, bool force, bool overwrite,
         const py::object& progress, StopToken* stop) {
        slurry::RunOptions o;
        if (directory) o.directory = *directory;
        o.frames = frames;
        o.threads = threads;
        o.write_files = write_files;
        o.resume = resume;
        o.force = force;
        o.overwrite = overwrite;
        std::vector<std::string> notices;
        o.notice = [&notices](const std::string& line) { notices.push_back(line); };
        const bool pipeline = write_files && (!scene.output.surface.empty() || scene.output.vdb_points);
#ifdef SLURRY_PYTHON_WITH_OPENVDB
        const slurry::io::FrameOutputs outputs = slurry::io::frame_outputs(scene);
        // The surfacer keeps its buffers from frame to frame; the run returns them when it ends,
        // however it ends, so that the Python process does not hold them after the bake.
        struct ReleaseSurfacing {
          ~ReleaseSurfacing() { slurry::io::release_surfacing_memory(); }
        } release_surfacing;
#else
        if (pipeline)
          throw slurry::SceneError(scene.source + ": " + (scene.output.vdb_points ? "output.vdb_points" : "output.surface") +
                                   ": this module was built without OpenVDB; expected no pipeline outputs");
#endif
        StopFlag flag(stop);
        o.stop = flag.flag();
        Progress shown(progress, double(frames ? *frames : scene.output.frames), "frame");
        std::exception_ptr callback_error;
        slurry::RunSummary summary;
        {
          py::gil_scoped_release release;
          summary = slurry::run_scene(scene, o, [&](const slurry::FrameReport& r) {
            std::vector<std::string> files;
#ifdef SLURRY_PYTHON_WITH_OPENVDB
            // The surfaces, level sets and VDB points the scene asks for, as `slurry run` writes
            // them beside each frame (the colliders come from run_scene itself).
            if (pipeline && r.frame_data) {
              slurry::io::with_threads(threads, [&] {
                for (const auto& f : slurry::io::write_frame_outputs(*r.frame_data, r.frame, r.file.parent_path(), outputs).files)
                  files.push_back(f.string());
              });
            }
#endif
            if (callback_error) return;
            py::gil_scoped_acquire acquire;
            try {
              shown(double(r.frame));
              if (!on_frame) return;
              py::dict d;
              d["frame"] = r.frame;
              d["frames"] = r.frames;
              d["substeps"] = r.substeps;
              d["seconds"] = r.seconds;
              d["particles"] = r.particles;
              d["file"] = r.file.string();
              d["pipeline_files"] = files;
              d["stats"] = stats_dict(r.stats);
              d["warnings"] = r.warnings;
              on_frame(d);
            } catch (...) {
              callback_error = std::current_exception();
              *flag.flag() = kStoppedByToken;  // stop the run after this frame
            }
          });
        }
        if (callback_error) std::rethrow_exception(callback_error);
        flag.raise_if_interrupted();
        py::dict d;
        d["frames_written"] = summary.frames_written;
        d["directory"] = summary.directory.string();
        d["particles"] = summary.particles;
        d["wall_seconds"] = summary.wall_seconds;
        d["drift_warnings"] = summary.drift_warnings;
        d["resumed_from"] = summary.resumed_from;
        d["checkpoints_written"] = summary.checkpoints_written;
        d["stopped"] = summary.interrupted != 0;
        d["notices"] = notices;
        d["first"] = stats_dict(summary.first);
        d["last"] = stats_dict(summary.last);
        return d;
      },
      py::arg("scene"), py::arg("directory") = py::none(), py::arg("frames") = py::none(), py::arg("threads") = 0,
      py::arg("write_files") = true, py::arg("on_frame") = nullptr, py::arg("resume") = false,
      py::arg("force") = false, py::arg("overwrite") = false, py::arg("progress") = py::none(),
      py::arg("stop") = nullptr,
      "Runs the scene as `slurry run` does (frames, stats.csv, checkpoints, colliders, and the surfaces and VDB "
      "points the scene asks for), calling on_frame(dict) after every frame. resume: continue from the newest "
      "checkpoint in the directory (force: one written for another version of the scene); overwrite: remove "
      "another scene's frames; progress: None, True (tqdm if installed) or progress(frame, frames); stop: a "
      "StopToken (the run ends after the frame it is computing and returns with 'stopped' True). Releases the GIL; "
      "Ctrl-C (main thread) stops after the current substep loop and raises KeyboardInterrupt.");
}
