// DistanceField: the store of surfels and returns by sub-map (replaced region by region, with
// their normals refitted), its statistics and its persistence. The query kernels are in
// distance_field_query.cc.
#include "rim/map/distance_field.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <mutex>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/map/distance_field_part.h"

namespace rim {
namespace {
using distance_field_internal::Dot;
using distance_field_internal::Tree;
}  // namespace

DistanceField::DistanceField(const MapGeometry& geometry, float surfel_radius_m)
    : geometry_(geometry), radius_(surfel_radius_m) {}

DistanceField::~DistanceField() = default;

uint32_t DistanceField::VoxelIndex(const Int3& key, const Int3& g) const {
  const Int3 c = geometry_.cells(0);
  const Int3 l = g - key.cwiseProduct(c);
  return (uint32_t(l.x()) * uint32_t(c.y()) + uint32_t(l.y())) * uint32_t(c.z()) + uint32_t(l.z());
}

Int3 DistanceField::VoxelOf(const Int3& key, uint32_t index) const {
  const Int3 c = geometry_.cells(0);
  const int z = int(index % uint32_t(c.z()));
  index /= uint32_t(c.z());
  const int y = int(index % uint32_t(c.y()));
  const int x = int(index / uint32_t(c.y()));
  return key.cwiseProduct(c) + Int3(x, y, z);
}

DistanceField::PartPtr DistanceField::MakePart(std::vector<Surfel> surfels, float radius,
                                               float blend_radius) {
  return std::make_shared<const Part>(std::move(surfels), radius, blend_radius);
}

void DistanceField::FitNormals(const Int3& key, std::vector<Surfel>* surfels) const {
  // Positions on the zero level are accurate to millimetres; the field's gradient is not as
  // good a normal (it tilts where the field is steep or curved). A plane through the surfels of
  // the 3×3×3 voxels around a fresh one gives its normal where they are planar; the field's
  // normal orients it, and stays where the neighbourhood is not a plane (edges, thin parts).
  std::vector<Surfel>& s = *surfels;
  // The surfels are sorted by voxel index, (x·Cy + y)·Cz + z within the sub-map: a column of
  // neighbours (fixed x and y offsets, z − 1 … z + 1) is a run of consecutive indices. Fresh
  // surfels are visited in index order, so the lowest neighbour index of each of the 9 columns
  // only grows; a cursor per column follows it through the array, with no lookups.
  const Int3 c = geometry_.cells(0);
  const size_t total = s.size();
  const double leaf = geometry_.leaf_m();
  auto index_at = [&](size_t i) { return s[i].voxel & ~kFresh; };
  size_t cursor[9] = {};
  for (Surfel& x : s) {
    if (!(x.voxel & kFresh)) continue;
    x.voxel &= ~kFresh;
    const Int3 g = VoxelOf(key, x.voxel) - key.cwiseProduct(c);  // within the sub-map
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    Eigen::Matrix3d second = Eigen::Matrix3d::Zero();
    int count = 0;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy) {
        const int hx = g.x() + dx, hy = g.y() + dy;
        if (hx < 0 || hx >= c.x() || hy < 0 || hy >= c.y()) continue;
        const uint32_t column = (uint32_t(hx) * uint32_t(c.y()) + uint32_t(hy)) * uint32_t(c.z());
        const uint32_t first = column + uint32_t(std::max(g.z() - 1, 0));
        size_t& at = cursor[(dx + 1) * 3 + (dy + 1)];
        while (at < total && index_at(at) < first) ++at;
        size_t k = at;
        for (int dz = -1; dz <= 1; ++dz) {
          const int hz = g.z() + dz;
          if (hz < 0 || hz >= c.z()) continue;
          const uint32_t target = column + uint32_t(hz);
          while (k < total && index_at(k) < target) ++k;
          if (k == total || index_at(k) != target) continue;
          const Eigen::Vector3d p(s[k].p[0], s[k].p[1], s[k].p[2]);
          mean += p;
          second += p * p.transpose();
          ++count;
        }
      }
    if (count < 5) continue;
    mean /= count;
    const Eigen::Matrix3d cov = second / count - mean * mean.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
    eig.computeDirect(cov);
    const Eigen::Vector3d ev = eig.eigenvalues();  // ascending
    // Planar: thin across (within a few millimetres) and spread along two directions.
    if (!(ev[0] < 1e-5 && ev[1] > 0.1 * leaf * leaf * 0.5)) continue;
    Eigen::Vector3d n = eig.eigenvectors().col(0);
    const Eigen::Vector3d field(x.n[0], x.n[1], x.n[2]);
    if (n.dot(field) < 0) n = -n;
    // A fit far from the field's own normal is two surfaces meeting, not a plane.
    if (n.dot(field) < 0.7) continue;
    for (int a = 0; a < 3; ++a) x.n[a] = float(n[a]);
  }
}

