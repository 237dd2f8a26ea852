// Scene files: JSON -> Scene structs, with every key type-checked; Scene::validate() then checks
// ranges and cross references. Reading the mesh files a scene names.
#include "slurry/io/scene_file.h"

#include <cmath>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <utility>

#include "fnv1a.h"
#include "slurry/engine/scene/names.h"
#include "slurry/engine/scene/quality.h"
#include "slurry/engine/scene/scene_files.h"
#include "slurry/io/tetgen.h"
#include "slurry/io/triangle_mesh_file.h"

namespace slurry {
namespace {

using json = nlohmann::json;
using namespace scene_names;

std::string int_str(long double x) {
  std::ostringstream o;
  o.precision(20);
  o << x;
  return o.str();
}

std::string dump_short(const json& j) {
  std::string s = j.dump();
  return s.size() > 60 ? s.substr(0, 57) + "..." : s;
}

[[noreturn]] void fail(const std::string& source, const std::string& path, const std::string& what) {
  throw SceneError(source + ": " + path + ": " + what);
}

/// Reads one JSON object, remembering which keys were used so that unknown ones are reported.
class ObjectReader {
 public:
  ObjectReader(const json& j, std::string path, const std::string& source, int dim)
      : j_(j), path_(std::move(path)), source_(source), dim_(dim) {
    if (!j_.is_object()) fail(source_, path_.empty() ? "(top level)" : path_, "expected an object, got " + dump_short(j_));
  }

  std::string at(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }
  bool has(const std::string& key) const { return j_.contains(key); }
  const json* raw(const std::string& key) {
    seen_.insert(key);
    auto it = j_.find(key);
    return it == j_.end() ? nullptr : &*it;
  }

  void number(const std::string& key, double& out) {
    if (const json* v = raw(key)) {
      if (!v->is_number()) fail(source_, at(key), "expected a number, got " + dump_short(*v));
      out = v->get<double>();
      if (!std::isfinite(out)) fail(source_, at(key), "expected a finite number");
    }
  }
  /// An integer in [lo, hi] (by default the range of I): JSON integers are 64-bit, and one that
  /// does not fit is an error rather than wrapping.
  template <class I>
  void integer(const std::string& key, I& out, I lo = std::numeric_limits<I>::min(), I hi = std::numeric_limits<I>::max()) {
    if (const json* v = raw(key)) out = static_cast<I>(integer_in(source_, at(key), *v, lo, hi));
  }
  /// `v` as an integer in [lo, hi]; long double holds every 64-bit integer exactly.
  static long double integer_in(const std::string& source, const std::string& path, const json& v, long double lo,
                                long double hi) {
    if (!v.is_number_integer()) fail(source, path, "expected an integer, got " + dump_short(v));
    const long double x = v.is_number_unsigned() ? static_cast<long double>(v.get<std::uint64_t>())
                                                 : static_cast<long double>(v.get<std::int64_t>());
    if (x < lo || x > hi)
      fail(source, path, "expected an integer in [" + int_str(lo) + ", " + int_str(hi) + "], got " + dump_short(v));
    return x;
  }
  void boolean(const std::string& key, bool& out) {
    if (const json* v = raw(key)) {
      if (!v->is_boolean()) fail(source_, at(key), "expected true or false, got " + dump_short(*v));
      out = v->get<bool>();
    }
  }
  void string(const std::string& key, std::string& out) {
    if (const json* v = raw(key)) {
      if (!v->is_string()) fail(source_, at(key), "expected a string, got " + dump_short(*v));
      out = v->get<std::string>();
    }
  }
  template <class E>
  void choice(const std::string& key, const NameTable<E>& table, E& out) {
    if (const json* v = raw(key)) {
      if (v->is_string())
        for (const auto& [name, value] : table)
          if (name == v->get<std::string>()) {
            out = value;
            return;
          }
      fail(source_, at(key), "expected one of " + choices(table) + ", got " + dump_short(*v));
    }
  }
  void vector(const std::string& key, Eigen::Vector3d& out) {
    if (const json* v = raw(key)) {
      if (!v->is_array() || int(v->size()) != dim_)
        fail(source_, at(key),
             "expected an array of " + std::to_string(dim_) + " numbers (the scene's dimension), got " +
                 dump_short(*v));
      for (int d = 0; d < dim_; ++d) {
        if (!(*v)[d].is_number())
          fail(source_, at(key) + "[" + std::to_string(d) + "]", "expected a number, got " + dump_short((*v)[d]));
        out[d] = (*v)[d].get<double>();
      }
      if (dim_ == 2) out[2] = 0;
    }
  }
  void strings(const std::string& key, std::vector<std::string>& out) {
    if (const json* v = raw(key)) {
      if (!v->is_array()) fail(source_, at(key), "expected an array of strings, got " + dump_short(*v));
      out.clear();
      for (std::size_t i = 0; i < v->size(); ++i) {
        if (!(*v)[i].is_string())
          fail(source_, at(key) + "[" + std::to_string(i) + "]", "expected a string, got " + dump_short((*v)[i]));
        out.push_back((*v)[i].get<std::string>());
      }
    }
  }
  /// Calls fn(reader) for each element of an optional array of objects.
  template <class Fn>
  void objects(const std::string& key, Fn&& fn) {
    if (const json* v = raw(key)) {
      if (!v->is_array()) fail(source_, at(key), "expected an array of objects, got " + dump_short(*v));
      for (std::size_t i = 0; i < v->size(); ++i) {
        ObjectReader r((*v)[i], at(key) + "[" + std::to_string(i) + "]", source_, dim_);
        fn(r, i);
        r.finish();
      }
    }
  }
  template <class Fn>
  void object(const std::string& key, Fn&& fn) {
    if (const json* v = raw(key)) {
      ObjectReader r(*v, at(key), source_, dim_);
      fn(r);
      r.finish();
    }
  }
  /// Rejects keys that were never asked for.
  void finish() const {
    for (auto it = j_.begin(); it != j_.end(); ++it)
      if (!seen_.count(it.key())) {
        std::string known;
        for (const auto& k : seen_) known += (known.empty() ? "" : ", ") + k;
        fail(source_, at(it.key()), "unknown key (expected one of: " + known + ")");
      }
  }

