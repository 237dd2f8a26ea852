#pragma once
/// \file names.h
/// The words a scene file uses for each enumeration of scene.h ("apic", "fixed_corotated",
/// "half_space"...), in one table per enumeration, for the scene reader, to_string() and
/// messages that list the choices.
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "slurry/engine/scene/scene.h"

namespace slurry::scene_names {

template <class E>
using NameTable = std::vector<std::pair<std::string_view, E>>;

inline const NameTable<Precision> kPrecision{{"float", Precision::Float}, {"double", Precision::Double}};
inline const NameTable<TransferKind> kTransfer{{"pic", TransferKind::PIC},
                                        {"flip", TransferKind::FLIP},
                                        {"apic", TransferKind::APIC},
                                        {"mls", TransferKind::MLS}};
inline const NameTable<KernelKind> kKernel{
    {"linear", KernelKind::Linear}, {"quadratic", KernelKind::Quadratic}, {"cubic", KernelKind::Cubic}};
inline const NameTable<Integrator> kIntegrator{{"explicit", Integrator::Explicit}, {"implicit", Integrator::Implicit}};
inline const NameTable<ImplicitPreconditioner> kImplicitPreconditioner{{"jacobi", ImplicitPreconditioner::Jacobi},
                                                                {"block_jacobi", ImplicitPreconditioner::BlockJacobi},
                                                                {"ic0", ImplicitPreconditioner::IC0}};
inline const NameTable<SolverType> kSolverType{{"mpm", SolverType::MPM}, {"flip", SolverType::FLIP}, {"fem", SolverType::FEM}};
inline const NameTable<ElasticModel> kElastic{{"corotated_linear", ElasticModel::CorotatedLinear},
                                       {"fixed_corotated", ElasticModel::FixedCorotated},
                                       {"neo_hookean", ElasticModel::NeoHookean},
                                       {"stvk", ElasticModel::StVK},
                                       {"hencky_stvk", ElasticModel::HenckyStVK},
                                       {"fluid", ElasticModel::Fluid}};
inline const NameTable<PlasticModel> kPlastic{{"none", PlasticModel::None},
                                       {"snow", PlasticModel::Snow},
                                       {"drucker_prager", PlasticModel::DruckerPrager},
                                       {"von_mises", PlasticModel::VonMises}};
inline const NameTable<Shape> kShape{
    {"box", Shape::Box}, {"sphere", Shape::Sphere}, {"cylinder", Shape::Cylinder}, {"mesh", Shape::Mesh}};
inline const NameTable<Sampling> kSampling{{"regular", Sampling::Regular}, {"jittered", Sampling::Jittered}};
inline const NameTable<ColliderShape> kColliderShape{{"half_space", ColliderShape::HalfSpace},
                                              {"box", ColliderShape::Box},
                                              {"sphere", ColliderShape::Sphere},
                                              {"mesh", ColliderShape::Mesh}};
inline const NameTable<Condition> kCondition{
    {"sticky", Condition::Sticky}, {"slip", Condition::Slip}, {"separate", Condition::Separate}};
inline const NameTable<GridKind> kGrid{{"auto", GridKind::Auto}, {"sparse", GridKind::Sparse}, {"dense", GridKind::Dense}};
inline const NameTable<PlyEncoding> kEncoding{{"binary", PlyEncoding::Binary}, {"ascii", PlyEncoding::Ascii}};
inline const NameTable<AdvectionScheme> kAdvection{{"euler", AdvectionScheme::Euler},
                                            {"midpoint", AdvectionScheme::Midpoint},
                                            {"heun", AdvectionScheme::Heun},
                                            {"rk3", AdvectionScheme::RK3}};
inline const NameTable<FreeSurface> kFreeSurface{
    {"auto", FreeSurface::Auto}, {"cell", FreeSurface::Cell}, {"subcell", FreeSurface::Subcell}};
inline const NameTable<PressurePreconditioner> kPreconditioner{{"multigrid", PressurePreconditioner::Multigrid},
                                                        {"mic0", PressurePreconditioner::MIC0},
                                                        {"jacobi", PressurePreconditioner::Jacobi},
                                                        {"none", PressurePreconditioner::None}};
inline const NameTable<OnInstability> kOnInstability{{"stop", OnInstability::Stop}, {"retry", OnInstability::Retry}};
/// The values output.attributes may list.
inline const std::vector<std::string> kAttributes{"position", "velocity", "material", "J", "plastic", "id"};

template <class E>
inline std::string_view name_of(const NameTable<E>& table, E value) {
  for (const auto& [name, v] : table)
    if (v == value) return name;
  return "?";
}

template <class E>
inline std::string choices(const NameTable<E>& table) {
  std::string s;
  for (const auto& [name, v] : table) s += (s.empty() ? "\"" : ", \"") + std::string(name) + "\"";
  return s;
}


}  // namespace slurry::scene_names
