// Shared by the GPU path's test and benchmark: a local map filled with random (never zero) data,
// a random decoder, and training batches near a wavy surface with their labels and eikonal probes.
#pragma once

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "rim/config/config.h"
#include "rim/map/local_map.h"
#include "rim/model/decoder.h"

namespace rim::gpu_testing {

inline bool LoadNothing(int, const Int3&, float*, uint8_t*) { return false; }

// Places the box so that it holds the origin and fills every level's features, Adam moments and
// step counts, and level 0's flags, with random values.
inline void PlaceAndFill(LocalMap* map, uint32_t seed) {
  const MapGeometry& geo = map->geometry();
  const Int3 half = geo.cells(geo.levels() - 1) / 2;
  map->MoveTo(-half, LocalMap::SaveFn(), LoadNothing);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.f, 1.f), small(-0.01f, 0.01f), pos(1e-6f, 1e-4f);
  std::uniform_int_distribution<int> steps(0, 5), flag(0, 7);
  for (int l = 0; l < geo.levels(); ++l) {
    LocalMap::Level& lv = map->level(l);
    for (int64_t s = 0; s < lv.slots(); ++s) {
      for (int d = 0; d < geo.feature_dim(); ++d) {
        lv.features(s)[d] = u(rng);
        lv.adam_m(s)[d] = small(rng);
        lv.adam_v(s)[d] = pos(rng);
      }
      lv.adam_steps(s) = steps(rng);
      if (l == 0) lv.flags(s) = uint8_t(flag(rng));
    }
  }
}

// The decoder's seeded initialisation with its biases moved, so that hidden units are both
// active and inactive over the box.
inline void PerturbDecoder(Decoder* decoder, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-0.2f, 0.2f);
  for (const Decoder::Layer& L : decoder->layers())
    for (int k = 0; k < L.out; ++k) decoder->params()[L.bias_offset + size_t(k)] += u(rng);
}

inline std::vector<float> RandomPointsInBox(const LocalMap& map, int n, double margin,
                                            uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Vec3d lo = map.min_m() + Vec3d::Constant(margin);
  const Vec3d span = map.max_m() - map.min_m() - Vec3d::Constant(2 * margin);
  std::vector<float> xyz;
  xyz.reserve(size_t(n) * 3);
  for (int i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) xyz.push_back(float(lo[a] + u(rng) * span[a]));
  return xyz;
}

// A training batch as the trainer builds one: `labelled` samples within ±0.4 m of the surface
// z = 0.3 sin x + 0.2 cos 1.3y (label: the vertical offset), then 6 eikonal probes (±h per axis)
// around each of the first `probed` samples.
struct Batch {
  std::vector<float> xyz, labels;
  int rows = 0, labelled = 0;
};

inline Batch SurfaceBatch(const LocalMap& map, int labelled, int probed, float h, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0), off(-0.4, 0.4);
  const double margin = 2.0 * h + 0.01;
  const Vec3d lo = map.min_m() + Vec3d::Constant(margin);
  const Vec3d hi = map.max_m() - Vec3d::Constant(margin);
  Batch b;
  while (int(b.labels.size()) < labelled) {
    const double x = lo.x() + u(rng) * (hi.x() - lo.x()), y = lo.y() + u(rng) * (hi.y() - lo.y());
    const double t = off(rng);
    const double z = 0.3 * std::sin(x) + 0.2 * std::cos(1.3 * y) + t;
    if (z < lo.z() || z > hi.z()) continue;
    b.xyz.insert(b.xyz.end(), {float(x), float(y), float(z)});
    b.labels.push_back(float(t));
  }
  for (int i = 0; i < probed && i < labelled; ++i)
    for (int a = 0; a < 3; ++a)
      for (float s : {h, -h}) {
        float q[3] = {b.xyz[3 * i], b.xyz[3 * i + 1], b.xyz[3 * i + 2]};
        q[a] += s;
        b.xyz.insert(b.xyz.end(), {q[0], q[1], q[2]});
      }
  b.labelled = labelled;
  b.rows = int(b.xyz.size() / 3);
  return b;
}

}  // namespace rim::gpu_testing