 private:
  const json& j_;
  std::string path_;
  const std::string& source_;
  int dim_;
  std::set<std::string> seen_;
};

/// Builds the JSON value of a scene file through nlohmann's SAX interface, checking the limits
/// a scene file needs while parsing (before a deep or huge value is built): nesting at most
/// kMaxSceneDepth, no duplicate keys in an object, numbers in the range of double. Each error
/// names the JSON path where it happened. (nlohmann's own callback parser scans the enclosing
/// array at the end of every object, which made a file of 1e6 collider keyframes take minutes.)
class SceneJsonBuilder {
 public:
  SceneJsonBuilder(json& root, const std::string& source) : root_(root), source_(source) {}

  bool null() { return value(nullptr); }
  bool boolean(bool v) { return value(v); }
  bool number_integer(json::number_integer_t v) { return value(v); }
  bool number_unsigned(json::number_unsigned_t v) { return value(v); }
  bool number_float(json::number_float_t v, const json::string_t&) { return value(v); }
  bool string(json::string_t& v) { return value(std::move(v)); }
  bool binary(json::binary_t& v) { return value(json::binary(std::move(v))); }
  bool start_object(std::size_t) { return start(json::object(), false); }
  bool start_array(std::size_t) { return start(json::array(), true); }
  bool key(json::string_t& k) {
    Level& l = stack_.back();
    l.key = k;
    if (!l.keys.insert(l.key).second) fail(source_, path(), "duplicate key (expected each key once in an object)");
    return true;
  }
  bool end_object() { return end(); }
  bool end_array() { return end(); }
  bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception& e) {
    if (e.id == 406) {  // the parser's only out_of_range: a number beyond the range of double
      const std::string what = e.what();
      const auto q = what.find('\'');
      const std::string number = q == std::string::npos ? what : what.substr(q);
      fail(source_, path(), "number " + number +
                                " is out of the range of double (expected a finite number, |x| < 1.8e308)");
    }
    throw SceneError(source_ + ": not valid JSON: " + e.what());
  }

 private:
  struct Level {
    json* value = nullptr;
    bool array = false;
    std::string key;        // the current key of an object
    std::size_t index = 0;  // the current element of an array
    std::set<std::string> keys;
  };