void DistanceField::Replace(const Int3& key, const std::vector<IntBox>& regions,
                            std::vector<Surfel> fresh) {
  for (Surfel& s : fresh) s.voxel |= kFresh;
  PartPtr old;
  {
    std::shared_lock<std::shared_mutex> lock(mu_);
    auto it = parts_.find(key);
    if (it != parts_.end()) old = it->second;
  }
  if (old && !regions.empty()) {
    // Kept: the old surfels outside the regions, appended with no spare capacity (the part keeps
    // this vector).
    std::vector<uint32_t> kept;
    for (uint32_t i = 0; i < uint32_t(old->surfels.size()); ++i) {
      const Int3 g = VoxelOf(key, old->surfels[i].voxel);
      bool inside = false;
      for (const IntBox& b : regions) inside = inside || b.Contains(g);
      if (!inside) kept.push_back(i);
    }
    fresh.reserve(fresh.size() + kept.size());
    for (uint32_t i : kept) fresh.push_back(old->surfels[i]);
  }
  // A fixed order, whatever order the regions were extracted in: saved bytes and tree layout
  // depend on the map alone.
  std::sort(fresh.begin(), fresh.end(), [](const Surfel& a, const Surfel& b) {
    return (a.voxel & ~kFresh) < (b.voxel & ~kFresh);
  });
  FitNormals(key, &fresh);
  PartPtr part = fresh.empty() ? nullptr : MakePart(std::move(fresh), radius_, radius_);
  std::unique_lock<std::shared_mutex> lock(mu_);
  if (part)
    parts_[key] = std::move(part);
  else
    parts_.erase(key);
}

void DistanceField::ReplaceReturns(const Int3& key, std::vector<Surfel> returns) {
  PartPtr part = returns.empty() ? nullptr : MakePart(std::move(returns), 0.f, returns_blend_);
  std::unique_lock<std::shared_mutex> lock(mu_);
  if (part)
    returns_[key] = std::move(part);
  else
    returns_.erase(key);
}

std::shared_ptr<const std::vector<Surfel>> DistanceField::Surfels(const Int3& key) const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  auto it = parts_.find(key);
  if (it == parts_.end()) return nullptr;
  return std::shared_ptr<const std::vector<Surfel>>(it->second, &it->second->surfels);
}

void DistanceField::Clear() {
  std::unique_lock<std::shared_mutex> lock(mu_);
  parts_.clear();
  returns_.clear();
}

DistanceFieldStats DistanceField::Stats() const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  DistanceFieldStats st;
  auto bytes = [](const Part& part) {
    return int64_t(part.surfels.capacity() * sizeof(Surfel) +
                   const_cast<Tree&>(part.tree).usedMemory(const_cast<Tree&>(part.tree)));
  };
  for (const auto& [key, part] : parts_) {
    st.surfels += int64_t(part->surfels.size());
    st.bytes += bytes(*part);
    ++st.submaps;
  }
  for (const auto& [key, part] : returns_) {
    st.returns += int64_t(part->surfels.size());
    st.bytes += bytes(*part);
  }
  return st;
}

void DistanceField::WriteParts(const std::map<Int3, PartPtr, KeyLess>& parts, ByteWriter* w) {
  w->U64(parts.size());
  for (const auto& [key, part] : parts) {
    for (int a = 0; a < 3; ++a) w->I32(key[a]);
    w->PodVector(part->surfels);
  }
}

void DistanceField::Serialize(ByteWriter* w) const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  w->F32(radius_);
  WriteParts(parts_, w);
}

