// Mapper: keeping the metric distance field (map/distance_field.h) up to the map: when a refresh
// is due, which voxels it re-extracts, the surfels found by Newton steps onto the network's zero
// level, and the deferred returns.
#include <algorithm>
#include <cmath>
#include <memory>
#include <mutex>
#include <vector>

#include "rim/base/worker_pool.h"
#include "rim/map/deferred_points.h"
#include "rim/map/distance_field.h"
#include "rim/map/local_map.h"
#include "rim/map/slab_saver.h"
#include "rim/map/submap_store.h"
#include "rim/mapper.h"
#include "rim/mapper_internal.h"
#include "rim/mesh/mesher.h"
#include "rim/model/encoder.h"

namespace rim {
using mapper_internal::Now;

std::vector<Int3> Mapper::RefreshVoxels(const Int3& key, const std::vector<IntBox>& regions) const {
  const MeshTileSource src{*geometry_, *local_map_, *store_, *decoder_, mu_};
  std::vector<Int3> voxels = rim::ObservedVoxels(src, key);
  if (!regions.empty()) {
    voxels.erase(std::remove_if(voxels.begin(), voxels.end(),
                                [&](const Int3& g) {
                                  for (const IntBox& b : regions)
                                    if (b.Contains(g)) return false;
                                  return true;
                                }),
                 voxels.end());
  }
  return voxels;
}

void Mapper::ExtractSurfels(const Int3& key, const std::vector<Int3>& voxels, size_t begin,
                            size_t m, const std::vector<Surfel>* before,
                            std::vector<Surfel>* out) const {
  const double s = geometry_->leaf_m();
  // Newton steps onto the zero level, p ← p − f ∇f / |∇f|². A voxel that held a surfel starts
  // from it: the level moves millimetres between refreshes, so one step lands on it, and the
  // voxel keeps the point when that step was short. Any other voxel, and one whose step from its
  // old surfel was long, starts from its centre and takes two steps, the second from where the
  // first landed. Either way the voxel keeps the point when it lies in it (with a hair of slack)
  // and the last step was short.
  enum Stage : uint8_t { kFromSurfel, kFirst, kSecond, kDone, kDropped };
  std::vector<float> p(3 * m), f(m), g(3 * m);
  std::vector<uint8_t> stage(m, kFirst);
  std::vector<uint8_t> from_centre(m, 1);  // whether the voxel's steps started at its centre
  std::vector<float> old_n(3 * m);
  auto centre = [&](size_t i) {
    for (int a = 0; a < 3; ++a) p[3 * i + a] = float((voxels[begin + i][a] + 0.5) * s);
  };
  for (size_t i = 0; i < m; ++i) {
    centre(i);
    if (!before) continue;
    const uint32_t index = distance_->VoxelIndex(key, voxels[begin + i]);
    auto it = std::lower_bound(before->begin(), before->end(), index,
                               [](const Surfel& x, uint32_t v) { return x.voxel < v; });
    if (it == before->end() || it->voxel != index) continue;
    for (int a = 0; a < 3; ++a) p[3 * i + a] = it->p[a];
    for (int a = 0; a < 3; ++a) old_n[3 * i + a] = it->n[a];
    stage[i] = kFromSurfel;
    from_centre[i] = 0;
  }
  std::vector<size_t> live;
  std::vector<float> q, fv, gv;
  while (true) {
    live.clear();
    for (size_t i = 0; i < m; ++i)
      if (stage[i] < kDone) live.push_back(i);
    if (live.empty()) break;
    q.resize(3 * live.size());
    fv.resize(live.size());
    gv.resize(3 * live.size());
    for (size_t k = 0; k < live.size(); ++k)
      for (int a = 0; a < 3; ++a) q[3 * k + a] = p[3 * live[k] + a];
    EvalNeural(q.data(), live.size(), fv.data(), gv.data(), nullptr);
    for (size_t k = 0; k < live.size(); ++k) {
      const size_t i = live[k];
      const float* gk = &gv[3 * k];
      const float g2 = gk[0] * gk[0] + gk[1] * gk[1] + gk[2] * gk[2];
      // The Newton step's length |f| / |∇f| (the field's slope is not 1: along-ray labels
      // steepen it where rays graze a surface): a surface farther than the voxel's half
      // diagonal from its centre does not cross it.
      const float len = std::sqrt(std::max(g2, 1e-12f));
      const float step_m = std::abs(fv[k]) / len;
      bool ok = g2 > 0.01f && step_m <= (stage[i] == kFirst ? 0.9 : 0.5) * s;
      if (stage[i] == kFromSurfel) {
        // Only where the level barely moved (a quarter voxel) and did not turn (26°): a voxel
        // whose field changes more goes back to the centre's two steps, which decide again
        // whether the level crosses it. Without these bounds gradients at 0.1–2 m came out
        // worse on the dev city (BENCHMARK.md, "A cheaper distance refresh").
        const float* n = &old_n[3 * i];
        ok = ok && step_m <= 0.25 * s && (gk[0] * n[0] + gk[1] * n[1] + gk[2] * n[2]) >= 0.9f * len;
      }
      if (!ok) {
        if (stage[i] == kFromSurfel) {
          stage[i] = kFirst;
          from_centre[i] = 1;
          centre(i);
        } else {
          stage[i] = kDropped;
        }
        continue;
      }
      f[i] = fv[k];
      for (int a = 0; a < 3; ++a) {
        g[3 * i + a] = gk[a];
        p[3 * i + a] -= fv[k] * gk[a] / g2;
      }
      stage[i] = stage[i] == kFirst ? kSecond : kDone;
    }
  }
  for (size_t i = 0; i < m; ++i)
    if (stage[i] == kDone) live.push_back(i);
  // Where the two steps from the centre ended, the field must be at its zero level: Newton steps
  // also come to rest in a dip of the field that stays above zero, such as what is left where
  // a person stood once the network has learnt the free space there (a dip 13 cm above zero
  // read as surface 0.5 m from planner points on seed 706's crossing line). One more SDF-only
  // evaluation, for those voxels only (one that kept its surfel came within a quarter voxel of
  // it): the value must be within a tenth of a voxel of zero at the slope of the last step.
  {
    std::vector<size_t> check;
    for (size_t i : live)
      if (from_centre[i]) check.push_back(i);
    q.resize(3 * check.size());
    fv.resize(check.size());
    for (size_t k = 0; k < check.size(); ++k)
      for (int a = 0; a < 3; ++a) q[3 * k + a] = p[3 * check[k] + a];
    if (!check.empty()) EvalNeural(q.data(), check.size(), fv.data(), nullptr, nullptr);
    for (size_t k = 0; k < check.size(); ++k) {
      const float* gi = &g[3 * check[k]];
      const float slope = std::sqrt(gi[0] * gi[0] + gi[1] * gi[1] + gi[2] * gi[2]);
      if (!(std::abs(fv[k]) <= 0.1 * s * slope)) stage[check[k]] = kDropped;
    }
  }
  for (size_t i : live) {
    if (stage[i] != kDone) continue;
    const Int3& v = voxels[begin + i];
    bool inside = true;
    for (int a = 0; a < 3; ++a)
      inside = inside && p[3 * i + a] >= (v[a] - 0.05) * s && p[3 * i + a] <= (v[a] + 1.05) * s;
    if (!inside) continue;
    Surfel sf;
    const float* gi = &g[3 * i];
    const float norm = std::sqrt(gi[0] * gi[0] + gi[1] * gi[1] + gi[2] * gi[2]);
    for (int a = 0; a < 3; ++a) {
      sf.p[a] = p[3 * i + a];
      sf.n[a] = gi[a] / norm;
    }
    sf.voxel = distance_->VoxelIndex(key, v);
    out->push_back(sf);
  }
}

bool Mapper::RefreshDueLocked(bool* overdue) const {
  // Every query.refresh_frames frames, and more often while the map is young and small (after
  // frames 1, 2, 4, 8, ...), so that a short session's first queries see its surfaces.
  const int64_t every = config_.query.refresh_frames;
  if (overdue) *overdue = distance_frames_ < 0 || frames_ - distance_frames_ >= 2 * every;
  return distance_frames_ < 0 ||
         frames_ - distance_frames_ >=
             std::min<int64_t>(every, std::max<int64_t>(1, distance_frames_));
}

bool Mapper::DistanceRefreshDue(bool* overdue) const {
  std::lock_guard<std::mutex> refresh(refresh_mu_);
  std::shared_lock lock(mu_);
  return RefreshDueLocked(overdue);
}

bool Mapper::DistanceFieldBehind() const {
  std::lock_guard<std::mutex> refresh(refresh_mu_);
  std::shared_lock lock(mu_);
  return distance_frames_ != frames_;
}

double Mapper::RefreshDistanceField() {
  const double start = Now();
  std::lock_guard<std::mutex> refresh(refresh_mu_);
  std::shared_lock lock(mu_);
  saver_->Flush();
  distance_frames_ = frames_;
  std::vector<Int3> keys;
  std::vector<IntBox> regions;
  std::unique_ptr<IntBox> box;
  if (local_map_->placed()) {
    // Voxels just outside the box read coarse rows on its faces, which still train.
    const IntBox b = local_map_->LatticeBox(0);
    const Int3 widen = Int3::Constant(geometry_->scale_to_coarse(0));
    box = std::make_unique<IntBox>(IntBox{b.lo - widen, b.hi + widen});
  }
  if (distance_all_stale_) {
    // Every sub-map the store knows, and those the box covers.
    for (const auto& [key, version] : store_->Versions()) keys.push_back(key);
    distance_all_stale_ = false;
  } else if (box) {
    regions.push_back(*box);
    if (distance_box_ && !(distance_box_->lo == box->lo && distance_box_->hi == box->hi))
      regions.push_back(*distance_box_);
    regions.insert(regions.end(), distance_pending_.begin(), distance_pending_.end());
  }
  distance_pending_.clear();
  for (const IntBox& r : box ? std::vector<IntBox>{*box} : std::vector<IntBox>{}) {
    const Int3 lo = geometry_->SubmapOfLattice(0, r.lo), hi = geometry_->SubmapOfLattice(0, r.hi);
    for (int x = lo.x(); x <= hi.x(); ++x)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int z = lo.z(); z <= hi.z(); ++z) keys.push_back(Int3(x, y, z));
  }
  for (const IntBox& r : regions) {
    const Int3 lo = geometry_->SubmapOfLattice(0, r.lo), hi = geometry_->SubmapOfLattice(0, r.hi);
    for (int x = lo.x(); x <= hi.x(); ++x)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int z = lo.z(); z <= hi.z(); ++z) keys.push_back(Int3(x, y, z));
  }
  std::sort(keys.begin(), keys.end(), [](const Int3& a, const Int3& b) {
    return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
  });
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  // Extraction runs in pieces of at most kRefreshPiece voxels of one sub-map, all sub-maps' pieces
  // over the threads at once: most sub-maps of a refresh hold fewer voxels than two threads'
  // worth of pieces, and extracting them one after another left a core idle. A voxel's surfel
  // depends on that voxel alone, and Replace sorts each sub-map's surfels, so the split changes
  // nothing. The normal fits and tree builds of Replace are one thread's work per sub-map, so
  // those run side by side too (sub-maps share nothing there).
  const int threads = std::max(config_.train.threads, 1);
  std::vector<std::vector<Int3>> voxels(keys.size());
  // Where the last refresh found the zero level, by voxel: the next refresh starts there.
  std::vector<std::shared_ptr<const std::vector<Surfel>>> before(keys.size());
  ParallelFor(int64_t(keys.size()), 1, threads, [&](int64_t begin, int64_t end) {
    for (int64_t k = begin; k < end; ++k) {
      voxels[size_t(k)] = RefreshVoxels(keys[size_t(k)], regions);
      before[size_t(k)] = distance_->Surfels(keys[size_t(k)]);
    }
  });
  struct Piece {
    size_t key, begin, count;
  };
  constexpr size_t kRefreshPiece = 1024;
  std::vector<Piece> pieces;
  for (size_t k = 0; k < keys.size(); ++k)
    for (size_t b = 0; b < voxels[k].size(); b += kRefreshPiece)
      pieces.push_back({k, b, std::min(kRefreshPiece, voxels[k].size() - b)});
  std::vector<std::vector<Surfel>> found(pieces.size());
  ParallelFor(int64_t(pieces.size()), 1, threads, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const Piece& piece = pieces[size_t(i)];
      ExtractSurfels(keys[piece.key], voxels[piece.key], piece.begin, piece.count,
                     before[piece.key].get(), &found[size_t(i)]);
    }
  });
  std::vector<std::vector<Surfel>> fresh(keys.size());
  std::vector<size_t> counts(keys.size(), 0);
  for (size_t i = 0; i < pieces.size(); ++i) counts[pieces[i].key] += found[i].size();
  for (size_t k = 0; k < keys.size(); ++k) fresh[k].reserve(counts[k]);
  for (size_t i = 0; i < pieces.size(); ++i) {
    std::vector<Surfel>& to = fresh[pieces[i].key];
    to.insert(to.end(), found[i].begin(), found[i].end());
  }
  ParallelFor(int64_t(keys.size()), 1, std::max(config_.train.threads, 1),
              [&](int64_t begin, int64_t end) {
                for (int64_t k = begin; k < end; ++k)
                  distance_->Replace(keys[size_t(k)], regions, std::move(fresh[size_t(k)]));
              });
  if (box) distance_box_ = std::move(box);
  RefreshReturns();
  return Now() - start;
}