  std::string path() const {
    std::string p;
    for (const Level& l : stack_) {
      if (l.array)
        p += "[" + std::to_string(l.index) + "]";
      else if (!l.key.empty())
        p += (p.empty() ? "" : ".") + l.key;
      if (p.size() > 80) return p.substr(0, 77) + "...";
    }
    return p.empty() ? std::string("(top level)") : p;
  }
  /// Places v in the current array or object (or at the top) and returns where it went.
  json* place(json&& v) {
    if (stack_.empty()) {
      root_ = std::move(v);
      return &root_;
    }
    Level& l = stack_.back();
    if (l.array) {
      l.value->push_back(std::move(v));
      return &l.value->back();
    }
    json& slot = (*l.value)[l.key];
    slot = std::move(v);
    return &slot;
  }
  /// A scalar value; the next element of an enclosing array follows it.
  bool value(json&& v) {
    place(std::move(v));
    if (!stack_.empty() && stack_.back().array) ++stack_.back().index;
    return true;
  }
  bool start(json&& empty, bool array) {
    if (int(stack_.size()) >= kMaxSceneDepth)
      fail(source_, path(), "nested deeper than " + std::to_string(kMaxSceneDepth) +
                                " levels (expected a scene: objects and arrays a few levels deep)");
    json* v = place(std::move(empty));
    stack_.push_back({v, array, {}, 0, {}});
    return true;
  }
  bool end() {
    stack_.pop_back();
    if (!stack_.empty() && stack_.back().array) ++stack_.back().index;
    return true;
  }

  json& root_;
  const std::string& source_;
  std::vector<Level> stack_;
};

json parse_json(std::string_view text, const std::string& source) {
  json root;
  SceneJsonBuilder builder(root, source);
  json::sax_parse(text.begin(), text.end(), &builder);
  return root;
}

}  // namespace

