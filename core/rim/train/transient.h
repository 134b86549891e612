// Moving things leave no trace (docs/core.md, "Moving things"): a return that a later scan's rays
// clearly pass is evidence that what stood there (a person, a passing car) has gone. Such returns
// are dropped from the point buffer and from the deferred rays, and for a few frames free-space
// samples where they stood clear the network, so the mesh, the distance field and the observed
// surface forget them.
//
// The rule, judged per point p against the later scan's range image (nearest return per bin of
// direction, in the sensor frame, with where in the bin it lies), over a window of bins around
// p's direction (docs/core.md, "Moving things", has the numbers and the measurements):
//  - no return of the window lies within near_m + near_bins · (bin width at p's range) of p
//    (something is still there: a thin pole's hits), and
//  - the window holds returns on both sides of p in azimuth and in elevation, and either
//  - every return ends at least margin_m + margin_per_m · range beyond p, or
//  - (surface_fit) a plane fitted to the returns in 1/range (linear in the direction for any
//    plane) fits them within fit_rms_m + fit_rms_per_m · range and passes p by the margin along
//    the ray and by fit_normal_margin_m along its normal: the road beyond a departed person's
//    feet, where the rays below them end in front of where they stood.
// A static surface that the scan sees is not eroded: its own returns fit a plane through p, not
// beyond it, at any angle; the normal margin keeps points a few centimetres off a surface seen at
// a grazing angle; across a depth edge no plane fits and of two rays on opposite sides of p one
// ends nearer. A surface hidden behind something nearer keeps its points. A surface seen once from
// afar and never again in the window's reach is not judged. An empty bin counts as a return at
// the scan's range only along a fired row (empty_is_free, fired_row_share): the sky behind a
// person seen along the street; elsewhere (absorbing or specular surfaces, gaps between rings)
// it is no evidence. A return nearer than the scan's minimum range blocks the window.
#pragma once

#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <mutex>
#include <utility>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "rim/base/types.h"
#include "rim/base/worker_pool.h"
#include "rim/config/config.h"
#include "rim/map/deferred_points.h"
#include "rim/map/local_map.h"
#include "rim/train/point_buffer.h"
#include "rim/train/sampler.h"

namespace rim {

// The nearest return per bin of direction (azimuth, elevation) of one scan, in the sensor frame.
class RangeImage {
 public:
  // Per point of the scan while filling: its bin, or ~0 when not binned, its place in it and its
  // range in centimetres.
  struct Scratch {
    std::vector<uint32_t> bins;
    std::vector<uint16_t> offsets;
    std::vector<uint16_t> ranges_cm;
  };

  explicit RangeImage(float bin_deg);

  // Bins the points (sensor frame) whose range lies in [min_range_m, max_range_m]; with a pool,
  // on its threads (the same image either way). A bin whose nearest return lies nearer than
  // min_range_m reads 0 (blocked: what lies behind it is unknown).
  // A row holding returns at fired_row_share of its azimuths or more counts as fired (Fired()).
  // The per-point scratch (Scratch, below) is `external` when given (one for many images), else
  // the image's own.
  void Fill(const std::vector<Vec3f>& points_S, float min_range_m, float max_range_m,
            WorkerPool* pool = nullptr, float fired_row_share = 0.5f, Scratch* external = nullptr);

