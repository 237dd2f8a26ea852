// Scene files: JSON -> Scene structs, with every key type-checked and range-checked.
#include "slurry/engine/scene.h"
#include "slurry/engine/quality.h"

#include "fnv1a.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <utility>
#include <unistd.h>

namespace slurry {
namespace {

using json = nlohmann::json;

template <class E>
using NameTable = std::vector<std::pair<std::string_view, E>>;

const NameTable<Precision> kPrecision{{"float", Precision::Float}, {"double", Precision::Double}};
const NameTable<TransferKind> kTransfer{{"pic", TransferKind::PIC},
                                        {"flip", TransferKind::FLIP},
                                        {"apic", TransferKind::APIC},
                                        {"mls", TransferKind::MLS}};
const NameTable<KernelKind> kKernel{
    {"linear", KernelKind::Linear}, {"quadratic", KernelKind::Quadratic}, {"cubic", KernelKind::Cubic}};
const NameTable<Integrator> kIntegrator{{"explicit", Integrator::Explicit}, {"implicit", Integrator::Implicit}};
const NameTable<ImplicitPreconditioner> kImplicitPreconditioner{{"jacobi", ImplicitPreconditioner::Jacobi},
                                                                {"block_jacobi", ImplicitPreconditioner::BlockJacobi},
                                                                {"ic0", ImplicitPreconditioner::IC0}};
const NameTable<SolverType> kSolverType{{"mpm", SolverType::MPM}, {"flip", SolverType::FLIP}, {"fem", SolverType::FEM}};
const NameTable<ElasticModel> kElastic{{"corotated_linear", ElasticModel::CorotatedLinear},
                                       {"fixed_corotated", ElasticModel::FixedCorotated},
                                       {"neo_hookean", ElasticModel::NeoHookean},
                                       {"stvk", ElasticModel::StVK},
                                       {"hencky_stvk", ElasticModel::HenckyStVK},
                                       {"fluid", ElasticModel::Fluid}};
const NameTable<PlasticModel> kPlastic{{"none", PlasticModel::None},
                                       {"snow", PlasticModel::Snow},
                                       {"drucker_prager", PlasticModel::DruckerPrager},
                                       {"von_mises", PlasticModel::VonMises}};
const NameTable<Shape> kShape{
    {"box", Shape::Box}, {"sphere", Shape::Sphere}, {"cylinder", Shape::Cylinder}, {"mesh", Shape::Mesh}};
const NameTable<Sampling> kSampling{{"regular", Sampling::Regular}, {"jittered", Sampling::Jittered}};
const NameTable<ColliderShape> kColliderShape{{"half_space", ColliderShape::HalfSpace},
                                              {"box", ColliderShape::Box},
                                              {"sphere", ColliderShape::Sphere},
                                              {"mesh", ColliderShape::Mesh}};
const NameTable<Condition> kCondition{
    {"sticky", Condition::Sticky}, {"slip", Condition::Slip}, {"separate", Condition::Separate}};
const NameTable<GridKind> kGrid{{"auto", GridKind::Auto}, {"sparse", GridKind::Sparse}, {"dense", GridKind::Dense}};
const NameTable<PlyEncoding> kEncoding{{"binary", PlyEncoding::Binary}, {"ascii", PlyEncoding::Ascii}};
const NameTable<AdvectionScheme> kAdvection{{"euler", AdvectionScheme::Euler},
                                            {"midpoint", AdvectionScheme::Midpoint},
                                            {"heun", AdvectionScheme::Heun},
                                            {"rk3", AdvectionScheme::RK3}};
const NameTable<PressurePreconditioner> kPreconditioner{{"multigrid", PressurePreconditioner::Multigrid},
                                                        {"mic0", PressurePreconditioner::MIC0},
                                                        {"jacobi", PressurePreconditioner::Jacobi},
                                                        {"none", PressurePreconditioner::None}};
const NameTable<OnInstability> kOnInstability{{"stop", OnInstability::Stop}, {"retry", OnInstability::Retry}};
const std::vector<std::string> kAttributes{"position", "velocity", "material", "J", "plastic", "id"};

template <class E>
std::string_view name_of(const NameTable<E>& table, E value) {
  for (const auto& [name, v] : table)
    if (v == value) return name;
  return "?";
}

template <class E>
std::string choices(const NameTable<E>& table) {
  std::string s;
  for (const auto& [name, v] : table) s += (s.empty() ? "\"" : ", \"") + std::string(name) + "\"";
  return s;
}

std::string fmt_num(double x) {
  std::ostringstream o;
  o.precision(12);
  o << x;
  return o.str();
}

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

/// Range checks shared by validate(): each names the path and what was expected.
struct Checker {
  const std::string& source;
  void positive(const std::string& path, double v) const {
    if (!(v > 0)) fail(source, path, "expected a number > 0, got " + fmt_num(v));
  }
  void non_negative(const std::string& path, double v) const {
    if (!(v >= 0)) fail(source, path, "expected a number >= 0, got " + fmt_num(v));
  }
  void in_range(const std::string& path, double v, double lo, double hi, bool lo_open, bool hi_open) const {
    const bool ok = (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
    if (!ok)
      fail(source, path,
           "expected a number in " + std::string(lo_open ? "(" : "[") + fmt_num(lo) + ", " + fmt_num(hi) +
               (hi_open ? ")" : "]") + ", got " + fmt_num(v));
  }
};

std::string vec_str(const Eigen::Vector3d& v, int dim) {
  std::string s = "[";
  for (int d = 0; d < dim; ++d) s += (d ? ", " : "") + fmt_num(v[d]);
  return s + "]";
}

/// The settings solver.type "fem" needs: co-rotated linear materials without plasticity, and
/// bodies that are a mesh file, a box or a sphere (meshed with spacing domain.dx).
void validate_fem(const Scene& s) {
  const Checker c{s.source};
  for (std::size_t i = 0; i < s.materials.size(); ++i) {
    const auto& m = s.materials[i];
    const std::string p = "materials[" + std::to_string(i) + "]";
    if (m.model != ElasticModel::CorotatedLinear)
      fail(s.source, p + ".model", "solver.type \"fem\" simulates \"corotated_linear\" only, got \"" +
                                       std::string(to_string(m.model)) + "\"");
    if (m.plasticity != PlasticModel::None)
      fail(s.source, p + ".plasticity", "solver.type \"fem\" has no plasticity (expected \"none\")");
    c.non_negative(p + ".damping", m.damping);
  }
  for (std::size_t i = 0; i < s.bodies.size(); ++i) {
    if (s.bodies[i].shape == Shape::Mesh)
      fail(s.source, "bodies[" + std::to_string(i) + "].shape",
           "solver.type \"fem\" reads a TetGen \"mesh\" for a \"box\" or \"sphere\" body; \"mesh\" bodies (triangle meshes) are "
           "filled with particles by \"mpm\" and \"flip\"");
    if (s.bodies[i].mesh.empty() && s.bodies[i].shape == Shape::Cylinder)
      fail(s.source, "bodies[" + std::to_string(i) + "].shape",
           "solver.type \"fem\" meshes \"box\" and \"sphere\" bodies; give a cylinder as a TetGen \"mesh\"");
  }
}

/// json::parse with the limits a scene file needs, checked while parsing (before a deep or huge
/// value is built): nesting at most kMaxSceneDepth, no duplicate keys in an object, numbers in
/// the range of double. Each error names the JSON path where it happened.
json parse_json(std::string_view text, const std::string& source) {
  struct Level {
    bool array = false;
    std::string key;  // the current key of an object
    std::size_t index = 0;  // the current element of an array
    std::set<std::string> keys;
  };
  std::vector<Level> stack;
  const auto path = [&] {
    std::string p;
    for (const Level& l : stack) {
      if (l.array)
        p += "[" + std::to_string(l.index) + "]";
      else if (!l.key.empty())
        p += (p.empty() ? "" : ".") + l.key;
      if (p.size() > 80) return p.substr(0, 77) + "...";
    }
    return p.empty() ? std::string("(top level)") : p;
  };
  const json::parser_callback_t check = [&](int, json::parse_event_t event, json& parsed) {
    switch (event) {
      case json::parse_event_t::object_start:
      case json::parse_event_t::array_start:
        if (int(stack.size()) >= kMaxSceneDepth)
          fail(source, path(), "nested deeper than " + std::to_string(kMaxSceneDepth) +
                                   " levels (expected a scene: objects and arrays a few levels deep)");
        stack.push_back({event == json::parse_event_t::array_start, {}, 0, {}});
        break;
      case json::parse_event_t::key:
        stack.back().key = parsed.get<std::string>();
        if (!stack.back().keys.insert(stack.back().key).second)
          fail(source, path(), "duplicate key (expected each key once in an object)");
        break;
      case json::parse_event_t::object_end:
      case json::parse_event_t::array_end:
        stack.pop_back();
        [[fallthrough]];
      case json::parse_event_t::value:
        if (!stack.empty() && stack.back().array) ++stack.back().index;
        break;
    }
    return true;
  };
  try {
    return json::parse(text.begin(), text.end(), check);
  } catch (const json::out_of_range& e) {
    // The parser's only out_of_range: a number beyond the range of double (406).
    std::string what = e.what();
    const auto q = what.find('\'');
    const std::string number = q == std::string::npos ? what : what.substr(q);
    fail(source, path(), "number " + number + " is out of the range of double (expected a finite number, |x| < 1.8e308)");
  } catch (const json::exception& e) {
    throw SceneError(source + ": not valid JSON: " + e.what());
  }
}

double wave_speed(const MaterialParams& m) {
  if (m.model == ElasticModel::Fluid) return std::sqrt(m.bulk_modulus / m.density);
  const double mu = m.E / (2 * (1 + m.nu)), lambda = m.E * m.nu / ((1 + m.nu) * (1 - 2 * m.nu));
  return std::sqrt((lambda + 2 * mu) / m.density);
}

/// A body's bounding box and the share of it the shape fills.
void body_extent(const BodyParams& b, int dim, Eigen::Vector3d& lo, Eigen::Vector3d& hi, double& fill) {
  lo = b.min;
  hi = b.max;
  fill = 1;
  if (b.shape == Shape::Box) return;
  lo = b.center.array() - b.radius;
  hi = b.center.array() + b.radius;
  const double pi = 3.14159265358979323846;
  fill = dim == 3 && b.shape == Shape::Sphere ? pi / 6 : pi / 4;
  if (b.shape == Shape::Cylinder) {
    lo[b.axis] = b.center[b.axis] - 0.5 * b.height;
    hi[b.axis] = b.center[b.axis] + 0.5 * b.height;
  }
}

/// Whether two bodies share volume: boxes by their intervals, spheres by their centres'
/// distance, anything with a cylinder by bounding boxes.
bool overlap(const BodyParams& a, const BodyParams& b, int dim) {
  Eigen::Vector3d alo, ahi, blo, bhi;
  double fill;
  body_extent(a, dim, alo, ahi, fill);
  body_extent(b, dim, blo, bhi, fill);
  for (int d = 0; d < dim; ++d)
    if (!(alo[d] < bhi[d] && blo[d] < ahi[d])) return false;
  const auto distance_to_box = [dim](const Eigen::Vector3d& c, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
    double d2 = 0;
    for (int d = 0; d < dim; ++d) {
      const double e = std::max({lo[d] - c[d], 0.0, c[d] - hi[d]});
      d2 += e * e;
    }
    return std::sqrt(d2);
  };
  if (a.shape == Shape::Sphere && b.shape == Shape::Sphere)
    return (a.center - b.center).head(dim).norm() < a.radius + b.radius;
  if (a.shape == Shape::Sphere && b.shape == Shape::Box) return distance_to_box(a.center, b.min, b.max) < a.radius;
  if (b.shape == Shape::Sphere && a.shape == Shape::Box) return distance_to_box(b.center, a.min, a.max) < b.radius;
  return true;
}

}  // namespace

std::string_view to_string(ElasticModel m) { return name_of(kElastic, m); }
std::string_view to_string(PlasticModel m) { return name_of(kPlastic, m); }
std::string_view to_string(TransferKind m) { return name_of(kTransfer, m); }
std::string_view to_string(KernelKind m) { return name_of(kKernel, m); }
std::string_view to_string(SolverType m) { return name_of(kSolverType, m); }
std::string_view to_string(Integrator m) { return name_of(kIntegrator, m); }
std::string_view to_string(ImplicitPreconditioner m) { return name_of(kImplicitPreconditioner, m); }
std::string_view to_string(AdvectionScheme m) { return name_of(kAdvection, m); }
std::string_view to_string(PressurePreconditioner m) { return name_of(kPreconditioner, m); }
std::string_view to_string(OnInstability m) { return name_of(kOnInstability, m); }

int Scene::material_index(std::string_view name) const {
  for (std::size_t i = 0; i < materials.size(); ++i)
    if (materials[i].name == name) return int(i);
  return -1;
}

void Scene::validate_flip() const {
  const Checker c{source};
  const int dim = solver.dimension;
  if (solver.transfer == TransferKind::MLS)
    fail(source, "solver.transfer", "solver.type \"flip\" takes \"pic\", \"flip\" or \"apic\", got \"mls\"");
  if (solver.kernel == KernelKind::Cubic)
    fail(source, "solver.kernel", "solver.type \"flip\" takes \"linear\" or \"quadratic\", got \"cubic\"");
  c.in_range("solver.pressure.tolerance", solver.pressure.tolerance, 0, 1, true, true);
  if (solver.pressure.max_iterations < 1 || solver.pressure.max_iterations > 1000000)
    fail(source, "solver.pressure.max_iterations",
         "expected an integer in [1, 1000000], got " + std::to_string(solver.pressure.max_iterations));
  if (solver.reseed.min_per_cell < 0 || solver.reseed.min_per_cell > 64)
    fail(source, "solver.reseed.min_per_cell",
         "expected an integer in [0, 64], got " + std::to_string(solver.reseed.min_per_cell));
  if (solver.reseed.max_per_cell != 0 &&
      (solver.reseed.max_per_cell <= solver.reseed.min_per_cell || solver.reseed.max_per_cell > 512))
    fail(source, "solver.reseed.max_per_cell",
         "expected 0 (off) or an integer in (min_per_cell = " + std::to_string(solver.reseed.min_per_cell) + ", 512], got " +
             std::to_string(solver.reseed.max_per_cell));
  for (std::size_t i = 0; i < materials.size(); ++i) {
    const std::string p = "materials[" + std::to_string(i) + "]";
    if (materials[i].model != ElasticModel::Fluid)
      fail(source, p + ".model",
           "solver.type \"flip\" simulates liquids: expected \"fluid\", got \"" +
               std::string(to_string(materials[i].model)) + "\"");
    if (materials[i].plasticity != PlasticModel::None)
      fail(source, p + ".plasticity", "a \"fluid\" material takes no plasticity (expected \"none\")");
    if (i > 0 && materials[i].density != materials[0].density)
      fail(source, p + ".density",
           "the FLIP solver takes one density for all liquids: expected " + fmt_num(materials[0].density) +
               " (materials[0].density), got " + fmt_num(materials[i].density));
  }
  if (boundaries.walls == Condition::Sticky)
    fail(source, "boundaries.walls", "solver.type \"flip\" walls are free-slip: expected \"slip\" or \"separate\", got \"sticky\"");
  if (boundaries.friction != 0)
    fail(source, "boundaries.friction", "solver.type \"flip\" walls are free-slip: expected 0, got " + fmt_num(boundaries.friction));
  for (std::size_t i = 0; i < colliders.size(); ++i) {
    const std::string p = "colliders[" + std::to_string(i) + "]";
    if (colliders[i].condition == Condition::Sticky)
      fail(source, p + ".condition", "solver.type \"flip\" colliders are free-slip: expected \"slip\" or \"separate\", got \"sticky\"");
    if (colliders[i].friction != 0)
      fail(source, p + ".friction", "solver.type \"flip\" colliders are free-slip: expected 0, got " + fmt_num(colliders[i].friction));
  }
  for (std::size_t i = 0; i < emitters.size(); ++i) {
    const auto& e = emitters[i];
    const std::string p = "emitters[" + std::to_string(i) + "]";
    if (material_index(e.material) < 0) {
      std::string known;
      for (const auto& m : materials) known += (known.empty() ? "\"" : ", \"") + m.name + "\"";
      fail(source, p + ".material", "expected the name of a material (" + known + "), got \"" + e.material + "\"");
    }
    Eigen::Vector3d lo = e.min, hi = e.max;
    if (e.shape == Shape::Box) {
      for (int d = 0; d < dim; ++d)
        if (!(e.max[d] > e.min[d]))
          fail(source, p + ".max", "expected every component greater than min " + vec_str(e.min, dim) +
                                       " (an empty box), got " + vec_str(e.max, dim));
    } else if (e.shape == Shape::Sphere) {
      c.positive(p + ".radius", e.radius);
      lo = e.center.array() - e.radius;
      hi = e.center.array() + e.radius;
    } else {
      fail(source, p + ".shape", std::string("expected \"box\" or \"sphere\", got \"") + (e.shape == Shape::Mesh ? "mesh" : "cylinder") + "\"");
    }
    for (int d = 0; d < dim; ++d)
      if (lo[d] < domain.min[d] || hi[d] > domain.max[d])
        fail(source, p, "the emitter spans " + vec_str(lo, dim) + " to " + vec_str(hi, dim) +
                            ", expected it inside the domain " + vec_str(domain.min, dim) + " to " +
                            vec_str(domain.max, dim));
    c.positive(p + ".rate", e.rate);
    c.non_negative(p + ".start", e.start);
    if (!(e.end > e.start))
      fail(source, p + ".end", "expected a time greater than start (" + fmt_num(e.start) + "), got " + fmt_num(e.end));
    c.in_range(p + ".particles_per_cell", e.particles_per_cell, 0, 512, true, false);
  }
  for (std::size_t i = 0; i < output.attributes.size(); ++i) {
    const auto& a = output.attributes[i];
    if (a == "J" || a == "plastic")
      fail(source, "output.attributes[" + std::to_string(i) + "]",
           "solver.type \"flip\" writes \"position\", \"velocity\", \"material\" and \"id\" (its liquid is incompressible), got \"" + a + "\"");
  }
}

void Scene::validate() const {
  const Checker c{source};
  const int dim = solver.dimension;
  if (dim != 2 && dim != 3) fail(source, "solver.dimension", "expected 2 or 3, got " + std::to_string(dim));
  // Solvers and integrators this build provides (each branch of the engine enables its own).
  const bool flip = solver.type == SolverType::FLIP;
  const bool fem = solver.type == SolverType::FEM;
  if (flip && solver.integrator != Integrator::Explicit)
    fail(source, "solver.integrator", "expected \"explicit\" for solver.type \"flip\" (\"implicit\" is for MPM solids and FEM)");
  if (solver.integrator == Integrator::Implicit && !fem)
    for (std::size_t i = 0; i < materials.size(); ++i)
      if (materials[i].model == ElasticModel::Fluid)
        fail(source, "solver.integrator",
             "\"implicit\" is for solids; materials[" + std::to_string(i) + "] (\"" + materials[i].name +
                 "\") is a \"fluid\", which runs with \"explicit\" only");
  for (std::size_t i = 0; i < bodies.size(); ++i) {
    const auto& b = bodies[i];
    const std::string p = "bodies[" + std::to_string(i) + "]";
    if (!b.mesh.empty() && !fem && b.shape != Shape::Mesh)
      fail(source, p + ".mesh", "a triangle mesh is filled with particles by \"shape\": \"mesh\" (TetGen meshes are for solver.type \"fem\")");
    if (b.shape == Shape::Mesh && !fem) {
      if (b.mesh.empty()) fail(source, p + ".mesh", "missing (expected the path of a closed triangle mesh, .obj or .ply)");
      if (dim != 3) fail(source, p + ".shape", "\"mesh\" bodies are 3D (solver.dimension is 2)");
      for (int d = 0; d < 3; ++d)
        if (!(std::abs(b.scale[d]) > 0))
          fail(source, p + ".scale[" + std::to_string(d) + "]", "expected a non-zero factor, got " + fmt_num(b.scale[d]));
    }
  }
  if (fem) validate_fem(*this);

  // Domain.
  c.positive("domain.dx", domain.dx);
  for (int d = 0; d < dim; ++d)
    if (!(domain.max[d] > domain.min[d]))
      fail(source, "domain.max", "expected every component greater than domain.min " + vec_str(domain.min, dim) +
                                     ", got " + vec_str(domain.max, dim));
  double nodes = 1, blocks = 1;
  for (int d = 0; d < dim; ++d) {
    const double n = std::ceil((domain.max[d] - domain.min[d]) / domain.dx - 1e-9);
    if (n < 4) fail(source, "domain.dx", "expected at least 4 cells along each axis, got " + fmt_num(n));
    nodes *= n + 7;
    blocks *= std::ceil((n + 7) / (dim == 3 ? 4 : 8));
  }
  const bool dense = domain.grid == GridKind::Dense || (domain.grid == GridKind::Auto && solver.integrator == Integrator::Implicit);
  if (domain.grid == GridKind::Sparse && solver.integrator == Integrator::Implicit)
    fail(source, "domain.grid", "expected \"dense\" or \"auto\" with solver.integrator \"implicit\" (its solve runs on the dense grid)");
  if (dense && nodes > 2.0e9)
    fail(source, "domain.dx",
         "the dense grid would have " + fmt_num(nodes) + " nodes (limit 2e9); use a larger dx or domain.grid \"sparse\"");
  // The sparse grid's page table holds one int32 per block of the domain (two tables: grid and
  // particle bins), so 2^28 blocks cost 2 GiB.
  if (blocks > double(1 << 28))
    fail(source, "domain.dx", "the sparse grid's page table would have " + fmt_num(blocks) + " blocks (limit 2^28); use a larger dx");

  // Float positions far from the origin. A float resolves a coordinate x only to its spacing
  // there, up to 2^-23 |x|: at 1e4 m that is 1e-3 m, a twentieth of a 2 cm cell, and slow
  // motions (under spacing / (2 dt)) do not move particles at all. Measured on a block landing
  // at dx = 1/32 m (tests/extremes/precision_test.cpp): shifted to 1e4 m its centre of mass ends
  // 0.13 cells off and its energy grows 5%; at 1e3 m, 0.004 cells. Coordinates are allowed up
  // to kMaxFloatCells cells, where the spacing is at most 1/256 of a cell.
  if (solver.precision == Precision::Float) {
    constexpr double kMaxFloatCells = 32768;
    double far = 0;
    for (int d = 0; d < dim; ++d) far = std::max({far, std::abs(domain.min[d]), std::abs(domain.max[d])});
    const auto g3 = [](double x) {
      char b[32];
      std::snprintf(b, sizeof b, "%.3g", x);
      return std::string(b);
    };
    if (far / domain.dx > kMaxFloatCells)
      fail(source, "solver.precision",
           "\"float\" resolves positions " + g3(far) + " m from the origin only to " + g3(far * 0x1p-23) +
               " m, " + g3(far * 0x1p-23 / domain.dx) + " of a cell of domain.dx = " + fmt_num(domain.dx) +
               " m; expected every domain coordinate within 32768 cells (" + g3(kMaxFloatCells * domain.dx) +
               " m) of the origin: use \"precision\": \"double\", or move the scene's origin into the domain");
  }

  // Solver.
  if (solver.transfer == TransferKind::MLS && solver.kernel == KernelKind::Linear)
    fail(source, "solver.kernel",
         "transfer \"mls\" needs kernel \"quadratic\" or \"cubic\" (its D_p^-1 is not constant for the linear kernel)");
  c.in_range("solver.flip_ratio", solver.flip_ratio, 0, 1, false, false);
  c.in_range("solver.volume_correction", solver.volume_correction, 0, 1, false, false);
  c.in_range("solver.cfl", solver.cfl, 0, flip ? 5 : 1, true, false);
  c.in_range("solver.elastic_cfl", solver.elastic_cfl, 0, 1, true, false);
  c.positive("solver.max_dt", solver.max_dt);
  c.in_range("solver.cg_tolerance", solver.cg_tolerance, 0, 1, true, true);
  if (solver.cg_max_iterations < 1)
    fail(source, "solver.cg_max_iterations", "expected an integer >= 1, got " + std::to_string(solver.cg_max_iterations));
  if (solver.max_retries < 1 || solver.max_retries > 30)
    fail(source, "solver.max_retries", "expected an integer in [1, 30], got " + std::to_string(solver.max_retries));

  if (flip) validate_flip();
  if (!flip && !emitters.empty()) fail(source, "emitters", "emitters need solver.type \"flip\"");

  // Materials.
  if (materials.empty()) fail(source, "materials", "expected at least one material");
  for (std::size_t i = 0; i < materials.size(); ++i) {
    const auto& m = materials[i];
    const std::string p = "materials[" + std::to_string(i) + "]";
    if (m.name.empty()) fail(source, p + ".name", "expected a non-empty name");
    for (std::size_t j = 0; j < i; ++j)
      if (materials[j].name == m.name) fail(source, p + ".name", "duplicate material name \"" + m.name + "\"");
    c.positive(p + ".density", m.density);
    if (m.model == ElasticModel::Fluid) {
      c.positive(p + ".bulk_modulus", m.bulk_modulus);
      c.in_range(p + ".gamma", m.gamma, 1, 20, false, false);
      if (m.plasticity != PlasticModel::None)
        fail(source, p + ".plasticity", "a \"fluid\" material takes no plasticity (expected \"none\")");
    } else {
      c.positive(p + ".E", m.E);
      c.in_range(p + ".nu", m.nu, -1, 0.5, true, true);
    }
    switch (m.plasticity) {
      case PlasticModel::Snow:
        c.in_range(p + ".critical_compression", m.critical_compression, 0, 1, true, true);
        c.positive(p + ".critical_stretch", m.critical_stretch);
        c.non_negative(p + ".hardening", m.hardening);
        break;
      case PlasticModel::DruckerPrager:
        c.in_range(p + ".friction_angle", m.friction_angle, 0, 90, true, true);
        break;
      case PlasticModel::VonMises:
        c.positive(p + ".yield_stress", m.yield_stress);
        break;
      case PlasticModel::None:
        break;
    }
  }

  // Sleeping material.
  c.non_negative("solver.sleep.speed", solver.sleep.speed);
  c.non_negative("solver.sleep.wake_speed", solver.sleep.wake_speed);
  if (solver.sleep.speed > 0) {
    c.positive("solver.sleep.strain_rate", solver.sleep.strain_rate);
    if (solver.sleep.substeps < 1 || solver.sleep.substeps > 65535)
      fail(source, "solver.sleep.substeps", "expected an integer in [1, 65535], got " + std::to_string(solver.sleep.substeps));
    if (solver.type != SolverType::MPM)
      fail(source, "solver.sleep.speed", "sleeping material is for solver.type \"mpm\" (expected 0)");
    if (solver.integrator == Integrator::Implicit)
      fail(source, "solver.sleep.speed", "sleeping material is for the \"explicit\" integrator (expected 0 with \"implicit\")");
  }

  // Bodies.
  if (bodies.empty() && emitters.empty())
    fail(source, "bodies", flip ? "expected at least one body or emitter" : "expected at least one body");
  for (std::size_t i = 0; i < bodies.size(); ++i) {
    const auto& b = bodies[i];
    const std::string p = "bodies[" + std::to_string(i) + "]";
    if (material_index(b.material) < 0) {
      std::string known;
      for (const auto& m : materials) known += (known.empty() ? "\"" : ", \"") + m.name + "\"";
      fail(source, p + ".material", "expected the name of a material (" + known + "), got \"" + b.material + "\"");
    }
    c.positive(p + ".particles_per_cell", b.particles_per_cell);
    if (b.particles_per_cell > 512) fail(source, p + ".particles_per_cell", "expected at most 512, got " + fmt_num(b.particles_per_cell));
    if (!b.mesh.empty()) continue;  // a mesh body's extent is checked when the mesh is read
    Eigen::Vector3d lo = b.min, hi = b.max;
    for (std::size_t j = 0; j < i; ++j)
      if (bodies[j].mesh.empty() && overlap(b, bodies[j], dim))
        fail(source, p, "overlaps bodies[" + std::to_string(j) + "] (expected bodies that share no volume: the overlap would hold two sets of particles)");
    switch (b.shape) {
      case Shape::Box:
        for (int d = 0; d < dim; ++d)
          if (!(b.max[d] > b.min[d]))
            fail(source, p + ".max", "expected every component greater than min " + vec_str(b.min, dim) +
                                         " (an empty box), got " + vec_str(b.max, dim));
        break;
      case Shape::Sphere:
        c.positive(p + ".radius", b.radius);
        lo = b.center.array() - b.radius;
        hi = b.center.array() + b.radius;
        break;
      case Shape::Cylinder:
        c.positive(p + ".radius", b.radius);
        c.positive(p + ".height", b.height);
        if (b.axis < 0 || b.axis >= dim)
          fail(source, p + ".axis", "expected an axis index in [0, " + std::to_string(dim - 1) + "], got " + std::to_string(b.axis));
        lo = b.center.array() - b.radius;
        hi = b.center.array() + b.radius;
        lo[b.axis] = b.center[b.axis] - 0.5 * b.height;
        hi[b.axis] = b.center[b.axis] + 0.5 * b.height;
        break;
      case Shape::Mesh:
        break;  // unreachable: a mesh body names its file
    }
    for (int d = 0; d < dim; ++d)
      if (lo[d] < domain.min[d] || hi[d] > domain.max[d])
        fail(source, p, "the body spans " + vec_str(lo, dim) + " to " + vec_str(hi, dim) +
                            ", expected it inside the domain " + vec_str(domain.min, dim) + " to " +
                            vec_str(domain.max, dim));
    // A body narrower than one particle spacing (FEM: one cell) seeds a single row of particles
    // or one particle: almost surely a unit slip, never what the scene means.
    const double spacing = fem ? domain.dx : domain.dx / std::pow(b.particles_per_cell, 1.0 / dim);
    for (int d = 0; d < dim; ++d)
      if (hi[d] - lo[d] < spacing)
        fail(source, p, "the body is " + fmt_num(hi[d] - lo[d]) + " m across along axis " + std::to_string(d) +
                            ", expected at least one " + (fem ? "cell (domain.dx = " : "particle spacing (dx / particles_per_cell^(1/dimension) = ") +
                            fmt_num(spacing) + " m)");
  }

  // Boundaries and colliders.
  c.non_negative("boundaries.friction", boundaries.friction);
  if (boundaries.friction > 0 && boundaries.walls != Condition::Separate)
    fail(source, "boundaries.friction", "friction applies to walls \"separate\" only");
  if (boundaries.thickness < 1 || boundaries.thickness > 8)
    fail(source, "boundaries.thickness", "expected an integer in [1, 8], got " + std::to_string(boundaries.thickness));
  for (std::size_t i = 0; i < colliders.size(); ++i) {
    const auto& k = colliders[i];
    const std::string p = "colliders[" + std::to_string(i) + "]";
    c.non_negative(p + ".friction", k.friction);
    if (k.friction > 0 && k.condition != Condition::Separate)
      fail(source, p + ".friction", "friction applies to condition \"separate\" only");
    switch (k.shape) {
      case ColliderShape::HalfSpace:
        if (!(k.normal.head(dim).norm() > 0)) fail(source, p + ".normal", "expected a non-zero vector");
        break;
      case ColliderShape::Box:
        for (int d = 0; d < dim; ++d)
          if (!(k.max[d] > k.min[d]))
            fail(source, p + ".max", "expected every component greater than min " + vec_str(k.min, dim) + ", got " + vec_str(k.max, dim));
        break;
      case ColliderShape::Sphere:
        c.positive(p + ".radius", k.radius);
        break;
      case ColliderShape::Mesh:
        if (k.mesh.empty()) fail(source, p + ".mesh", "missing (expected the path of a closed triangle mesh, .obj or .ply)");
        if (dim != 3) fail(source, p + ".shape", "\"mesh\" colliders are 3D (solver.dimension is 2)");
        for (int d = 0; d < 3; ++d)
          if (!(std::abs(k.scale[d]) > 0))
            fail(source, p + ".scale[" + std::to_string(d) + "]", "expected a non-zero factor, got " + fmt_num(k.scale[d]));
        for (std::size_t j = 1; j < k.keyframes.size(); ++j)
          if (!(k.keyframes[j].time > k.keyframes[j - 1].time))
            fail(source, p + ".keyframes[" + std::to_string(j) + "].time",
                 "expected times in increasing order: " + fmt_num(k.keyframes[j].time) + " follows " + fmt_num(k.keyframes[j - 1].time));
        break;
    }
    if (k.shape != ColliderShape::Mesh && (!k.mesh.empty() || !k.keyframes.empty()))
      fail(source, p + (k.mesh.empty() ? ".keyframes" : ".mesh"), "\"mesh\" and \"keyframes\" belong to \"shape\": \"mesh\"");
  }

  // Output.
  c.positive("output.fps", output.fps);
  c.in_range("output.fps", output.fps, 1e-6, 1e6, false, false);
  if (output.frames < 0) fail(source, "output.frames", "expected an integer >= 0, got " + std::to_string(output.frames));
  if (output.directory.empty()) fail(source, "output.directory", "expected a non-empty path");
  if (output.checkpoint_every < 0)
    fail(source, "output.checkpoint_every", "expected an integer >= 0 (0 = no checkpoints), got " + std::to_string(output.checkpoint_every));
  for (const auto& [key, value] : {std::pair<const char*, double>{"output.mass_drift", output.mass_drift},
                                   {"output.volume_drift", output.volume_drift},
                                   {"output.energy_growth", output.energy_growth}})
    if (!(value >= 0 && value <= 1e300)) fail(source, key, "expected a number >= 0, got " + fmt_num(value));
  bool position = false;
  for (const auto& a : output.attributes) position = position || a == "position";
  if (!position)
    fail(source, "output.attributes", "expected a list that includes \"position\" (a frame without positions is no frame), got " +
                                          std::to_string(output.attributes.size()) + " attributes without it");
  // Limits and the time-step floor: what can be known before the run.
  c.non_negative("limits.memory_gb", limits.memory_gb);
  if (limits.substeps_per_frame < 1)
    fail(source, "limits.substeps_per_frame", "expected an integer >= 1, got " + std::to_string(limits.substeps_per_frame));
  const double per_frame = double(limits.substeps_per_frame);
  if (frame_dt() / solver.max_dt > per_frame)
    fail(source, "solver.max_dt",
         fmt_num(solver.max_dt) + " s would take " + fmt_num(frame_dt() / solver.max_dt) + " substeps per frame of " +
             fmt_num(frame_dt()) + " s, more than limits.substeps_per_frame = " + std::to_string(limits.substeps_per_frame) +
             " (expected a larger solver.max_dt)");
  if (frame_dt() / elastic_dt() > per_frame)
    fail(source, "solver.elastic_cfl",
         "the elastic limit elastic_cfl dx / c = " + fmt_num(elastic_dt()) + " s would take " + fmt_num(frame_dt() / elastic_dt()) +
             " substeps per frame, more than limits.substeps_per_frame = " + std::to_string(limits.substeps_per_frame) +
             " (expected a larger solver.elastic_cfl or domain.dx, or a softer material)");
  for (std::size_t i = 0; i < output.attributes.size(); ++i) {
    const auto& a = output.attributes[i];
    const std::string p = "output.attributes[" + std::to_string(i) + "]";
    bool known = false;
    for (const auto& k : kAttributes) known = known || k == a;
    if (!known)
      fail(source, p, "expected one of \"position\", \"velocity\", \"material\", \"J\", \"plastic\", \"id\", got \"" + a + "\"");
    if (a == "id" && solver.type == SolverType::FEM)
      fail(source, p, "\"id\" (persistent particle ids) is written by solver.type \"mpm\" and \"flip\", not \"fem\" (its vertices keep their order)");
    for (std::size_t j = 0; j < i; ++j)
      if (output.attributes[j] == a) fail(source, p, "duplicate attribute \"" + a + "\"");
    if (a == "plastic") {
      bool any = false;
      for (const auto& m : materials) any = any || m.plasticity != PlasticModel::None;
      if (!any) fail(source, p, "\"plastic\" needs a material with plasticity; this scene has none");
    }
  }
  validate_pipeline_outputs();
}

void Scene::validate_pipeline_outputs() const {
  const auto has = [&](const char* a) { return std::find(output.attributes.begin(), output.attributes.end(), a) != output.attributes.end(); };
  for (std::size_t i = 0; i < output.surface.size(); ++i) {
    const auto& f = output.surface[i];
    const std::string p = "output.surface[" + std::to_string(i) + "]";
    if (f != "vdb" && f != "ply" && f != "obj") fail(source, p, "expected one of \"vdb\", \"ply\", \"obj\", got \"" + f + "\"");
    for (std::size_t j = 0; j < i; ++j)
      if (output.surface[j] == f) fail(source, p, "duplicate format \"" + f + "\"");
  }
  if (!output.surface.empty() && solver.dimension != 3)
    fail(source, "output.surface", "surfaces are made of 3D scenes only (solver.dimension is " + std::to_string(solver.dimension) + ")");
  if ((!output.surface.empty() || output.vdb_points) && solver.type == SolverType::FEM)
    fail(source, output.vdb_points ? "output.vdb_points" : "output.surface",
         "solver.type \"fem\" writes meshes, not particles: surfaces and VDB points are for \"mpm\" and \"flip\"");
  if (output.per_rank && (!output.surface.empty() || output.vdb_points))
    fail(source, "output.per_rank",
         std::string("per-rank frames hold part of the particles each, and ") +
             (output.vdb_points ? "output.vdb_points" : "output.surface") +
             " is made from whole frames: expected output.per_rank false, or no pipeline outputs (make them from the "
             "frames `slurry merge` joins, with `slurry surface`)");
  if (output.vdb_points && !(has("velocity") && has("id")))
    fail(source, "output.vdb_points", "the points carry velocity and a persistent id: expected \"velocity\" and \"id\" in output.attributes");
  if (!(output.surface_voxel_size >= 0 && output.surface_voxel_size <= 1e300))
    fail(source, "output.surface_voxel_size", "expected a length >= 0 (0: domain.dx), got " + fmt_num(output.surface_voxel_size));
  if (output.surface_voxel_size > 0 && (output.surface_voxel_size > 100 * domain.dx || output.surface_voxel_size < 0.01 * domain.dx))
    fail(source, "output.surface_voxel_size", "expected a length within [0.01, 100] x domain.dx (" + fmt_num(domain.dx) + "), got " +
                                                  fmt_num(output.surface_voxel_size));
  const double vdb_voxel = output.surface_voxel_size > 0 ? output.surface_voxel_size : domain.dx;
  if ((!output.surface.empty() || output.vdb_points) && !(vdb_voxel >= kMinVoxelSize))
    fail(source, output.surface_voxel_size > 0 ? "output.surface_voxel_size" : "domain.dx",
         "the voxel of the OpenVDB outputs is " + fmt_num(vdb_voxel) +
             " m, below the " + fmt_num(kMinVoxelSize) + " m OpenVDB can represent; expected a larger output.surface_voxel_size, or the scene in larger units");
  if (output.surface_smoothing < 0 || output.surface_smoothing > 100)
    fail(source, "output.surface_smoothing", "expected an integer in [0, 100], got " + std::to_string(output.surface_smoothing));
  // An MPM surface of some of the materials selects particles by the frame's material column.
  if (!output.surface.empty() && solver.type == SolverType::MPM && materials.size() > 1 && !has("material")) {
    std::size_t fluids = 0;
    for (const auto& m : materials) fluids += m.model == ElasticModel::Fluid;
    if (output.surface_per_material || (fluids > 0 && fluids < materials.size()))
      fail(source, "output.surface", "the surface is of some materials only (" +
                                         std::string(output.surface_per_material ? "output.surface_per_material" : "the \"fluid\" ones") +
                                         "): expected \"material\" in output.attributes");
  }
  if (!output.surface.empty() && solver.type == SolverType::FLIP && output.surface_per_material && materials.size() > 1 && !has("material"))
    fail(source, "output.surface_per_material", "one surface per material: expected \"material\" in output.attributes");
}

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
    if (r.has("quality")) quality_ppc = apply_quality(s, quality);
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
    // incompressible: density is its only parameter.
    if (s.solver.type == SolverType::FLIP) {
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
    r.number("mass_drift", s.output.mass_drift);
    r.number("volume_drift", s.output.volume_drift);
    r.number("energy_growth", s.output.energy_growth);
    r.integer("checkpoint_every", s.output.checkpoint_every, 0, std::numeric_limits<int>::max());
    r.boolean("per_rank", s.output.per_rank);
    r.strings("surface", s.output.surface);
    r.boolean("vdb_points", s.output.vdb_points);
    r.number("surface_voxel_size", s.output.surface_voxel_size);
    r.integer("surface_smoothing", s.output.surface_smoothing, -1000000, 1000000);
    r.boolean("surface_per_material", s.output.surface_per_material);
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

std::filesystem::path Scene::resolve(const std::string& file) const {
  const std::filesystem::path p(file);
  if (p.is_absolute()) return p;
  return std::filesystem::path(source).parent_path() / p;
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

double Scene::elastic_dt() const {
  if (solver.type != SolverType::MPM || solver.integrator == Integrator::Implicit) return std::numeric_limits<double>::infinity();
  double c = 0;
  for (const auto& m : materials) c = std::max(c, wave_speed(m));
  const double kernel_factor = solver.kernel == KernelKind::Linear ? 0.25 : 1.0;  // as Simulation::stable_dt
  return c > 0 ? kernel_factor * solver.elastic_cfl * domain.dx / c : std::numeric_limits<double>::infinity();
}

ResourceEstimate Scene::estimate() const {
  const int dim = solver.dimension;
  const bool fem = solver.type == SolverType::FEM, flip = solver.type == SolverType::FLIP;
  const double real = solver.precision == Precision::Double ? 8 : 4;
  ResourceEstimate e;
  for (const auto& b : bodies) {
    if (!b.mesh.empty()) continue;  // a mesh file's size bounds what reading it allocates
    Eigen::Vector3d lo, hi;
    double fill, lattice = 1;
    body_extent(b, dim, lo, hi, fill);
    const double h = fem ? domain.dx : domain.dx / std::pow(b.particles_per_cell, 1.0 / dim);
    for (int d = 0; d < dim; ++d) lattice *= std::max(1.0, std::round((hi[d] - lo[d]) / h));
    if (fem)
      e.elements += lattice * (dim == 3 ? 6 : 2);  // box_mesh: 6 tetrahedra per cube, 2 triangles per square
    else
      e.particles += lattice * fill;
  }
  double cells = 1, nodes = 1;
  for (int d = 0; d < dim; ++d) {
    const double n = std::ceil((domain.max[d] - domain.min[d]) / domain.dx - 1e-9);
    cells *= n;
    nodes *= n + 7;
  }
  const bool dense = domain.grid == GridKind::Dense || (domain.grid == GridKind::Auto && solver.integrator == Integrator::Implicit);
  // Bytes per item: rough upper bounds of the solvers' channels (position, velocity, mass,
  // volume, F, C and the stress, bins; FLIP face velocities, weights, pressure, PCG and
  // multigrid vectors; FEM element matrices and, implicit, the assembled stiffness).
  const double particle_bytes = real * (2 * dim + 2 + (flip ? dim * dim : 3 * dim * dim)) + 16;
  if (flip) e.grid_nodes = cells;
  else if (!fem && dense) e.grid_nodes = nodes;
  const double node_bytes = flip ? real * (3 * dim + 8) + 4 : real * (2 + 2 * dim) * (solver.integrator == Integrator::Implicit ? 4 : 1);
  const double element_bytes = 200 + (solver.integrator == Integrator::Implicit ? 12.0 * (dim + 1) * dim * (dim + 1) * dim : 0);
  e.bytes = e.particles * particle_bytes + e.grid_nodes * node_bytes + e.elements * element_bytes;
  return e;
}

double physical_memory_bytes() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? double(pages) * double(page) : 0;
}

void check_resources(const Scene& scene, double memory_gb) {
  const ResourceEstimate e = scene.estimate();
  const auto error = [&](const std::string& path, const std::string& what) {
    throw ResourceError(scene.source + ": " + path + ": " + what);
  };
  // Particle, vertex and element indices are 32-bit.
  if (e.particles > 2e9) error("bodies", "the bodies would seed " + fmt_num(e.particles) + " particles (limit 2e9); expected fewer or larger particles (particles_per_cell, domain.dx)");
  if (e.elements > 2e9) error("bodies", "the bodies would mesh " + fmt_num(e.elements) + " elements (limit 2e9); expected a larger domain.dx");
  std::string limit_name = "limits.memory_gb";
  double gb = memory_gb > 0 ? memory_gb : scene.limits.memory_gb;
  if (memory_gb > 0) limit_name = "--memory-limit";
  if (gb <= 0) {
    gb = physical_memory_bytes() / double(1 << 30);
    limit_name = "the machine's memory";
  }
  if (gb <= 0 || e.bytes <= gb * double(1 << 30)) return;
  const double p = e.particles, g = e.grid_nodes, m = e.elements;
  const std::string what = p >= g && p >= m ? fmt_num(p) + " particles seeded by the bodies"
                           : g >= m         ? fmt_num(g) + (scene.solver.type == SolverType::FLIP ? " grid cells" : " dense grid nodes")
                                            : fmt_num(m) + " mesh elements";
  char size[64];
  std::snprintf(size, sizeof size, "%.3g GiB, more than %.3g GiB (", e.bytes / double(1 << 30), gb);
  error(p >= g && p >= m ? "bodies" : g >= m ? "domain.dx" : "bodies",
        "the run would need about " + std::string(size) + limit_name + ") for " + what +
            "; expected a smaller scene, or raise the limit with limits.memory_gb or --memory-limit");
}

}  // namespace slurry