Scene parse_scene(std::string_view text, const std::string& source) {
  const json j = parse_json(text, source);
  Scene s;
  s.source = source;
  s.source_hash = detail::fnv1a64(text);
  // The dimension decides the length of every vector, so it is read first.
  if (j.is_object() && j.contains("solver") && j["solver"].is_object() && j["solver"].contains("dimension")) {
    const json& d = j["solver"]["dimension"];
    if (!d.is_number_integer() || (d != 2 && d != 3)) fail(source, "solver.dimension", "expected 2 or 3, got " + dump_short(d));
    s.solver.dimension = d.get<int>();
  }
  const int dim = s.solver.dimension;
  if (dim == 2) s.solver.gravity = {0, -9.81, 0};

  ObjectReader top(j, "", source, dim);
  top.object("domain", [&](ObjectReader& r) {
    r.vector("min", s.domain.min);
    r.vector("max", s.domain.max);
    r.number("dx", s.domain.dx);
    r.choice("grid", kGrid, s.domain.grid);
  });
  double quality_ppc = 0;  // particles_per_cell of a solver.quality preset, 0 without one
  top.object("solver", [&](ObjectReader& r) {
    r.choice("type", kSolverType, s.solver.type);
    r.integer("dimension", s.solver.dimension);
    // A preset sets its knobs first (quality.h); the keys read below override them.
    std::string quality;
    r.string("quality", quality);
    quality_ppc = r.has("quality") ? apply_quality(s, quality) : apply_default_quality(s);
    r.choice("precision", kPrecision, s.solver.precision);
    r.choice("transfer", kTransfer, s.solver.transfer);
    r.choice("kernel", kKernel, s.solver.kernel);
    r.number("flip_ratio", s.solver.flip_ratio);
    r.number("cfl", s.solver.cfl);
    r.number("elastic_cfl", s.solver.elastic_cfl);
    r.vector("gravity", s.solver.gravity);
    r.number("max_dt", s.solver.max_dt);
    r.choice("integrator", kIntegrator, s.solver.integrator);
    if (s.solver.type == SolverType::FLIP) {  // keys of the FLIP solver only
      r.choice("advection", kAdvection, s.solver.advection);
      r.choice("free_surface", kFreeSurface, s.solver.free_surface);
      r.number("volume_correction", s.solver.volume_correction);
      r.object("pressure", [&](ObjectReader& q) {
        q.choice("preconditioner", kPreconditioner, s.solver.pressure.preconditioner);
        q.number("tolerance", s.solver.pressure.tolerance);
        q.integer("max_iterations", s.solver.pressure.max_iterations);
      });
      r.object("reseed", [&](ObjectReader& q) {
        q.integer("min_per_cell", s.solver.reseed.min_per_cell);
        q.integer("max_per_cell", s.solver.reseed.max_per_cell);
      });
      r.object("whitewater", [&](ObjectReader& q) {  // ranges checked by validate_flip
        auto& w = s.solver.whitewater;
        q.boolean("enabled", w.enabled);
        q.integer("seed", w.seed);
        q.number("trapped_air_rate", w.trapped_air_rate);
        q.number("wave_crest_rate", w.wave_crest_rate);
        q.number("trapped_air_min", w.trapped_air_min);
        q.number("trapped_air_max", w.trapped_air_max);
        q.number("wave_crest_min", w.wave_crest_min);
        q.number("wave_crest_max", w.wave_crest_max);
        q.number("kinetic_energy_min", w.kinetic_energy_min);
        q.number("kinetic_energy_max", w.kinetic_energy_max);
        q.number("lifetime_min", w.lifetime_min);
        q.number("lifetime_max", w.lifetime_max);
        q.number("spray_drag", w.spray_drag);
        q.number("bubble_buoyancy", w.bubble_buoyancy);
        q.number("bubble_drag", w.bubble_drag);
        q.number("spray_distance", w.spray_distance);
        q.number("bubble_depth", w.bubble_depth);
        q.integer("max_particles", w.max_particles);
      });
    }
    r.number("cg_tolerance", s.solver.cg_tolerance);
    r.integer("cg_max_iterations", s.solver.cg_max_iterations);
    r.choice("implicit_preconditioner", kImplicitPreconditioner, s.solver.implicit_preconditioner);
    r.choice("on_instability", kOnInstability, s.solver.on_instability);
    r.integer("max_retries", s.solver.max_retries, 1, 30);
    if (s.solver.type == SolverType::MPM)
      r.object("sleep", [&](ObjectReader& q) {
        q.number("speed", s.solver.sleep.speed);
        q.number("strain_rate", s.solver.sleep.strain_rate);
        q.integer("substeps", s.solver.sleep.substeps, 1, 65535);
        q.number("wake_speed", s.solver.sleep.wake_speed);
      });
  });
  if (!top.has("materials")) fail(source, "materials", "missing (expected an array of materials)");
  top.objects("materials", [&](ObjectReader& r, std::size_t) {
    MaterialParams m;
    r.string("name", m.name);
    r.choice("model", kElastic, m.model);
    r.number("density", m.density);
    r.choice("plasticity", kPlastic, m.plasticity);
    // Keys that belong to another model are errors, not silently ignored. The FLIP liquid is
    // incompressible: density, viscosity and surface tension are its parameters.
    if (s.solver.type == SolverType::FLIP) {
      r.number("viscosity", m.viscosity);
      r.number("surface_tension", m.surface_tension);
    } else if (m.model == ElasticModel::Fluid) {
      r.number("bulk_modulus", m.bulk_modulus);
      r.number("gamma", m.gamma);
    } else {
      r.number("E", m.E);
      r.number("nu", m.nu);
    }
    if (s.solver.type == SolverType::FEM) r.number("damping", m.damping);
    if (m.plasticity == PlasticModel::Snow) {
      r.number("critical_compression", m.critical_compression);
      r.number("critical_stretch", m.critical_stretch);
      r.number("hardening", m.hardening);
    } else if (m.plasticity == PlasticModel::DruckerPrager) {
      r.number("friction_angle", m.friction_angle);
    } else if (m.plasticity == PlasticModel::VonMises) {
      r.number("yield_stress", m.yield_stress);
    }
    s.materials.push_back(m);
  });
  if (!top.has("bodies") && !(s.solver.type == SolverType::FLIP && top.has("emitters")))
    fail(source, "bodies", "missing (expected an array of bodies)");
  top.objects("bodies", [&](ObjectReader& r, std::size_t) {
    BodyParams b;
    if (quality_ppc > 0) b.particles_per_cell = quality_ppc;
    r.choice("shape", kShape, b.shape);
    if (b.shape == Shape::Mesh) {
      r.vector("scale", b.scale);
      r.vector("rotation", b.rotation);
      r.vector("translation", b.translation);
    } else if (b.shape == Shape::Box) {
      if ((!r.has("min") || !r.has("max")) && !r.has("mesh")) fail(source, r.at("min"), "a box needs \"min\" and \"max\"");
      r.vector("min", b.min);
      r.vector("max", b.max);
    } else {
      if (!r.has("center") || !r.has("radius")) fail(source, r.at("radius"), "a sphere or cylinder needs \"center\" and \"radius\"");
      r.vector("center", b.center);
      r.number("radius", b.radius);
      if (b.shape == Shape::Cylinder) {
        r.number("height", b.height);
        r.integer("axis", b.axis);
      }
    }
    if (!r.has("material")) fail(source, r.at("material"), "missing (expected the name of a material)");
    r.string("material", b.material);
    r.vector("velocity", b.velocity);
    r.number("particles_per_cell", b.particles_per_cell);
    r.choice("sampling", kSampling, b.sampling);
    r.integer("seed", b.seed);
    r.string("mesh", b.mesh);
    s.bodies.push_back(b);
  });
  top.object("boundaries", [&](ObjectReader& r) {
    r.choice("walls", kCondition, s.boundaries.walls);
    r.number("friction", s.boundaries.friction);
    r.integer("thickness", s.boundaries.thickness);
  });
  top.objects("colliders", [&](ObjectReader& r, std::size_t) {
    ColliderParams k;
    r.choice("shape", kColliderShape, k.shape);
    if (k.shape == ColliderShape::HalfSpace) {
      r.vector("point", k.point);
      r.vector("normal", k.normal);
    } else if (k.shape == ColliderShape::Box) {
      r.vector("min", k.min);
      r.vector("max", k.max);
    } else if (k.shape == ColliderShape::Mesh) {
      r.string("mesh", k.mesh);
      r.vector("scale", k.scale);
      r.vector("rotation", k.rotation);
      r.vector("translation", k.translation);
      r.objects("keyframes", [&](ObjectReader& q, std::size_t) {
        ColliderKeyframe key;
        if (!q.has("time")) fail(source, q.at("time"), "missing (expected the key's time in s)");
        q.number("time", key.time);
        q.vector("translation", key.translation);
        q.vector("rotation", key.rotation);
        k.keyframes.push_back(key);
      });
    } else {
      r.vector("center", k.center);
      r.number("radius", k.radius);
    }
    r.vector("velocity", k.velocity);
    r.choice("condition", kCondition, k.condition);
    r.number("friction", k.friction);
    s.colliders.push_back(k);
  });
  top.objects("emitters", [&](ObjectReader& r, std::size_t) {
    EmitterParams e;
    if (quality_ppc > 0) e.particles_per_cell = quality_ppc;
    r.choice("shape", kShape, e.shape);
    if (e.shape == Shape::Box) {
      if (!r.has("min") || !r.has("max")) fail(source, r.at("min"), "a box needs \"min\" and \"max\"");
      r.vector("min", e.min);
      r.vector("max", e.max);
    } else {
      if (!r.has("center") || !r.has("radius")) fail(source, r.at("radius"), "a sphere needs \"center\" and \"radius\"");
      r.vector("center", e.center);
      r.number("radius", e.radius);
    }
    if (!r.has("material")) fail(source, r.at("material"), "missing (expected the name of a material)");
    r.string("material", e.material);
    if (!r.has("rate")) fail(source, r.at("rate"), "missing (expected the emitted volume per second)");
    r.number("rate", e.rate);
    r.vector("velocity", e.velocity);
    r.number("start", e.start);
    r.number("end", e.end);
    r.number("particles_per_cell", e.particles_per_cell);
    r.integer("seed", e.seed);
    s.emitters.push_back(e);
  });
  top.object("output", [&](ObjectReader& r) {
    r.string("directory", s.output.directory);
    r.number("fps", s.output.fps);
    r.integer("frames", s.output.frames, 0, std::numeric_limits<int>::max());
    r.strings("attributes", s.output.attributes);
    r.choice("format", kEncoding, s.output.format);
    r.string("up_axis", s.output.up_axis);
    r.number("mass_drift", s.output.mass_drift);
    r.number("volume_drift", s.output.volume_drift);
    r.number("energy_growth", s.output.energy_growth);
    r.integer("checkpoint_every", s.output.checkpoint_every, 0, std::numeric_limits<int>::max());
    r.boolean("per_rank", s.output.per_rank);
    r.strings("surface", s.output.surface);
    r.boolean("vdb_points", s.output.vdb_points);
    r.number("surface_voxel_size", s.output.surface_voxel_size);
    r.string("surface_method", s.output.surface_method);
    r.integer("surface_smoothing", s.output.surface_smoothing, -1000000, 1000000);
    r.boolean("surface_per_material", s.output.surface_per_material);
    r.boolean("error_estimate", s.output.error_estimate);
    r.number("error_order", s.output.error_order);
  });
  top.object("limits", [&](ObjectReader& r) {
    r.number("memory_gb", s.limits.memory_gb);
    r.integer("substeps_per_frame", s.limits.substeps_per_frame);
  });
  std::string description;
  top.string("description", description);  // free text for people, ignored
  top.finish();
  s.validate();
  return s;
}