  int azimuth_bins() const { return na_; }
  int elevation_bins() const { return ne_; }
  // Bins needed to span an angle (radians; its tangent is fine for small angles), rounded up.
  int BinsSpanning(float angle_rad) const { return int(std::ceil(angle_rad * inv_bin_rad_)); }
  // The bin of a direction (need not be unit; not zero).
  void BinOf(const Vec3f& d_S, int* azimuth, int* elevation) const;
  // The direction's place in bins, continuous: azimuth in [0, azimuth_bins()), elevation in
  // [0, elevation_bins()]; its bin is (floor(azimuth), floor(elevation)).
  void PlaceOf(const Vec3f& d_S, float* azimuth, float* elevation) const;
  // PlaceOf for eight points, with their ranges: the same bits as PlaceOf and norm(), eight at a
  // time where the processor has AVX2.
  void Place8(const Vec3f* p, float* range, float* azimuth, float* elevation) const;
  float bin_rad() const { return 1.f / inv_bin_rad_; }
  // The nearest range in bin (azimuth, elevation), floored to the centimetre; +inf when it holds
  // no return. Azimuth wraps; elevation must be in [0, elevation_bins()).
  float At(int azimuth, int elevation) const {
    azimuth %= na_;
    if (azimuth < 0) azimuth += na_;
    return AtWrapped(azimuth, elevation);
  }
  // Whether the sensor fired along elevation row `elevation` (see Fill),
  // and the range up to which an empty bin of such a row saw nothing.
  bool Fired(int elevation) const {
    const int row = elevation - first_row_;
    return unsigned(row) < unsigned(rows_) && fired_[size_t(row)];
  }
  float empty_range_m() const { return empty_range_m_; }
  // The rows that hold returns: [first_row(), first_row() + rows()); every other row is empty.
  int first_row() const { return first_row_; }
  int rows() const { return rows_; }
  // Whether row `elevation` (one of those) holds a blocked bin (a return nearer than the minimum
  // range).
  bool RowBlocked(int elevation) const { return blocked_[size_t(elevation - first_row_)] != 0; }
  // At() for an azimuth already in [0, azimuth_bins()).
  float AtWrapped(int azimuth, int elevation) const {
    const int row = elevation - first_row_;
    if (unsigned(row) >= unsigned(rows_)) return std::numeric_limits<float>::infinity();
    const uint16_t cm = range_cm_[size_t(row) * na_ + azimuth];
    return cm == kEmpty ? std::numeric_limits<float>::infinity() : 0.01f * float(cm);
  }
  // Row `elevation`'s ranges (centimetres, empty_cm() where the bin holds no return, 0 where it
  // is blocked) and return places (8 bits each way, as OffsetAt decodes them), azimuth-indexed;
  // null for a row without returns (every bin empty). Row r's fired flag: Fired().
  const uint16_t* RangeRow(int elevation) const {
    const int row = elevation - first_row_;
    return unsigned(row) < unsigned(rows_) ? &range_cm_[size_t(row) * na_] : nullptr;
  }
  const uint16_t* OffsetRow(int elevation) const {
    return &offset_[size_t(elevation - first_row_) * na_];
  }
  static constexpr uint16_t empty_cm() { return kEmpty; }
  // Where in bin (azimuth, elevation), already wrapped, its nearest return lies: offsets in
  // [0, 1) of a bin from the bin's lower corner. Only for a bin that holds a return.
  void OffsetAt(int azimuth, int elevation, float* da, float* de) const {
    const uint16_t o = offset_[size_t(elevation - first_row_) * na_ + azimuth];
    *da = (float(o & 0xff) + 0.5f) * (1.f / 256.f);
    *de = (float(o >> 8) + 0.5f) * (1.f / 256.f);
  }

 private:
  // Only the rows between the scan's lowest and highest return are kept, in centimetres: for a
  // spinning LiDAR that is 70 rows of 900 bins, 126 KB, which stays in a core's cache while a
  // frame's points are judged in random directions (a float image of every elevation was 1.6 MB,
  // and judging waited on memory).
  static constexpr uint16_t kEmpty = 0xffff;
  static constexpr size_t kRowSlack = 8;  // bins kept past the last row (see Fill)
  // Place8 with AVX2 (only where the processor has it).
  void Place8Avx2(const Vec3f* p, float* range, float* azimuth, float* elevation) const;
  // Fill's binning of eight points with AVX2: per point its bin (~0 when not binned), its place in
  // it and its range in centimetres, as Fill's scalar code writes them; lo and hi take the lowest
  // and highest row binned.
  void Bin8Avx2(const Vec3f* p, float min_range_m, float max_range_m, uint32_t* bins,
                uint16_t* offsets, uint16_t* ranges_cm, int* lo, int* hi) const;
  float inv_bin_rad_;
  int na_, ne_;
  int first_row_ = 0, rows_ = 0;
  std::vector<uint16_t> range_cm_;
  std::vector<uint16_t> offset_;  // per bin: its return's place in it, 8 bits each way
  std::vector<uint8_t> fired_;    // per row
  std::vector<uint8_t> blocked_;  // per row
  float empty_range_m_ = 0.f;
  Scratch scratch_;  // when Fill is given none
};

// The rule above for a point p_S (sensor frame) at range r = |p_S| in [min_range_m, max_range_m]
// (false outside it).
bool SeenThrough(const RangeImage& image, const TransientConfig& config, const Vec3f& p_S);
// The same, telling apart why a point is kept when a return of the window lies within the near
// distance of it (something is there).
enum class Verdict : uint8_t { kKept, kSomethingThere, kSeenThrough };
Verdict Judge(const RangeImage& image, const TransientConfig& config, const Vec3f& p_S);
// Judge with the window read one bin at a time whatever the processor: the reference that the
// window read eight bins at a time (where the processor has AVX2) must equal.
Verdict JudgeReference(const RangeImage& image, const TransientConfig& config, const Vec3f& p_S);

// Where dropped returns stood, for a few frames: free-space samples there clear the network.
class ClearedPoints {
 public:
  // p_W, seen along dir_W (unit, from the sensor that saw it), dropped at `frame`.
  void Add(const Vec3f& p_W, const Vec3f& dir_W, int64_t frame);
  // Forgets points dropped before frame − lifetime_frames, or outside the box [lo, hi), and the
  // oldest beyond max_points.
  void Expire(int64_t frame, int lifetime_frames, size_t max_points, const Vec3d& lo,
              const Vec3d& hi);
  size_t size() const { return points_.size(); }
  // Appends n samples at p + u·dir (u uniform in [−band_m, band_m], p a uniformly drawn point)
  // with label `label_m` (free space), dropping those outside the box [lo, hi).
  void Sample(int n, float band_m, float label_m, const Vec3f& lo, const Vec3f& hi, FastRng* rng,
              SampleBatch* out) const;
  void Clear();

