// Mapper: queries. QueryNeural reads the network; QuerySdf the metric distance field
// (map/distance_field.h), signed by what the map observed.
#include <algorithm>
#include <cmath>
#include <functional>
#include <mutex>
#include <vector>

#include "absl/strings/str_cat.h"
#include "rim/base/status_macros.h"
#include "rim/base/worker_pool.h"
#include "rim/map/distance_field.h"
#include "rim/map/local_map.h"
#include "rim/map/slab_saver.h"
#include "rim/map/submap_store.h"
#include "rim/mapper.h"
#include "rim/model/decoder.h"
#include "rim/model/encoder.h"

namespace rim {

namespace {
absl::Status CheckQueryPoints(const float* xyz, size_t n) {
  for (size_t i = 0; i < 3 * n; ++i)
    if (!std::isfinite(xyz[i]) || std::abs(xyz[i]) > 1e6f)
      return absl::InvalidArgumentError(
          absl::StrCat("points[", i / 3, "] is not finite or beyond 1e6 m"));
  return absl::OkStatus();
}

uint8_t ObservedCode(uint8_t bits) {
  return ((bits & LocalMap::kObserved) ? QueryResult::kObservedSurface : 0) |
         ((bits & LocalMap::kSeenFree) ? QueryResult::kObservedFree : 0);
}

// Chunks of points, so that scratch buffers stay small whatever the batch, spread over up to
// `threads` threads for large batches. Every point's answer depends on that point alone, so the
// split does not change any value. A batch over one chunk is cut into equal chunks of at most
// twice kQueryChunk, as many per thread: a planner's 10k points go as two chunks of 5k, one per
// thread, where chunks of 4096 left one thread two of them (5.9k points against 4.1k) and two
// waits for the map's lock in a row.
constexpr size_t kQueryChunk = 4096;
void ForChunks(size_t n, int threads, const std::function<void(size_t, size_t)>& fn) {
  threads = std::max(threads, 1);
  size_t block = kQueryChunk;
  if (n > kQueryChunk && threads > 1) {
    const size_t per_round = size_t(threads) * 2 * kQueryChunk;
    const size_t chunks = size_t(threads) * ((n + per_round - 1) / per_round);
    block = (n + chunks - 1) / chunks;
  }
  ParallelFor(int64_t(n), int64_t(block), threads,
              [&](int64_t b, int64_t e) { fn(size_t(b), size_t(e - b)); });
}
}  // namespace

void Mapper::EvalNeural(const float* xyz, size_t n, float* sdf, float* grad,
                        uint8_t* observed) const {
  const int F = geometry_->encoding_dim();
  const double inv_s = 1.0 / geometry_->leaf_m();
  FeatureReader reader(*local_map_, *store_);
  const size_t chunk = std::min(n, kQueryChunk);
  std::vector<float> features(chunk * F), jac(grad ? chunk * F * 3 : 0), dsdf(grad ? chunk * F : 0);
  for (size_t begin = 0; begin < n; begin += kQueryChunk) {
    const size_t m = std::min(kQueryChunk, n - begin);
    constexpr size_t kAhead = 4;  // points whose rows are on their way while one is blended
    for (size_t i = 0; i < m; ++i) {
      if (i + kAhead < m) {
        const float* ahead = xyz + 3 * (begin + i + kAhead);
        reader.Prefetch(Vec3d(ahead[0], ahead[1], ahead[2]));
      }
      const float* q = xyz + 3 * (begin + i);
      const Vec3d p(q[0], q[1], q[2]);
      reader.Encode(p, &features[i * F], grad ? &jac[i * F * 3] : nullptr);
      if (observed) {
        const Int3 g0(int(std::floor(p.x() * inv_s)), int(std::floor(p.y() * inv_s)),
                      int(std::floor(p.z() * inv_s)));
        observed[begin + i] = ObservedCode(reader.ObservedBits(g0));
      }
    }
    decoder_->Forward(features.data(), int(m), sdf + begin, grad ? dsdf.data() : nullptr);
    if (!grad) continue;
    // Chain rule: d sdf / d p = (d sdf / d features) · (d features / d p).
    for (size_t i = 0; i < m; ++i) {
      float* g = grad + 3 * (begin + i);
      g[0] = g[1] = g[2] = 0.f;
      for (int f = 0; f < F; ++f)
        for (int a = 0; a < 3; ++a) g[a] += dsdf[i * F + f] * jac[(i * F + f) * 3 + a];
    }
  }
}

absl::Status Mapper::QueryNeural(const float* xyz, size_t n, bool want_gradient,
                                 QueryResult* out) const {
  RIM_RETURN_IF_ERROR(CheckQueryPoints(xyz, n));
  std::shared_lock lock(mu_);
  // Under the lock, or a slide in between could leave slabs on their way to the store, in
  // neither the local map nor the store, and read as unobserved zeros.
  saver_->Flush();
  out->sdf.resize(n);
  out->observed.resize(n);
  out->gradient.assign(want_gradient ? 3 * n : 0, 0.f);
  out->saturated.clear();
  ForChunks(n, config_.train.threads, [&](size_t begin, size_t m) {
    EvalNeural(xyz + 3 * begin, m, &out->sdf[begin],
               want_gradient ? &out->gradient[3 * begin] : nullptr, &out->observed[begin]);
  });
  out->map_version = map_version_.load();
  return absl::OkStatus();
}

absl::Status Mapper::QuerySdf(const float* xyz, size_t n, bool want_gradient,
                              QueryResult* out) const {
  RIM_RETURN_IF_ERROR(CheckQueryPoints(xyz, n));
  out->sdf.resize(n);
  out->observed.resize(n);
  out->saturated.resize(n);
  out->gradient.assign(want_gradient ? 3 * n : 0, 0.f);
  // The version the answer starts from; a large batch may read newer ones in later chunks.
  out->map_version = map_version_.load();
  const double inv_s = 1.0 / geometry_->leaf_m();
  ForChunks(n, config_.train.threads, [&](size_t begin, size_t m) {
    // The map itself (observed flags, the network's side inside surface bands) is read under
    // the shared lock one chunk at a time, so that training waits for at most one chunk of a
    // large batch, not the whole of it; the distances then come from the field's own snapshots,
    // outside the lock.
    // The sign. The side of the nearest disk's plane is wrong past a convex edge (the disk's
    // plane runs on beyond it) and before a stray surfel. A voxel that rays crossed, away from
    // any surface band, is free space; inside a surface band the network, trained there, knows
    // the side; elsewhere (never observed) the disk decides.
    std::vector<size_t> band;
    std::vector<float> band_xyz, band_sdf;
    {
      std::shared_lock lock(mu_);
      saver_->Flush();  // under the lock, as in QueryNeural
      FeatureReader reader(*local_map_, *store_);
      for (size_t i = begin; i < begin + m; ++i) {
        const float* q = xyz + 3 * i;
        const Int3 g0(int(std::floor(q[0] * inv_s)), int(std::floor(q[1] * inv_s)),
                      int(std::floor(q[2] * inv_s)));
        out->observed[i] = ObservedCode(reader.ObservedBits(g0));
        if (out->observed[i] & QueryResult::kObservedSurface) {
          band.push_back(i);
          band_xyz.insert(band_xyz.end(), q, q + 3);
        }
      }
      band_sdf.resize(band.size());
      if (!band.empty())
        EvalNeural(band_xyz.data(), band.size(), band_sdf.data(), nullptr, nullptr);
    }
    // Returns count at observed points only: elsewhere a planner must treat the place as
    // unknown whatever it reads, and the surfels' distance there costs no more than before
    // returns were kept (half the points of a batch spread over the map lie out there).
    distance_->Query(xyz + 3 * begin, m, config_.query.max_distance_m, &out->sdf[begin],
                     want_gradient ? &out->gradient[3 * begin] : nullptr, &out->saturated[begin],
                     &out->observed[begin]);
    // The gradient turns too, except within a couple of centimetres of the surface: there the
    // two disagree because the network's zero level and the disks' planes lie millimetres apart,
    // and the gradient of a signed distance at its surface is the normal on either side.
    auto flip = [&](size_t i) {
      out->sdf[i] = -out->sdf[i];
      if (want_gradient && std::abs(out->sdf[i]) > 0.02f)
        for (int a = 0; a < 3; ++a) out->gradient[3 * i + a] = -out->gradient[3 * i + a];
    };
    for (size_t k = 0; k < band.size(); ++k)
      if ((band_sdf[k] < 0) != (out->sdf[band[k]] < 0)) flip(band[k]);
    for (size_t i = begin; i < begin + m; ++i)
      if (out->observed[i] == QueryResult::kObservedFree && out->sdf[i] < 0) flip(i);
  });
  return absl::OkStatus();
}

}  // namespace rim