absl::Status DistanceField::Deserialize(ByteReader* r) {
  float radius;
  uint64_t count;
  RIM_RETURN_IF_ERROR(r->F32(&radius));
  if (radius != radius_)
    return absl::DataLossError(
        absl::StrCat("surfel radius ", radius, " m, the config gives ", radius_));
  RIM_RETURN_IF_ERROR(r->U64(&count));
  if (count > r->remaining() / 20)
    return absl::DataLossError(absl::StrCat(count, " sub-maps do not fit in the file"));
  const Int3 cells = geometry_.cells(0);
  const uint64_t voxels = uint64_t(cells.x()) * cells.y() * cells.z();
  const double leaf = geometry_.leaf_m();
  std::map<Int3, PartPtr, KeyLess> parts;
  for (uint64_t k = 0; k < count; ++k) {
    Int3 key;
    for (int a = 0; a < 3; ++a) RIM_RETURN_IF_ERROR(r->I32(&key[a]));
    if ((key.cwiseAbs().array() > (1 << 20)).any() || parts.count(key))
      return absl::DataLossError(absl::StrCat("sub-map ", k, " has a bad or repeated key"));
    std::vector<Surfel> surfels;
    RIM_RETURN_IF_ERROR(r->PodVector(&surfels));
    for (size_t i = 0; i < surfels.size(); ++i) {
      const Surfel& s = surfels[i];
      bool ok = s.voxel < voxels && (i == 0 || surfels[i - 1].voxel <= s.voxel);
      const float n2 = Dot(s.n, s.n);
      ok = ok && std::isfinite(n2) && std::abs(n2 - 1.f) < 1e-3f;
      if (ok) {
        const Int3 g = VoxelOf(key, s.voxel);
        for (int a = 0; a < 3; ++a)
          ok = ok && std::isfinite(s.p[a]) && s.p[a] >= (g[a] - 1) * leaf &&
               s.p[a] <= (g[a] + 2) * leaf;
      }
      if (!ok)
        return absl::DataLossError(absl::StrCat("surfel ", i, " of sub-map (", key.x(), ",",
                                                key.y(), ",", key.z(), ") is out of order, ",
                                                "outside its voxel or not finite"));
    }
    if (!surfels.empty()) parts[key] = MakePart(std::move(surfels), radius_, radius_);
  }
  std::unique_lock<std::shared_mutex> lock(mu_);
  parts_ = std::move(parts);
  return absl::OkStatus();
}

void DistanceField::SerializeReturns(ByteWriter* w) const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  WriteParts(returns_, w);
}

absl::Status DistanceField::DeserializeReturns(ByteReader* r) {
  uint64_t count;
  RIM_RETURN_IF_ERROR(r->U64(&count));
  if (count > r->remaining() / 20)
    return absl::DataLossError(absl::StrCat(count, " sub-maps of returns do not fit in the file"));
  std::map<Int3, PartPtr, KeyLess> parts;
  for (uint64_t k = 0; k < count; ++k) {
    Int3 key;
    for (int a = 0; a < 3; ++a) RIM_RETURN_IF_ERROR(r->I32(&key[a]));
    if ((key.cwiseAbs().array() > (1 << 20)).any() || parts.count(key))
      return absl::DataLossError(
          absl::StrCat("returns of sub-map ", k, " have a bad or repeated key"));
    std::vector<Surfel> returns;
    RIM_RETURN_IF_ERROR(r->PodVector(&returns));
    for (size_t i = 0; i < returns.size(); ++i) {
      const Surfel& s = returns[i];
      const float n2 = Dot(s.n, s.n);
      bool ok = (i == 0 || returns[i - 1].voxel < s.voxel) && std::isfinite(n2) &&
                std::abs(n2 - 1.f) < 1e-3f;
      for (int a = 0; a < 3; ++a) ok = ok && std::isfinite(s.p[a]);
      if (!ok)
        return absl::DataLossError(absl::StrCat("return ", i, " of sub-map (", key.x(), ",",
                                                key.y(), ",", key.z(),
                                                ") is out of order or not finite"));
    }
    if (!returns.empty()) parts[key] = MakePart(std::move(returns), 0.f, returns_blend_);
  }
  std::unique_lock<std::shared_mutex> lock(mu_);
  returns_ = std::move(parts);
  return absl::OkStatus();
}

}  // namespace rim