 private:
  std::vector<Vec3f> points_, dirs_;
  std::vector<int64_t> frames_;  // non-decreasing
};

struct TransientStats {
  int64_t buffer_removed = 0;    // buffered returns dropped since creation
  int64_t deferred_removed = 0;  // deferred rays dropped since creation
  int64_t judged = 0;            // points judged since creation
  int64_t past_removed = 0;      // of buffer_removed, those dropped on earlier evidence
  int64_t busy_removed = 0;  // of buffer_removed, those dropped on passes added up (busy places)
  int64_t departed_removed = 0;  // departed points seen through since creation
};

class TransientFilter {
 public:
  explicit TransientFilter(const TransientConfig& config);

  // Judges against the scan (points in the sensor frame, the sensor's pose) one in period_frames
  // of the buffer's points and of the deferred rays within max_range_m of the sensor (which ones
  // turns with `frame`), and drops those seen through. Dropped buffer points join the cleared
  // points, and the finest voxels at the corners of the cell holding each lose their observed
  // mark in `map` (they read as seen free): meshing skips them at once, before the network has
  // unlearnt the surface there, and so does a region that leaves the box soon after (its marks
  // go to the global map with it). `aux_mu` is held while the buffer and the deferred store change
  // (readers of their sizes take it); judging the buffer reads it without the lock, so nothing else
  // may write it meanwhile. With a pool, the buffer's points are judged on its threads.
  void Apply(const std::vector<Vec3f>& points_S, const Eigen::Isometry3f& T_world_sensor,
             float scan_min_range_m, float scan_max_range_m, int64_t frame, PointBuffer* buffer,
             DeferredPoints* deferred, LocalMap* map, std::mutex* aux_mu, WorkerPool* pool);

  // Earlier evidence (TransientConfig::past_frames): judges the newest frame's buffered points
  // (PointBuffer::newest(), after this frame's Apply and AddFrame) against the scans past_frames,
  // 2 · past_frames, ... frames before this one, and drops those seen through, unmarking their
  // voxels and adding them to the cleared points as Apply does. Returns how many were dropped.
  // The same locking as Apply.
  int64_t JudgeNewest(int64_t frame, PointBuffer* buffer, LocalMap* map, std::mutex* aux_mu,
                      WorkerPool* pool);

  // Finest voxels (at the corners of the cells holding departed points, or buffered points the box
  // has just left, seen through) that lie outside the box now, collected since the last call: the
  // mapper marks them seen free in the global map (SubmapStore::ClearObserved). Each voxel once:
  // the buffer's points share them.
  std::vector<Int3> TakeOutsideCells();
  size_t departed() const { return departed_count_; }

