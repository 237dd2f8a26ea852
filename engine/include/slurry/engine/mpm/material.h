#pragma once
/// \file material.h
/// A scene material turned into constitutive value types: an elastic model (one of the
/// constitutive/ models, held in a std::variant and visited once per particle range, never per
/// particle) and an optional plastic return mapping. Lame parameters come from E and nu;
/// the elastic wave speed sqrt((lambda + 2 mu) / rho) (sqrt(K / rho) for fluids) bounds the
/// explicit time step.
#include <Eigen/Core>
#include <cmath>
#include <variant>

#include "slurry/constitutive/corotated_linear.h"
#include "slurry/constitutive/fixed_corotated.h"
#include "slurry/constitutive/fluid.h"
#include "slurry/constitutive/hencky_stvk.h"
#include "slurry/constitutive/lame.h"
#include "slurry/constitutive/neo_hookean.h"
#include "slurry/constitutive/plasticity.h"
#include "slurry/constitutive/stvk.h"
#include "slurry/engine/scene/scene.h"

namespace slurry {

template <class T, int Dim>
struct Material {
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  using Fluid = constitutive::WeaklyCompressibleFluid<T, Dim>;
  using Elastic = std::variant<constitutive::CorotatedLinear<T, Dim>, constitutive::FixedCorotated<T, Dim>,
                               constitutive::NeoHookean<T, Dim>, constitutive::StVenantKirchhoff<T, Dim>,
                               constitutive::HenckyStVK<T, Dim>, Fluid>;

  Elastic elastic;
  PlasticModel plastic_kind = PlasticModel::None;
  constitutive::SnowPlasticity<T> snow{};
  constitutive::DruckerPrager<T> drucker_prager{};
  constitutive::VonMises<T> von_mises{};
  bool fluid = false;
  T density = 1;
  T mu = 0, lambda = 0;
  T base_wave_speed = 0;  ///< at the material's own stiffness
  T wave_speed = 0;       ///< including snow hardening seen so far

  /// fn(model) with the concrete elastic model.
  template <class Fn>
  void visit_elastic(Fn&& fn) const {
    std::visit(std::forward<Fn>(fn), elastic);
  }
  const Fluid& fluid_model() const { return std::get<Fluid>(elastic); }

  /// Stiffness multiplier of snow at plastic volume ratio Jp (1 for other materials).
  T hardening_factor(T Jp) const {
    return plastic_kind == PlasticModel::Snow ? snow.hardening_factor(Jp) : T(1);
  }
  /// Starting value of the plastic channel: Jp = 1 for snow, 0 accumulated strain otherwise.
  T initial_plastic_state() const { return plastic_kind == PlasticModel::Snow ? T(1) : T(0); }

  /// Projects the elastic deformation gradient back to the yield surface; returns whether it
  /// changed F.
  bool project(Mat& F, T& state) const {
    switch (plastic_kind) {
      case PlasticModel::Snow: return snow.project(F, state);
      case PlasticModel::DruckerPrager: return drucker_prager.project(F, state, mu, lambda);
      case PlasticModel::VonMises: return von_mises.project(F, state, mu);
      case PlasticModel::None: break;
    }
    return false;
  }
};

/// Builds the constitutive objects for a validated MaterialParams.
template <class T, int Dim>
Material<T, Dim> make_material(const MaterialParams& p) {
  Material<T, Dim> m;
  m.density = T(p.density);
  m.plastic_kind = p.plasticity;
  if (p.model == ElasticModel::Fluid) {
    m.fluid = true;
    m.elastic = typename Material<T, Dim>::Fluid{T(p.bulk_modulus), T(p.gamma)};
    m.base_wave_speed = T(std::sqrt(p.bulk_modulus / p.density));
  } else {
    const auto l = constitutive::lame_from_young<double>(p.E, p.nu);
    m.mu = T(l.mu);
    m.lambda = T(l.lambda);
    switch (p.model) {
      case ElasticModel::CorotatedLinear: m.elastic = constitutive::CorotatedLinear<T, Dim>{m.mu, m.lambda}; break;
      case ElasticModel::FixedCorotated: m.elastic = constitutive::FixedCorotated<T, Dim>{m.mu, m.lambda}; break;
      case ElasticModel::NeoHookean: m.elastic = constitutive::NeoHookean<T, Dim>{m.mu, m.lambda}; break;
      case ElasticModel::StVK: m.elastic = constitutive::StVenantKirchhoff<T, Dim>{m.mu, m.lambda}; break;
      case ElasticModel::HenckyStVK: m.elastic = constitutive::HenckyStVK<T, Dim>{m.mu, m.lambda}; break;
      case ElasticModel::Fluid: break;
    }
    m.base_wave_speed = T(std::sqrt((l.lambda + 2 * l.mu) / p.density));
  }
  m.wave_speed = m.base_wave_speed;
  m.snow.critical_compression = T(p.critical_compression);
  m.snow.critical_stretch = T(p.critical_stretch);
  m.snow.hardening = T(p.hardening);
  m.drucker_prager.friction_angle = T(p.friction_angle);
  m.von_mises.yield_stress = T(p.yield_stress);
  return m;
}

}  // namespace slurry
