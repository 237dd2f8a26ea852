// The Python module `slurry` (pybind11): scenes from a file or a dict, simulations stepped from
// Python with their particles as NumPy arrays that read the solver's memory (no copy), whole runs
// with a Python callback per frame. docs/python.md describes every call with an example.
//
// Lifetimes: a particle array's memory belongs to the simulation; the array keeps the Python
// Simulation object alive, but its contents are valid only until the simulation takes its next
// substep (the solvers re-sort and reallocate their particles), so the arrays are read-only and
// the documentation says to copy what must outlive a step. Long calls (advance_to, run_scene)
// release the GIL; run_scene takes it back for the callback. Ctrl-C during a call stops it
// between substeps and raises KeyboardInterrupt.
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <algorithm>
#include <csignal>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "slurry/engine/errors.h"
#include "slurry/engine/run/run.h"
#include "slurry/engine/solver.h"
#include "slurry/io/scene_file.h"

namespace py = pybind11;

namespace {

using slurry::Scene;
using slurry::Solver;

/// SIGINT while C++ runs without the GIL: the flag is polled between substeps (RunOptions::stop)
/// and between advance_to's frames; the previous handler comes back afterwards.
volatile std::sig_atomic_t g_interrupted = 0;
extern "C" void on_sigint(int) { g_interrupted = 1; }

class SigintGuard {
 public:
  SigintGuard() {
    g_interrupted = 0;
    previous_ = std::signal(SIGINT, on_sigint);
  }
  ~SigintGuard() { std::signal(SIGINT, previous_); }
  SigintGuard(const SigintGuard&) = delete;
  SigintGuard& operator=(const SigintGuard&) = delete;

 private:
  void (*previous_)(int) = SIG_DFL;
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
  d["energy"] = s.energy();
  d["volume"] = s.volume;
  d["max_fluid_J_error"] = s.max_fluid_J_error;
  d["projected"] = s.projected;
  d["cfl"] = s.cfl;
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
          [](Simulation& s, double t) {
            SigintGuard guard;
            std::int64_t steps = 0;
            {
              py::gil_scoped_release release;
              // In pieces of one frame, so that Ctrl-C stops within a frame's worth of substeps.
              // Each piece ends at a later time than the last, so the loop ends at t.
              const double piece = s.scene.frame_dt();
              for (double next = s.solver->time(); next < t && !g_interrupted;) {
                next = std::min(t, std::max(next, s.solver->time()) + piece);
                steps += s.solver->advance_to(next);
              }
            }
            if (g_interrupted) {
              PyErr_SetNone(PyExc_KeyboardInterrupt);
              throw py::error_already_set();
            }
            return steps;
          },
          py::arg("t"), "Steps the simulation to time t (s); returns the substeps taken. Releases the GIL.")
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

  m.def(
      "run_scene",
      [](const Scene& scene, std::optional<std::string> directory, std::optional<int> frames, int threads,
         bool write_files, std::function<void(py::dict)> on_frame) {
        slurry::RunOptions o;
        if (directory) o.directory = *directory;
        o.frames = frames;
        o.threads = threads;
        o.write_files = write_files;
        SigintGuard guard;
        o.stop = &g_interrupted;
        std::exception_ptr callback_error;
        slurry::RunSummary summary;
        {
          py::gil_scoped_release release;
          summary = slurry::run_scene(scene, o, [&](const slurry::FrameReport& r) {
            if (!on_frame || callback_error) return;
            py::gil_scoped_acquire acquire;
            try {
              py::dict d;
              d["frame"] = r.frame;
              d["frames"] = r.frames;
              d["substeps"] = r.substeps;
              d["seconds"] = r.seconds;
              d["particles"] = r.particles;
              d["file"] = r.file.string();
              d["stats"] = stats_dict(r.stats);
              d["warnings"] = r.warnings;
              on_frame(d);
            } catch (...) {
              callback_error = std::current_exception();
              g_interrupted = 1;  // stop the run after this frame
            }
          });
        }
        if (callback_error) std::rethrow_exception(callback_error);
        if (summary.interrupted) {
          PyErr_SetNone(PyExc_KeyboardInterrupt);
          throw py::error_already_set();
        }
        py::dict d;
        d["frames_written"] = summary.frames_written;
        d["directory"] = summary.directory.string();
        d["particles"] = summary.particles;
        d["wall_seconds"] = summary.wall_seconds;
        d["drift_warnings"] = summary.drift_warnings;
        d["first"] = stats_dict(summary.first);
        d["last"] = stats_dict(summary.last);
        return d;
      },
      py::arg("scene"), py::arg("directory") = py::none(), py::arg("frames") = py::none(), py::arg("threads") = 0,
      py::arg("write_files") = true, py::arg("on_frame") = nullptr,
      "Runs the scene as `slurry run` does (frames, stats.csv, checkpoints), calling on_frame(dict) after every "
      "frame. Releases the GIL; Ctrl-C stops after the current substep loop and raises KeyboardInterrupt.");
}
