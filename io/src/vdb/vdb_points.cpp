// OpenVDB points (surface.h): a PointDataGrid with P, v, id and pscale. One translation unit
// for OpenVDB's points headers, which are slow to compile.
#include <openvdb/openvdb.h>
#include <openvdb/points/PointAttribute.h>
#include <openvdb/points/PointConversion.h>
#include <openvdb/points/PointCount.h>
#include <openvdb/points/PointDataGrid.h>
#include <openvdb/tools/PointIndexGrid.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "slurry/engine/errors.h"
#include "slurry/io/surface.h"
#include "vdb/vdb_common.h"

namespace slurry::io {

void write_vdb_points(const std::filesystem::path& path, const PointCloud& points, double radius,
                      double voxel_size) {
  namespace vp = openvdb::points;
  if (!(voxel_size > 0) || !std::isfinite(voxel_size))
    throw IoError(path.string() + ": VDB points need a voxel size > 0, got " +
                  std::to_string(voxel_size));
  const std::size_t n = points.size();
  if (!points.velocity.empty() && points.velocity.size() != n)
    throw IoError(path.string() + ": " + std::to_string(points.velocity.size()) +
                  " velocities for " + std::to_string(n) + " points");
  if (!points.id.empty() && points.id.size() != n)
    throw IoError(path.string() + ": " + std::to_string(points.id.size()) + " ids for " +
                  std::to_string(n) + " points");
  detail::initialize_openvdb();

  std::vector<openvdb::Vec3R> position(n);
  for (std::size_t i = 0; i < n; ++i)
    position[i] =
        openvdb::Vec3R(points.position[i][0], points.position[i][1], points.position[i][2]);
  const vp::PointAttributeVector<openvdb::Vec3R> position_list(position);
  const openvdb::math::Transform::Ptr xform =
      openvdb::math::Transform::createLinearTransform(voxel_size);
  const auto index =
      openvdb::tools::createPointIndexGrid<openvdb::tools::PointIndexGrid>(position_list, *xform);
  vp::PointDataGrid::Ptr grid =
      vp::createPointDataGrid<vp::NullCodec, vp::PointDataGrid>(*index, position_list, *xform);
  grid->setName("points");

  if (!points.velocity.empty()) {
    std::vector<openvdb::Vec3f> v(n);
    for (std::size_t i = 0; i < n; ++i)
      v[i] = openvdb::Vec3f(points.velocity[i][0], points.velocity[i][1], points.velocity[i][2]);
    vp::appendAttribute<openvdb::Vec3f>(grid->tree(), "v");
    vp::populateAttribute(grid->tree(), index->tree(), "v",
                          vp::PointAttributeVector<openvdb::Vec3f>(v));
  }
  if (!points.id.empty()) {
    // int32, the type Houdini gives "id"; the engine's particle counts stay below 2^31.
    std::vector<std::int32_t> id(n);
    for (std::size_t i = 0; i < n; ++i) {
      if (points.id[i] > std::uint32_t(std::numeric_limits<std::int32_t>::max()))
        throw IoError(path.string() + ": particle id " + std::to_string(points.id[i]) +
                      " does not fit the int32 \"id\" attribute");
      id[i] = std::int32_t(points.id[i]);
    }
    vp::appendAttribute<std::int32_t>(grid->tree(), "id");
    vp::populateAttribute(grid->tree(), index->tree(), "id",
                          vp::PointAttributeVector<std::int32_t>(id));
  }
  if (!points.type.empty()) {
    if (points.type.size() != n)
      throw IoError(path.string() + ": " + std::to_string(points.type.size()) + " types for " + std::to_string(n) + " points");
    const std::vector<std::int32_t> type(points.type.begin(), points.type.end());
    vp::appendAttribute<std::int32_t>(grid->tree(), "type");
    vp::populateAttribute(grid->tree(), index->tree(), "type", vp::PointAttributeVector<std::int32_t>(type));
  }
  vp::appendAttribute<float>(grid->tree(), "pscale", float(radius));
  detail::write_grids_atomically(path, openvdb::GridPtrVec{grid});
}

PointCloud read_vdb_points(const std::filesystem::path& path, std::vector<float>* pscale,
                           const std::string& name) {
  namespace vp = openvdb::points;
  openvdb::GridBase::Ptr base = detail::read_grid(path, name);
  vp::PointDataGrid::Ptr grid = openvdb::gridPtrCast<vp::PointDataGrid>(base);
  if (!grid)
    throw IoError(path.string() + ": grid \"" + name + "\" is a " + base->type() +
                  ", expected a PointDataGrid");
  PointCloud cloud;
  std::vector<float> radius;
  auto leaf = grid->tree().cbeginLeaf();
  if (!leaf) return cloud;
  const auto& descriptor = leaf->attributeSet().descriptor();
  const std::size_t P = descriptor.find("P"), v = descriptor.find("v"), id = descriptor.find("id"),
                    ps = descriptor.find("pscale"), ty = descriptor.find("type");
  if (P == vp::AttributeSet::INVALID_POS)
    throw IoError(path.string() + ": the points have no \"P\" attribute");
  const bool has_v = v != vp::AttributeSet::INVALID_POS,
             has_id = id != vp::AttributeSet::INVALID_POS,
             has_ps = ps != vp::AttributeSet::INVALID_POS,
             has_type = ty != vp::AttributeSet::INVALID_POS;
  for (; leaf; ++leaf) {
    vp::AttributeHandle<openvdb::Vec3f> hp(leaf->constAttributeArray(P));
    std::unique_ptr<vp::AttributeHandle<openvdb::Vec3f>> hv;
    std::unique_ptr<vp::AttributeHandle<std::int32_t>> hid;
    std::unique_ptr<vp::AttributeHandle<float>> hps;
    std::unique_ptr<vp::AttributeHandle<std::int32_t>> hty;
    if (has_v)
      hv = std::make_unique<vp::AttributeHandle<openvdb::Vec3f>>(leaf->constAttributeArray(v));
    if (has_id)
      hid = std::make_unique<vp::AttributeHandle<std::int32_t>>(leaf->constAttributeArray(id));
    if (has_ps) hps = std::make_unique<vp::AttributeHandle<float>>(leaf->constAttributeArray(ps));
    if (has_type) hty = std::make_unique<vp::AttributeHandle<std::int32_t>>(leaf->constAttributeArray(ty));
    for (auto it = leaf->beginIndexOn(); it; ++it) {
      const openvdb::Vec3d w =
          grid->transform().indexToWorld(hp.get(*it) + it.getCoord().asVec3d());
      cloud.position.push_back({float(w[0]), float(w[1]), float(w[2])});
      if (hv) {
        const openvdb::Vec3f u = hv->get(*it);
        cloud.velocity.push_back({u[0], u[1], u[2]});
      }
      if (hid) cloud.id.push_back(std::uint32_t(hid->get(*it)));
      if (hps) radius.push_back(hps->get(*it));
      if (hty) cloud.type.push_back(std::uint8_t(std::clamp(hty->get(*it), 0, 255)));
    }
  }
  if (has_id) {  // back to id order
    std::vector<std::size_t> order(cloud.size());
    std::iota(order.begin(), order.end(), std::size_t(0));
    std::sort(order.begin(), order.end(),
              [&](std::size_t a, std::size_t b) { return cloud.id[a] < cloud.id[b]; });
    PointCloud sorted;
    std::vector<float> sorted_radius;
    for (std::size_t i : order) {
      sorted.position.push_back(cloud.position[i]);
      if (has_v) sorted.velocity.push_back(cloud.velocity[i]);
      sorted.id.push_back(cloud.id[i]);
      if (has_type) sorted.type.push_back(cloud.type[i]);
      if (has_ps) sorted_radius.push_back(radius[i]);
    }
    cloud = std::move(sorted);
    radius = std::move(sorted_radius);
  }
  if (pscale) *pscale = std::move(radius);
  return cloud;
}

}  // namespace slurry::io
