// Free-space bookkeeping for queries (§3.5 "observed"): the finest voxels a measured ray crossed
// in front of its endpoint were seen free. Training samples only land in part of that space (free
// samples start at free_min_ratio of the range), so a planner asking about the space right in
// front of the robot would otherwise hear "never observed" about space the sensor just looked
// through.
#pragma once

#include <functional>
#include <vector>

#include "rim/base/types.h"
#include "rim/base/worker_pool.h"
#include "rim/map/local_map.h"

namespace rim {

// Marks kSeenFree on the finest voxels of the local map crossed by rays origin -> point, stopping
// `band_m` short of the endpoint (the surface band, which training marks kObserved). Uses at most
// `max_rays` rays, evenly strided through the scan, so the cost per frame is bounded whatever the
// scan size; 0 marks nothing. Only the part of each ray inside the box is walked. With a pool,
// the rays are shared among its threads; the marks are the same either way.
void MarkFreeSpace(const std::vector<Vec3f>& points_W, const std::vector<Vec3f>& origins_W,
                   float band_m, int max_rays, LocalMap* map, WorkerPool* pool = nullptr);

// Marks kObserved on the finest voxel of every endpoint inside the box: the sensor measured a
// surface there, so queries report it observed and meshing visits it, whether or not a training
// sample has landed in it yet. With a pool, the points are shared among its threads.
void MarkSurfaceVoxels(const std::vector<Vec3f>& points_W, LocalMap* map,
                       WorkerPool* pool = nullptr);

// One scan's marking in one pass over the pool: MarkSurfaceVoxels of the inside endpoints,
// MarkFreeSpace of the inside rays (at most `inside_rays`) and of the rays ending outside the box
// (at most `outside_rays`), with `also` run as one more task beside them (the mapper updates its
// point buffer there, which marking does not touch). The marks are those of the three calls.
void MarkScan(const std::vector<Vec3f>& inside_p, const std::vector<Vec3f>& inside_o,
              const std::vector<Vec3f>& outside_p, const std::vector<Vec3f>& outside_o,
              float band_m, int inside_rays, int outside_rays, LocalMap* map, WorkerPool* pool,
              const std::function<void()>& also = nullptr);

}  // namespace rim
