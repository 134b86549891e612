// Mesh accuracy against a ground-truth mesh (DESIGN.md §4.3), following the protocol of
// SHINE-Mapping's eval_mesh:
//  1. crop the prediction to the GT bounding box (padded by crop_margin_m),
//  2. sample points uniformly by area on each mesh,
//  3. voxel-average them (points in one voxel are replaced by their mean),
//  4. take nearest-neighbour distances both ways (exact, k-d tree),
//  5. drop prediction→GT distances >= drop_m, cap GT→prediction distances at cap_m,
//  6. precision / recall / F-score at fscore_m.
// The "strict" metrics repeat 5–6 without the drop and the cap, so that floaters count.
// The floater share is the share of the (cropped) prediction's area farther than floater_m from
// the GT: each voxel-averaged prediction point stands for the samples it averaged.
//
// Either input may be a point cloud instead of a mesh: a Mesh with vertices and no faces (e.g.
// rim_sim's gt_observed.ply, the surface its sensor actually saw). Its vertices are then the
// points of step 2 as they are (no area sampling); cropping keeps the points inside the box, and
// steps 3–6 are unchanged.
//
// With a box union (EvalOptions::box_union), both sides are cropped to it after step 2: only the
// samples (and a point cloud's points) inside it are kept. Meshes are clipped to the union's
// bounding box before sampling, so that the samples are spent near it.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/base/mesh.h"
#include "rim/eval/box_union.h"

namespace rim::eval {

struct EvalOptions {
  // Points sampled on each mesh (after cropping), before voxel averaging. The count is "about":
  // each triangle gets floor(samples * area / total_area + u), u uniform in [0, 1).
  int64_t samples = 10'000'000;
  double voxel_m = 0.01;   // voxel-averaging size; 0 disables averaging
  double drop_m = 0.2;     // standard metrics ignore prediction points at least this far from GT
  double cap_m = 2.0;      // standard metrics count GT points farther than this at cap_m
  double fscore_m = 0.1;   // inlier threshold of precision, recall and F-score
  double floater_m = 0.2;  // prediction surface farther than this from GT is a floater
  uint64_t seed = 1;       // the prediction is sampled with `seed`, the GT with another stream
  int threads = 2;         // results do not depend on the thread count
  bool crop_to_gt = true;  // step 1
  // Padding of the GT box on every side. A flat GT (a ground plane) has a box of zero height, and
  // a prediction point more than drop_m outside the box is more than drop_m from every GT point,
  // so padding by drop_m leaves the standard metrics as they would be without the crop.
  // (SHINE-Mapping pads only z, by its voxel size, and keeps only the triangles wholly inside;
  // here triangles are clipped exactly.)
  double crop_margin_m = 0.2;
  // When set, both the prediction and the GT are evaluated only inside this union of boxes (after
  // the crop of step 1).
  std::shared_ptr<const BoxUnion> box_union;
  // When set, EvalResult lists the GT points farther than fscore_m from the prediction (the
  // misses) and the prediction points farther than floater_m from the GT (the floaters).
  bool keep_outliers = false;
  // When set: surfaces there at the end though the GT leaves them out, such as rim_sim's
  // gt_moving_last.ply (the people and cars where the last scan saw them). A floater within
  // floater_m of them is something a mapper could not know would go; EvalResult's ghost share
  // counts the other floaters. A mesh or a point cloud; it changes no other measure.
  std::shared_ptr<const Mesh> present;
};

// Fractions are in [0, 1]; distances in metres.
struct Metrics {
  double accuracy_m = 0;  // mean prediction→GT distance (NaN when no prediction point is kept)
  double completeness_m = 0;  // mean GT→prediction distance
  double chamfer_l1_m = 0;    // (accuracy + completeness) / 2
  double precision = 0;       // prediction points (kept) closer than fscore_m to GT
  double recall = 0;          // GT points closer than fscore_m to the prediction
  double fscore = 0;          // 2PR / (P + R), 0 when P + R = 0
};

// What an input was taken as: a triangle mesh, or a point cloud (vertices and no faces).
enum class InputKind { kMesh, kPoints };
const char* InputKindName(InputKind kind);  // "mesh" or "points"

struct EvalResult {
  Metrics standard;  // with the drop and the cap (the paper's numbers)
  Metrics strict;    // without them
  InputKind pred_kind = InputKind::kMesh;
  InputKind gt_kind = InputKind::kMesh;
  // After cropping (to the GT box, and to the box union's bounding box); 0 for a point cloud.
  double pred_area_m2 = 0;
  double gt_area_m2 = 0;
  // Sampled (a point cloud: its points), after cropping (also to the box union itself), before
  // voxel averaging.
  int64_t pred_samples = 0;
  int64_t gt_samples = 0;
  int64_t pred_points = 0;  // after voxel averaging: the points the metrics are over
  int64_t gt_points = 0;
  int64_t pred_dropped = 0;  // prediction points left out of the standard metrics
  int64_t gt_capped = 0;     // GT points whose distance the standard metrics cap
  // The share of the prediction's area (after all cropping) farther than floater_m from the GT,
  // in [0, 1], and that area. A point cloud has no area: the share is then of its points (as
  // given, after cropping) and the area 0.
  double floater_share = 0;
  double floater_area_m2 = 0;
  // With EvalOptions::present: the floaters also farther than floater_m from it (the ghosts), as
  // a share of the prediction and an area, like the floaters'.
  bool has_present = false;
  double ghost_share = 0;
  double ghost_area_m2 = 0;
  // With EvalOptions::keep_outliers: the voxel-averaged points, each with its distance to the
  // other side, in voxel-key order.
  struct OutlierPoint {
    float x, y, z, distance_m;
  };
  std::vector<OutlierPoint> misses;    // GT points farther than fscore_m from the prediction
  std::vector<OutlierPoint> floaters;  // prediction points farther than floater_m from the GT
};

// Checks every field, naming the bad one.
absl::Status ValidateEvalOptions(const EvalOptions& options);

// Evaluates `pred` against `gt`; either may be a point cloud (vertices, no faces). Errors
// (InvalidArgument) for bad options, face indices out of range, non-finite vertices (of a point
// cloud: any vertex; of a mesh: those faces use), a GT without area or points, and a prediction
// without area or points inside the padded GT box (or either without points inside the box
// union): an empty prediction has no defined accuracy, and a script must not mistake it for a
// number.
absl::StatusOr<EvalResult> EvaluateMeshes(const Mesh& pred, const Mesh& gt,
                                          const EvalOptions& options);

// The cropping of step 1, exposed for tests and for rim_eval's --region: triangles are clipped
// exactly to the box [lower, upper] (a triangle across a face keeps only its part inside),
// returned as a triangle soup. A point cloud (no faces) keeps its vertices inside the box
// (bounds included), in their order.
Mesh CropMeshToBox(const Mesh& mesh, const std::array<float, 3>& lower,
                   const std::array<float, 3>& upper);

}  // namespace rim::eval