Scene load_scene(const std::filesystem::path& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec))
    throw IoError(path.string() + ": is a directory (expected a scene file, JSON)");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path.string() + ": cannot open the scene file (does it exist and is it readable?)");
  // Read in chunks up to kMaxSceneBytes: a device such as /dev/zero or a huge file is refused
  // before it fills the memory.
  std::string text;
  char chunk[1 << 16];
  while (in.read(chunk, sizeof chunk) || in.gcount() > 0) {
    text.append(chunk, std::size_t(in.gcount()));
    if (text.size() > kMaxSceneBytes)
      throw IoError(path.string() + ": larger than " + std::to_string(kMaxSceneBytes >> 20) +
                    " MiB (expected a scene file, JSON of a few kilobytes)");
  }
  if (in.bad()) throw IoError(path.string() + ": read error");
  return parse_scene(text, path.string());
}

namespace io {

void read_scene_files(Scene& scene) {
  auto files = std::make_shared<SceneFiles>();
  if (scene.solver.type == SolverType::FEM) {
    for (const BodyParams& b : scene.bodies) {
      if (b.mesh.empty()) continue;
      if (scene.solver.dimension == 2) {
        if (!files->tet_meshes_2.count(b.mesh)) files->tet_meshes_2.emplace(b.mesh, read_tetgen<2>(scene.resolve(b.mesh)));
      } else if (!files->tet_meshes_3.count(b.mesh)) {
        files->tet_meshes_3.emplace(b.mesh, read_tetgen<3>(scene.resolve(b.mesh)));
      }
    }
  } else {
    const auto read = [&](const std::string& file, const std::string& where) {
      if (files->triangle_meshes.count(file)) return;
      try {
        files->triangle_meshes.emplace(file, read_triangle_mesh(scene.resolve(file)));
      } catch (const ResourceError&) {
        throw;
      } catch (const IoError& e) {
        throw IoError(scene.source + ": " + where + ".mesh: " + e.what());
      }
    };
    for (std::size_t i = 0; i < scene.bodies.size(); ++i)
      if (scene.bodies[i].shape == Shape::Mesh) read(scene.bodies[i].mesh, "bodies[" + std::to_string(i) + "]");
    for (std::size_t i = 0; i < scene.colliders.size(); ++i)
      if (scene.colliders[i].shape == ColliderShape::Mesh)
        read(scene.colliders[i].mesh, "colliders[" + std::to_string(i) + "]");
  }
  scene.files = std::move(files);
}

bool names_files(const Scene& scene) {
  for (const BodyParams& b : scene.bodies)
    if (b.shape == Shape::Mesh || (scene.solver.type == SolverType::FEM && !b.mesh.empty())) return true;
  for (const ColliderParams& c : scene.colliders)
    if (c.shape == ColliderShape::Mesh) return true;
  return false;
}

}  // namespace io
}  // namespace slurry