void Mapper::RefreshReturns() {
  std::lock_guard<std::mutex> aux(aux_mu_);
  const std::vector<Int3> keys = deferred_->TakeChanged();
  if (keys.empty()) return;
  const double inv_s = 1.0 / geometry_->leaf_m();
  std::vector<std::vector<Surfel>> built(keys.size());
  ParallelFor(int64_t(keys.size()), 1, std::max(config_.train.threads, 1),
              [&](int64_t begin, int64_t end) {
                FeatureReader reader(*local_map_, *store_);
                std::vector<uint32_t> voxels;
                std::vector<float> rays;
                for (int64_t k = begin; k < end; ++k) {
                  deferred_->Rays(keys[size_t(k)], &voxels, &rays);
                  std::vector<Surfel>& out = built[size_t(k)];
                  out.reserve(voxels.size());
                  for (size_t i = 0; i < voxels.size(); ++i) {
                    const float* p = &rays[6 * i];
                    const Int3 g0(int(std::floor(p[0] * inv_s)), int(std::floor(p[1] * inv_s)),
                                  int(std::floor(p[2] * inv_s)));
                    // Where training put surface samples, the network's zero level holds the
                    // surface. Where a box saw free space and no surface, a later return from
                    // afar is something that moved through (docs/core.md, "Moving things").
                    if (reader.ObservedBits(g0) & LocalMap::kObservedBits) continue;
                    Surfel s;
                    float n2 = 0;
                    for (int a = 0; a < 3; ++a) {
                      s.p[a] = p[a];
                      s.n[a] = p[3 + a] - p[a];
                      n2 += s.n[a] * s.n[a];
                    }
                    if (!(n2 > 1e-12f)) continue;
                    const float inv = 1.f / std::sqrt(n2);
                    for (float& c : s.n) c *= inv;
                    s.voxel = voxels[i];
                    out.push_back(s);
                  }
                }
              });
  for (size_t k = 0; k < keys.size(); ++k) distance_->ReplaceReturns(keys[k], std::move(built[k]));
}

}  // namespace rim