  const ClearedPoints& cleared() const { return cleared_; }
  ClearedPoints& cleared() { return cleared_; }
  // Read under the `aux_mu` that Apply takes.
  TransientStats Stats() const { return stats_; }
  const RangeImage& image() const { return image_; }

 private:
  // Drops buffered points from index `from` on where drop_ is set, unmarking their voxels (see
  // Apply) and adding them to the cleared points. Returns how many.
  int64_t DropFromBuffer(int64_t frame, size_t from, PointBuffer* buffer, LocalMap* map,
                         std::mutex* aux_mu);
  // Returns how many departed points were seen through.
  int64_t JudgeDeparted(const std::vector<Vec3f>& points, int64_t frame, const LocalMap& map,
                        const Eigen::Isometry3f& T_world_sensor, WorkerPool* pool);

  // Where things move (TransientConfig::active_frames): the columns, active_cell_m across x and y,
  // in which a buffered return was dropped, with the frame of the last drop there and the drops
  // since the column was last quiet for active_frames frames. Only the rule's drops count (on
  // this scan's or on earlier evidence), not those of passes added up in busy places.
  struct Column {
    int64_t last = 0;
    int drops = 0;
  };
  static uint64_t ColumnKey(int cx, int cy) {
    return (uint64_t(uint32_t(cx)) << 32) | uint64_t(uint32_t(cy));
  }
  void NoteDrop(const Vec3f& p_W, int64_t frame);
  // Forgets the columns quiet since before frame − active_frames and sets active_mask_ to those
  // left, each with its eight neighbours, and busy_mask_ to those of them with busy_drops drops or
  // more (busy_on_: whether it holds this frame). Returns false when the gate is off this frame
  // (every point takes its turn).
  bool BuildActiveMask(int64_t frame);
  absl::flat_hash_map<uint64_t, Column> active_;
  struct ActiveMask {
    int x0 = 0, y0 = 0, nx = 0, ny = 0;  // columns [x0, x0 + nx) × [y0, y0 + ny)
    float inv_cell = 1.f;
    std::vector<uint8_t> on;
    bool Has(const Vec3f& p_W) const {
      const int x = int(std::floor(p_W.x() * inv_cell)) - x0;
      const int y = int(std::floor(p_W.y() * inv_cell)) - y0;
      return x >= 0 && y >= 0 && x < nx && y < ny && on[size_t(x) * size_t(ny) + size_t(y)];
    }
  };
  ActiveMask active_mask_;
  ActiveMask busy_mask_;
  bool busy_on_ = false;

  TransientConfig config_;
  RangeImage image_;  // this frame's scan
  Eigen::Isometry3f image_T_ = Eigen::Isometry3f::Identity();
  int64_t image_frame_ = -1;
  // Earlier scans' images, for JudgeNewest: a ring of past_frames · past_scans, the scan of
  // frame f in slot f mod its size.
  struct PastScan {
    RangeImage image;
    Eigen::Isometry3f T_world_sensor = Eigen::Isometry3f::Identity();
    int64_t frame = -1;
  };
  std::vector<PastScan> past_;
  RangeImage::Scratch fill_scratch_;  // for image_, whichever ring slot's storage it holds
  ClearedPoints cleared_;
  TransientStats stats_;
  std::vector<uint8_t> drop_;  // per buffered point: 1 seen through, 2 passes added up (busy)
  struct Departed {
    Vec3f p;
    int64_t frame;
    int64_t order;  // in the order they left (one frame's by voxel)
  };
  // The departed points by turn: those of turn t are judged in frames with frame mod
  // (2 · period_frames) equal to t. Each list in the order they left, from its head on.
  struct DepartedTurn {
    std::vector<Departed> points;
    size_t head = 0;
    size_t size() const { return points.size() - head; }
  };
  std::vector<DepartedTurn> departed_;
  size_t departed_count_ = 0;
  int64_t departed_order_ = 0;
  std::vector<uint8_t> departed_drop_;                          // per point of this frame's turn
  std::vector<std::pair<int64_t, uint32_t>> departed_leaving_;  // this frame's: voxel, point
  static constexpr int kFindPieces = 4;  // the search for leaving points, over the pool
  std::vector<std::pair<int64_t, uint32_t>> departed_found_[kFindPieces];
  std::vector<std::pair<int64_t, uint32_t>> departed_merge_;  // the first two merges

  std::vector<Int3> outside_cells_;
};

}  // namespace rim
