#include "sim/city.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/base/status_macros.h"
#include "sim/rng.h"

namespace rim::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

// Cross-section of a street, lateral distance from its centre line.
constexpr double kRoadHalfWidth = 4.5;
constexpr double kParkOffset = 3.45;  // parked car centre
constexpr double kPoleOffset = 4.9;
constexpr double kTreeOffset = 5.2;
constexpr double kWalkerMin = 6.0, kWalkerMax = 7.8;  // sidewalk band walkers use
// Lateral half extent of a parked car: half its width (at most 0.95 m) grown by its yaw jitter
// (at most 2 degrees, over half a length of at most 2.4 m).
constexpr double kParkReach = 1.04;
// Tree crowns start at least this high; pole arms are higher still.
constexpr double kLowestCrown = 2.2;
// Street furniture stays this far (along the street) from intersection centres.
constexpr double kIntersectionClear = 14.0;
// Streets (centre lines) at x = i * pitch for i in [kMinI, kMaxI], y = j * pitch for j in
// [kMinJ, kMaxJ]; the drive loop goes round the blocks [0, 2 pitch] x [0, pitch].
constexpr int kMinI = -1, kMaxI = 3, kMinJ = -1, kMaxJ = 2;
constexpr double kSink = 0.03;  // solids reach this far below the ground so that nothing floats
// The cross-section must leave the sensor's lane, parked cars and sidewalk objects apart.
static_assert(kLaneOffset + 0.5 < kParkOffset - 0.95, "parked cars too close to the lane");
static_assert(kParkOffset + 0.95 < kRoadHalfWidth, "parked cars must stay on the road");
static_assert(kRoadHalfWidth < kPoleOffset && kTreeOffset + 0.5 < kWalkerMin,
              "poles and trees stand on the sidewalk, clear of the walkers");
static_assert(kWalkerMax + 0.3 < kFrontage, "walkers stay clear of the buildings");
static_assert(0.95 * 0.99939 + 2.4 * 0.03490 < kParkReach, "parked car half width with yaw");

// Kerb-side parked cars (CityFeatures::parked_cars): their kerb side stays kKerbGapMin to
// kKerbGapMax inside the kerb line (kRoadHalfWidth), at most kKerbCarWidth wide and
// kKerbCarLength long, yawed at most kKerbYawDeg off the street; they reach no nearer the lane
// than the scattered cars do.
constexpr double kKerbGapMin = 0.03, kKerbGapMax = 0.15;
constexpr double kKerbCarWidth = 1.9, kKerbCarLength = 5.2, kKerbYawDeg = 0.8;
static_assert(kRoadHalfWidth - kKerbGapMax - kKerbCarWidth - 0.5 * kKerbCarLength * 0.01397 >=
                  kParkOffset - kParkReach,
              "kerb-side cars keep as far from the lane as the scattered ones");
// Balconies and broad canopies. Balconies stick out at most kMaxBalconyDepth from facades that
// stand kFrontage or more from every street centre line; ordinary tree crowns stay short of them.
constexpr double kBalconyEmbed = 0.03;  // how far slabs and annexes reach into their building
static_assert(kTreeOffset + 0.2 + 2.2 + 0.3 < kFrontage - kMaxBalconyDepth,
              "ordinary crowns stay clear of the balconies");
constexpr double kCanopyBaseMin = 2.5, kCanopyBaseMax = 3.5;
constexpr double kCanopyRadiusMin = 2.0, kCanopyRadiusMax = 4.0, kCanopyRadiusLeast = 1.6;
constexpr double kCanopyRoadEdge = kLaneOffset + 0.25;  // crowns reach no nearer the centre line
constexpr double kCanopyGap = 0.3;  // from buildings, balconies, annexes, poles and their arms
static_assert(kCanopyBaseMin >= kLowestCrown, "broad crowns are no lower than the others");
static_assert(kLowestBalcony > kLowestCrown, "balconies are higher than what walks beneath");

// Crossers: what they draw from, and what they keep clear of.
constexpr double kCrosserSpeedMin = 1.0, kCrosserSpeedMax = 1.6;
constexpr double kCrosserRadiusMin = 0.22, kCrosserRadiusMax = 0.28;
constexpr double kCrosserHeightMin = 1.6, kCrosserHeightMax = 1.9;
constexpr double kCrossSolidGap = 0.6;  // from a crossing line to any static solid but a car
constexpr double kCrossSpacing = 0.6;   // between two crossing lines
// While the sensor is within kPassReach (along the drive) of a crossing line, the crosser keeps
// kPassGap (laterally) from the sensor's lane.
constexpr double kPassReach = 2.5, kPassGap = 1.5;
static_assert(kCrossHalfSpan > kRoadHalfWidth + 1.0, "crossers walk from sidewalk to sidewalk");
static_assert(kCrossHalfSpan + kCrosserRadiusMax + 0.3 < kFrontage,
              "crossers stay clear of the buildings");
static_assert(kCrosserHeightMax < kLowestCrown, "crossers walk beneath the tree crowns");
static_assert(kCrossCarGap >= kCrossCarGapMin && kCrossCarGapMin > kCrosserRadiusMax + 0.4 &&
                  kCrossSolidGap > kCrosserRadiusMax + 0.3,
              "crossing lines keep crossers clear of cars and street furniture");
static_assert(kPassGap > 0.9 + kCrosserRadiusMax + 0.3, "crossers stay out of the sensor's way");
static_assert(kCrossSpacing > 2 * kCrosserRadiusMax, "crossers on neighbouring lines never meet");
// Movers: on their side of the centre line, clear of the drive's lane and of the parked cars, also
// at the corners, where the outer corners of the box swing out towards the centre line.
constexpr double kMoverSpeedMin = 7.0, kMoverSpeedMax = 12.0;
static_assert(kMoverOffset - 0.5 * kMoverWidth >= 0.3,
              "movers keep to their side of the centre line, away from the drive's lane");
static_assert(kMoverOffset + 0.5 * kMoverWidth + 0.15 < kParkOffset - kParkReach,
              "movers pass the parked cars with room to spare");
static_assert((kLoopCornerRadius - kMoverOffset + 0.5 * kMoverWidth) *
                          (kLoopCornerRadius - kMoverOffset + 0.5 * kMoverWidth) +
                      0.25 * kMoverLength * kMoverLength <
                  (kLoopCornerRadius - 0.1) * (kLoopCornerRadius - 0.1),
              "movers keep to their side of the centre line at the corners");
static_assert(kMoverHeight < kLowestCrown, "movers pass beneath the tree crowns");

double WrapAngle(double a) {
  a = std::fmod(a + kPi, 2 * kPi);
  if (a < 0) a += 2 * kPi;
  return a - kPi;
}

// Corners of a rectangle (centre, half extents, yaw) counter-clockwise.
std::array<Vec2, 4> RectCorners(const Vec2& c, const Vec2& h, double yaw) {
  const Vec2 u(std::cos(yaw), std::sin(yaw)), v(-std::sin(yaw), std::cos(yaw));
  return {c - h.x() * u - h.y() * v, c + h.x() * u - h.y() * v, c + h.x() * u + h.y() * v,
          c - h.x() * u + h.y() * v};
}

// True if two convex quads are at least `gap` apart along some edge normal (separating axis).
bool Separated(const std::array<Vec2, 4>& a, const std::array<Vec2, 4>& b, double gap) {
  for (const auto* poly : {&a, &b}) {
    for (int i = 0; i < 4; ++i) {
      const Vec2 e = (*poly)[(i + 1) % 4] - (*poly)[i];
      const Vec2 n = Vec2(-e.y(), e.x()).normalized();
      double amin = 1e300, amax = -1e300, bmin = 1e300, bmax = -1e300;
      for (const Vec2& p : a) {
        amin = std::min(amin, n.dot(p));
        amax = std::max(amax, n.dot(p));
      }
      for (const Vec2& p : b) {
        bmin = std::min(bmin, n.dot(p));
        bmax = std::max(bmax, n.dot(p));
      }
      if (amax + gap <= bmin || bmax + gap <= amin) return true;
    }
  }
  return false;
}

struct Footprint2d {
  std::array<Vec2, 4> corners;
};

// Distance from p to the convex quad (0 inside it).
double QuadDistance(const std::array<Vec2, 4>& q, const Vec2& p) {
  bool inside = true;
  double least = 1e300;
  for (int i = 0; i < 4; ++i) {
    const Vec2 a = q[i], b = q[(i + 1) % 4];
    const Vec2 e = b - a;
    inside = inside && e.x() * (p.y() - a.y()) - e.y() * (p.x() - a.x()) >= 0;
    const double t = std::clamp((p - a).dot(e) / e.squaredNorm(), 0.0, 1.0);
    least = std::min(least, (p - (a + t * e)).norm());
  }
  return inside ? 0.0 : least;
}

double SegmentDistance(const Vec2& a, const Vec2& b, const Vec2& p) {
  const Vec2 e = b - a;
  const double t = e.squaredNorm() > 0 ? std::clamp((p - a).dot(e) / e.squaredNorm(), 0.0, 1.0) : 0;
  return (p - (a + t * e)).norm();
}

class CityBuilder {
 public:
  CityBuilder(uint64_t seed, const BuildingOptions& buildings, const CityFeatures& features)
      : rng_(HashSeed(seed, 0xC17Eull)),
        extra_(HashSeed(seed, 0xFEA7ull)),
        buildings_(buildings),
        features_(features) {}

  Scene Build() {
    scene_.has_ground = true;
    scene_.ground_z = 0.0;
    for (int i = kMinI; i < kMaxI; ++i) {
      for (int j = kMinJ; j < kMaxJ; ++j) Block(i * kBlockPitch, j * kBlockPitch);
    }
    // Street segments between neighbouring intersections, both sides.
    for (int j = kMinJ; j <= kMaxJ; ++j) {
      for (int i = kMinI; i < kMaxI; ++i) {
        const Vec2 a(i * kBlockPitch, j * kBlockPitch);
        StreetSide(a, 0.0, +1);
        StreetSide(a, 0.0, -1);
      }
    }
    for (int i = kMinI; i <= kMaxI; ++i) {
      for (int j = kMinJ; j < kMaxJ; ++j) {
        const Vec2 a(i * kBlockPitch, j * kBlockPitch);
        StreetSide(a, kPi / 2, +1);
        StreetSide(a, kPi / 2, -1);
      }
    }
    return std::move(scene_);
  }

 private:
  // Adds the solid unless `keep` is false (the values were drawn all the same, so that what
  // follows is drawn as it would be with the solid).
  void Add(Shape shape, Material material, bool keep = true) {
    if (keep) scene_.primitives.push_back({shape, material});
  }

  // A box in a building's frame: x along its street facade, y inward (the street facade at
  // y = -half.y()), from z_min to z_max.
  static Box LocalBox(const Vec2& center, double yaw, double x0, double x1, double y0, double y1,
                      double z_min, double z_max) {
    const Vec2 u(std::cos(yaw), std::sin(yaw)), v(-std::sin(yaw), std::cos(yaw));
    return MakeBoxZ(center + 0.5 * (x0 + x1) * u + 0.5 * (y0 + y1) * v,
                    Vec2(0.5 * (x1 - x0), 0.5 * (y1 - y0)), yaw, z_min, z_max);
  }
  static std::array<Vec2, 4> BoxCorners(const Box& b) {
    return RectCorners(b.center.head<2>(), b.half.head<2>(), b.yaw);
  }

  // True if the footprint lies in [lo - grow, hi + grow] and keeps `gap` from every footprint in
  // `placed` but the one at index `own`.
  static bool Fits(const std::array<Vec2, 4>& corners, const Vec2& lo, const Vec2& hi, double grow,
                   const std::vector<Footprint2d>& placed, size_t own, double gap) {
    for (const Vec2& p : corners) {
      if (p.x() < lo.x() - grow || p.x() > hi.x() + grow || p.y() < lo.y() - grow ||
          p.y() > hi.y() + grow) {
        return false;
      }
    }
    for (size_t i = 0; i < placed.size(); ++i) {
      if (i != own && !Separated(placed[i].corners, corners, gap)) return false;
    }
    return true;
  }

  // Buildings along the four sides of the block with lower-left street corner (x0, y0).
  void Block(double x0, double y0) {
    const Vec2 lo(x0 + kFrontage, y0 + kFrontage);
    const Vec2 hi(x0 + kBlockPitch - kFrontage, y0 + kBlockPitch - kFrontage);
    std::vector<Footprint2d> placed;
    // Side k: start corner, direction along the side, inward normal.
    const std::array<Vec2, 4> starts = {Vec2(lo.x(), lo.y()), Vec2(hi.x(), lo.y()),
                                        Vec2(hi.x(), hi.y()), Vec2(lo.x(), hi.y())};
    const double side_len = hi.x() - lo.x();
    for (int k = 0; k < 4; ++k) {
      const double dir_angle = k * kPi / 2;
      const Vec2 along(std::cos(dir_angle), std::sin(dir_angle));
      const Vec2 inward(-along.y(), along.x());
      double u = rng_.Uniform(0.0, 4.0);
      while (u < side_len - 6.0) {
        if (rng_.Bernoulli(0.08)) {  // an empty lot
          u += rng_.Uniform(8.0, 16.0);
          continue;
        }
        const double width = rng_.Uniform(8.0, 25.0);
        const double depth = rng_.Uniform(8.0, 20.0);
        const double height = rng_.Uniform(buildings_.height_min, buildings_.height_max);
        const double setback = rng_.Uniform(buildings_.setback_min, buildings_.setback_max);
        const double yaw_jitter = rng_.Bernoulli(features_.yawed) ? rng_.Uniform(-35.0, 35.0) * kDeg
                                                                  : rng_.Uniform(-4.0, 4.0) * kDeg;
        const double yaw = dir_angle + yaw_jitter;
        // The set-back holds on the side streets too: a corner building starts and ends that far
        // inside the frontage.
        const double start = std::max(u, setback);
        const Vec2 half(0.5 * std::min(width, side_len - setback - start), 0.5 * depth);
        Vec2 center = starts[k] + (start + half.x()) * along + (setback + half.y()) * inward;
        // Push the rotated footprint inward until it clears the street frontage.
        auto corners = RectCorners(center, half, yaw);
        double worst = 0.0;
        for (const Vec2& p : corners)
          worst = std::min(worst, (p - starts[k]).dot(inward) - setback);
        center -= worst * inward;
        corners = RectCorners(center, half, yaw);
        bool ok = half.x() >= 3.0;
        const double inset = setback - 1e-9;  // the pushed corner lies on the line, give or take
        for (const Vec2& p : corners) {
          ok = ok && p.x() >= lo.x() + inset && p.x() <= hi.x() - inset &&
               p.y() >= lo.y() + inset && p.y() <= hi.y() - inset;
        }
        for (const Footprint2d& f : placed) ok = ok && Separated(f.corners, corners, 0.5);
        if (!ok) {
          u += 3.0;
          continue;
        }
        placed.push_back({corners});
        Add(MakeBoxZ(center, half, yaw, -kSink, height), Material::kBuilding);
        solids_.push_back(corners);
        const size_t own = placed.size() - 1;
        if (features_.annexes > 0 && extra_.Bernoulli(features_.annexes)) {
          Annex(center, half, yaw, height, lo, hi, own, &placed);
        }
        if (features_.balconies > 0 && extra_.Bernoulli(features_.balconies)) {
          Balconies(center, half, yaw, height, lo, hi, own, &placed);
        }
        u = start + 2 * half.x() + rng_.Uniform(0.5, 4.0);
      }
    }
  }

  // A lower box against the street facade or at the street corner of the building, behind the
  // frontage and 0.5 m from the block's other buildings; none where neither fits.
  void Annex(const Vec2& center, const Vec2& half, double yaw, double height, const Vec2& lo,
             const Vec2& hi, size_t own, std::vector<Footprint2d>* placed) {
    if (height < 3.0) return;
    const double top = extra_.Uniform(2.5, std::min(4.5, height - 0.5));
    const double hx = half.x(), hy = half.y();
    const double depth = extra_.Uniform(1.5, 4.0);
    const double front_width = extra_.Uniform(3.0, std::min(10.0, 2 * hx));
    const double front_x = extra_.Uniform(-hx + 0.5 * front_width, hx - 0.5 * front_width);
    const double side_len = extra_.Uniform(3.0, std::min(8.0, 2 * hy));
    const double side = extra_.Bernoulli(0.5) ? 1.0 : -1.0;
    const bool front_first = extra_.Bernoulli(0.6);
    for (int attempt = 0; attempt < 4; ++attempt) {
      const bool front = (attempt % 2 == 0) == front_first;
      const double d = attempt < 2 ? depth : 0.5 * depth;
      const Box box =
          front
              ? LocalBox(center, yaw, front_x - 0.5 * front_width, front_x + 0.5 * front_width,
                         -hy - d, -hy + kBalconyEmbed, -kSink, top)
              : LocalBox(center, yaw, side > 0 ? hx - kBalconyEmbed : -hx - d,
                         side > 0 ? hx + d : -hx + kBalconyEmbed, -hy, -hy + side_len, -kSink, top);
      const std::array<Vec2, 4> corners = BoxCorners(box);
      if (!Fits(corners, lo, hi, 1e-9, *placed, own, 0.5)) continue;
      placed->push_back({corners});
      solids_.push_back(corners);
      Add(box, Material::kBuilding);
      return;
    }
  }

  // Balcony slabs on the street facade: columns 2-4 m wide, one slab a floor from about 3 m up
  // to 1.2 m under the roof. A column that would come within 0.5 m of another building of the
  // block, or overhang the frontage by more than kMaxBalconyDepth, is left out.
  void Balconies(const Vec2& center, const Vec2& half, double yaw, double height, const Vec2& lo,
                 const Vec2& hi, size_t own, std::vector<Footprint2d>* placed) {
    const double floor_h = extra_.Uniform(2.8, 3.3);
    const double thick = extra_.Uniform(0.15, 0.2);
    const double first = kLowestBalcony + thick + extra_.Uniform(0.0, 0.5);  // slab top
    const double depth = extra_.Uniform(1.0, kMaxBalconyDepth);
    const double width = extra_.Uniform(2.0, 4.0);
    const double gap = extra_.Uniform(1.5, 4.0);
    const double span = 2 * half.x() - 1.0;
    const int columns = static_cast<int>(std::floor((span + gap) / (width + gap)));
    if (columns < 1 || first + 1.2 > height) return;
    const double x_start = -0.5 * (columns * width + (columns - 1) * gap);
    for (int c = 0; c < columns; ++c) {
      const double x0 = x_start + c * (width + gap), x1 = x0 + width;
      const Box column = LocalBox(center, yaw, x0, x1, -half.y() - depth, -half.y() + kBalconyEmbed,
                                  first - thick, first);
      const std::array<Vec2, 4> corners = BoxCorners(column);
      if (!Fits(corners, lo, hi, kMaxBalconyDepth + 1e-9, *placed, own, 0.5)) continue;
      placed->push_back({corners});
      solids_.push_back(corners);
      for (double z = first; z + 1.2 <= height; z += floor_h) {
        Add(LocalBox(center, yaw, x0, x1, -half.y() - depth, -half.y() + kBalconyEmbed, z - thick,
                     z),
            Material::kBuilding);
      }
    }
  }

  // Rows of kerb-side parked cars on one side of a street segment: stretches of [s_lo, s_hi],
  // each a row with probability parked_cars.
  std::vector<std::pair<double, double>> KerbRows(double s_lo, double s_hi) {
    std::vector<std::pair<double, double>> rows;
    if (features_.parked_cars <= 0) return rows;
    for (double s = s_lo; s < s_hi - 4.0;) {
      const double len = extra_.Uniform(8.0, 24.0);
      if (extra_.Bernoulli(features_.parked_cars)) {
        const double end = std::min(s + len, s_hi);
        if (!rows.empty() && rows.back().second >= s) {
          rows.back().second = end;
        } else {
          rows.push_back({s, end});
        }
      }
      s += len;
    }
    return rows;
  }

  // Trees, poles and parked cars on one side (+1 left, -1 right of travel along `heading`) of the
  // street segment that starts at intersection `a` and runs one block along `heading`.
  void StreetSide(const Vec2& a, double heading, int side) {
    const Vec2 along(std::cos(heading), std::sin(heading));
    const Vec2 left(-along.y(), along.x());
    const Vec2 outward = side * left;  // from the street centre line towards this side
    const double s_lo = kIntersectionClear, s_hi = kBlockPitch - kIntersectionClear;
    auto at = [&](double s, double lateral) { return Vec2(a + s * along + side * lateral * left); };

    std::vector<double> tree_s;
    canopies_.clear();
    for (double s = s_lo + rng_.Uniform(0.0, 6.0); s < s_hi; s += rng_.Uniform(10.0, 16.0)) {
      if (!rng_.Bernoulli(0.8)) continue;
      tree_s.push_back(s);
      const Vec2 trunk = at(s, kTreeOffset + rng_.Uniform(-0.2, 0.2));
      const bool canopy = features_.canopies > 0 && extra_.Bernoulli(features_.canopies) &&
                          Canopy(trunk, (trunk - a).dot(outward), outward);
      Tree(trunk, !canopy);
    }
    for (double s = s_lo + rng_.Uniform(0.0, 15.0); s < s_hi; s += rng_.Uniform(20.0, 30.0)) {
      bool clear = true;
      for (double t : tree_s) clear = clear && std::abs(t - s) > 2.5;
      if (!clear) continue;
      Pole(at(s, kPoleOffset), -outward);
    }
    const std::vector<std::pair<double, double>> rows = KerbRows(s_lo, s_hi);
    // The scattered cars, but where the kerb has rows.
    for (double s = s_lo; s < s_hi - 5.0;) {
      if (rng_.Bernoulli(0.35)) {
        const double length = rng_.Uniform(3.9, 4.8);
        if (s + length > s_hi) break;
        const double yaw =
            heading + (rng_.Bernoulli(0.5) ? 0.0 : kPi) + rng_.Uniform(-2.0, 2.0) * kDeg;
        bool keep = true;
        for (const auto& [r0, r1] : rows) keep = keep && (s + length + 1.0 < r0 || s > r1 + 1.0);
        Car(at(s + 0.5 * length, kParkOffset), length, yaw, keep);
        s += length + rng_.Uniform(1.0, 4.0);
      } else {
        s += rng_.Uniform(4.0, 10.0);
      }
    }
    for (const auto& [r0, r1] : rows) {
      for (double s = r0 + extra_.Uniform(0.0, 1.5);;) {
        const double length = KerbCar(heading, [&](double lateral, double len) {
          return s + len <= r1 ? std::optional<Vec2>(at(s + 0.5 * len, lateral)) : std::nullopt;
        });
        if (length <= 0) break;
        s += length + extra_.Uniform(0.5, 3.0);
      }
    }
  }

  // A car parked at the kerb, its kerb side kKerbGapMin..kKerbGapMax from the kerb line:
  // place(lateral, length) gives its centre, or nothing where it does not fit (then no car is
  // added and the result is 0). Returns its length.
  template <typename Place>
  double KerbCar(double heading, Place place) {
    const double kind = extra_.Uniform();
    double length, width, body_top, roof, cabin_share, back;
    if (kind < 0.6) {  // sedan, hatchback
      length = extra_.Uniform(3.9, 4.9);
      width = extra_.Uniform(1.72, 1.85);
      body_top = extra_.Uniform(0.75, 0.95);
      roof = extra_.Uniform(1.38, 1.52);
      cabin_share = extra_.Uniform(0.45, 0.58);
      back = extra_.Uniform(0.1, 0.4);
    } else if (kind < 0.85) {  // SUV
      length = extra_.Uniform(4.3, 4.9);
      width = extra_.Uniform(1.8, kKerbCarWidth);
      body_top = extra_.Uniform(0.95, 1.1);
      roof = extra_.Uniform(1.62, 1.85);
      cabin_share = extra_.Uniform(0.55, 0.68);
      back = extra_.Uniform(0.2, 0.4);
    } else {  // van: a short hood, the cabin to the back
      length = extra_.Uniform(4.8, kKerbCarLength);
      width = extra_.Uniform(1.85, kKerbCarWidth);
      body_top = extra_.Uniform(0.95, 1.15);
      roof = extra_.Uniform(1.9, 2.05);
      cabin_share = extra_.Uniform(0.72, 0.82);
      back = 0.5 * length * (1.0 - cabin_share) - 0.02;
    }
    const double yaw = heading + (extra_.Bernoulli(0.5) ? 0.0 : kPi) +
                       extra_.Uniform(-kKerbYawDeg, kKerbYawDeg) * kDeg;
    const double lateral = kRoadHalfWidth - extra_.Uniform(kKerbGapMin, kKerbGapMax) - 0.5 * width;
    const std::optional<Vec2> c = place(lateral, length);
    if (!c) return 0.0;
    Add(MakeBoxZ(*c, Vec2(0.5 * length, 0.5 * width), yaw, -kSink, body_top), Material::kCar);
    const double cabin_len = length * cabin_share;
    back = std::min(back, 0.5 * (length - cabin_len) - 0.02);
    const Vec2 shift = -back * Vec2(std::cos(yaw), std::sin(yaw));
    Add(MakeBoxZ(*c + shift, Vec2(0.5 * cabin_len, 0.5 * width - 0.08), yaw, body_top - 0.02, roof),
        Material::kCar);
    return length;
  }

  // A broad, low crown over the tree at `trunk`, `lateral` metres from the street centre line
  // (`outward` points away from it): a disc with a cone on top, as wide as the room allows
  // between the road (kCanopyRoadEdge) and the buildings (kCanopyGap). False, and nothing added,
  // where even kCanopyRadiusLeast does not fit.
  bool Canopy(const Vec2& trunk, double lateral, const Vec2& outward) {
    const double trunk_r = extra_.Uniform(0.15, 0.25);
    const double want = extra_.Uniform(kCanopyRadiusMin, kCanopyRadiusMax);
    const double base = extra_.Uniform(kCanopyBaseMin, kCanopyBaseMax);
    const double rim = extra_.Uniform(0.8, 1.6);
    const double cone = extra_.Uniform(1.2, 2.5);
    for (double r = want; r >= kCanopyRadiusLeast; r -= 0.1) {
      const double shift = std::max(0.0, kCanopyRoadEdge + r - lateral);
      if (shift > r - trunk_r - 0.2) continue;  // the trunk stays well inside the disc
      const Vec2 c = trunk + shift * outward;
      bool clear = true;
      for (const auto& q : solids_) clear = clear && QuadDistance(q, c) >= r + kCanopyGap;
      if (!clear) continue;
      Add(Cylinder{trunk, trunk_r, -kSink, base + 0.1}, Material::kTree);
      Add(Cylinder{c, r, base, base + rim}, Material::kTree);
      // The cone starts 2 cm inside the disc so that the union is closed.
      Add(Cone{c, r - 0.02, base + rim - 0.02, base + rim + cone}, Material::kTree);
      canopies_.push_back({c, r});
      return true;
    }
    return false;
  }

  void Tree(const Vec2& p, bool keep) {
    const double trunk_r = rng_.Uniform(0.12, 0.25);
    if (rng_.Bernoulli(0.6)) {  // broadleaf: sphere crown
      const double r = rng_.Uniform(1.4, 2.2);
      const double bottom = rng_.Uniform(2.4, 3.2);
      const Vec3 c(p.x(), p.y(), bottom + r);
      // The trunk ends 5 cm inside the crown so that the union is closed.
      const double top = c.z() - std::sqrt(r * r - trunk_r * trunk_r) + 0.05;
      Add(Cylinder{p, trunk_r, -kSink, top}, Material::kTree, keep);
      Add(Sphere{c, r}, Material::kTree, keep);
    } else {  // conifer: cone crown
      const double r = rng_.Uniform(1.2, 1.8);
      const double base = rng_.Uniform(kLowestCrown, 2.8);
      const double h = rng_.Uniform(4.0, 7.0);
      Add(Cylinder{p, trunk_r, -kSink, base + 0.1}, Material::kTree, keep);
      Add(Cone{p, r, base, base + h}, Material::kTree, keep);
    }
  }

  // A street light: a thin pole, and on most of them an arm reaching over the road (`to_road`).
  // None where it would come within kCanopyGap of a broad crown.
  void Pole(const Vec2& p, const Vec2& to_road) {
    const double r = rng_.Uniform(0.08, 0.12);
    const double h = rng_.Uniform(5.0, 9.0);
    const bool arm = rng_.Bernoulli(0.7);
    const double len = arm ? rng_.Uniform(1.2, 2.4) : 0.0;
    bool keep = true;
    for (const auto& [c, radius] : canopies_) {
      keep = keep && SegmentDistance(p, p + to_road * len, c) >= radius + kCanopyGap + r;
    }
    Add(Cylinder{p, r, -kSink, h}, Material::kPole, keep);
    if (arm) {
      const Vec2 c = p + to_road * (0.5 * len);
      const double yaw = std::atan2(to_road.y(), to_road.x());
      Add(MakeBoxZ(c, Vec2(0.5 * len + r, 0.08), yaw, h - 0.3, h - 0.15), Material::kPole, keep);
    }
  }

  void Car(const Vec2& c, double length, double yaw, bool keep) {
    const double width = rng_.Uniform(1.7, 1.9);
    if (rng_.Bernoulli(0.15)) {  // van
      Add(MakeBoxZ(c, Vec2(0.5 * length, 0.5 * width), yaw, -kSink, rng_.Uniform(1.9, 2.3)),
          Material::kCar, keep);
      return;
    }
    const double body_top = rng_.Uniform(0.9, 1.1);
    Add(MakeBoxZ(c, Vec2(0.5 * length, 0.5 * width), yaw, -kSink, body_top), Material::kCar, keep);
    const double cabin_len = length * rng_.Uniform(0.45, 0.6);
    const Vec2 back = -rng_.Uniform(0.1, 0.4) * Vec2(std::cos(yaw), std::sin(yaw));
    Add(MakeBoxZ(c + back, Vec2(0.5 * cabin_len, 0.5 * width - 0.08), yaw, body_top - 0.02,
                 body_top + rng_.Uniform(0.45, 0.6)),
        Material::kCar, keep);
  }

  Rng rng_;    // today's city: buildings, trees, poles and scattered cars
  Rng extra_;  // what CityFeatures adds, drawn apart so that today's draws stay as they were
  BuildingOptions buildings_;
  CityFeatures features_;
  Scene scene_;
  // Footprints of buildings, annexes and balconies; broad crowns of the current street side.
  std::vector<std::array<Vec2, 4>> solids_;
  std::vector<std::pair<Vec2, double>> canopies_;
};

// The stretch of drive arc length [lo, hi] that crossing lines and mover meetings are spread
// over: from kMovingAhead ahead of the first pose to the last pose (at least 10 m, at most a lap).
struct DriveSpan {
  double lo = 0.0, hi = 0.0;
};

DriveSpan DrivenSpan(const City& city, const CityOptions& options) {
  DriveSpan span;
  span.lo = city.start_s + kMovingAhead;
  const double last = city.start_s + std::max(options.frames - 1, 0) * options.step;
  span.hi = std::clamp(last, span.lo + 10.0, span.lo + city.drive_path.length());
  return span;
}

// The street at drive arc length s: the point of its centre line beside the drive, its direction
// and the unit vector across it towards the drive's lane. False on the corner arcs and within
// kIntersectionClear (along the street) of an intersection.
bool StreetAt(const LoopPath& drive, double s, Vec2* center, Vec2* street, Vec2* across) {
  Vec2 p;
  double heading;
  drive.Eval(s, &p, &heading);
  if (std::abs(std::sin(2 * heading)) > 1e-9) return false;  // on a corner arc
  *street = std::abs(std::cos(heading)) > 0.5 ? Vec2(std::cos(heading) > 0 ? 1 : -1, 0)
                                              : Vec2(0, std::sin(heading) > 0 ? 1 : -1);
  *across = Vec2(street->y(), -street->x());  // right of travel: the lane is right of the centre
  *center = p - kLaneOffset * *across;
  const double along = street->x() != 0 ? center->x() : center->y();
  const double u = along - kBlockPitch * std::floor(along / kBlockPitch);
  return u >= kIntersectionClear && u <= kBlockPitch - kIntersectionClear;
}

// The footprints (xy bounds) of the static solids a crosser could walk into.
struct Obstacle {
  Vec2 lo, hi;
  bool car;
};

std::vector<Obstacle> CrossingObstacles(const Scene& scene) {
  std::vector<Obstacle> out;
  for (const Primitive& p : scene.primitives) {
    const Aabb b = Bounds(p.shape);
    if (!b.IsFinite() || b.min.z() > kCrosserHeightMax + 0.1) continue;
    out.push_back({b.min.head<2>(), b.max.head<2>(), p.material == Material::kCar});
  }
  return out;
}

// How much room a crossing line has to spare: the least, over the obstacles, of its distance to
// one less what it must keep (>= 0: the line is clear), keeping kCrossCarGap from parked cars
// (`wide`) or only kCrossCarGapMin (`tight`: between parked cars); kCrossSolidGap from the rest.
struct Room {
  double wide = -1e300, tight = -1e300;  // off the street: never clear
};

// The room of the crossing line through `center` along `across`. The line's own bounding box
// stands in for it (exact here: crossing lines are axis-aligned).
Room CrossingRoom(const std::vector<Obstacle>& obstacles, const Vec2& center, const Vec2& across) {
  const Vec2 a = center - kCrossHalfSpan * across, b = center + kCrossHalfSpan * across;
  const Vec2 lo = a.cwiseMin(b), hi = a.cwiseMax(b);
  Room room{1e300, 1e300};
  for (const Obstacle& o : obstacles) {
    const double d = (o.lo - hi).cwiseMax(lo - o.hi).cwiseMax(Vec2::Zero()).norm();
    room.wide = std::min(room.wide, d - (o.car ? kCrossCarGap : kCrossSolidGap));
    room.tight = std::min(room.tight, d - (o.car ? kCrossCarGapMin : kCrossSolidGap));
  }
  return room;
}

// How well a crosser's phase suits the run: *gap receives the least lateral distance between the
// crosser and the sensor's lane (at +kLaneOffset) while the sensor is within kPassReach of its
// crossing line, over the first passes of the run (a run of many laps is checked for its first
// eight); the result is true if the crosser is on the road, in the run, at some time while the
// sensor drives towards its line from kSeenFrom to kSeenTo metres away (or if the run never sees
// that).
constexpr double kSeenFrom = 30.0, kSeenTo = 4.0;
bool CrossesInView(const Crosser& c, const City& city, const CityOptions& options, double* gap) {
  const double speed = options.step * kFrameRateHz;  // the sensor's, m/s
  const double last = city.start_s + std::max(options.frames - 1, 0) * options.step;
  const double lap = city.drive_path.length();
  *gap = 1e300;
  for (int n = 0; n < 8; ++n) {
    const double s = c.drive_s + n * lap;
    if (s - kPassReach > last) break;
    for (int i = 0; i <= 32; ++i) {
      const double t = (s - city.start_s + kPassReach * (i / 16.0 - 1.0)) / speed;
      *gap = std::min(*gap, std::abs(CrosserLateral(c, t) - kLaneOffset));
    }
  }
  const double from = std::max(c.drive_s - kSeenFrom, city.start_s);
  const double to = std::min(c.drive_s - kSeenTo, last);
  bool seen = to < from;
  for (int i = 0; !seen && i <= 32; ++i) {
    const double t = (from + (to - from) * i / 32.0 - city.start_s) / speed;
    seen = std::abs(CrosserLateral(c, t)) < kRoadHalfWidth - 0.5;
  }
  return seen;
}

// Crossing lines spread evenly (with some jitter) over the straights of the driven span, each
// moved to the nearest clear line not taken by another crosser: one that keeps kCrossCarGap from
// the parked cars if the span has one left, else one between parked cars, else the nearest such
// line beyond the span (a line with the most room when no line at all is clear).
void PlaceCrossers(const CityOptions& options, City* city) {
  Rng rng(HashSeed(options.seed, 0xC2055ull));
  const DriveSpan span = DrivenSpan(*city, options);
  const std::vector<Obstacle> obstacles = CrossingObstacles(city->scene);
  constexpr double kCandidateStep = 0.1;
  const int n = static_cast<int>(city->drive_path.length() / kCandidateStep);
  std::vector<Room> room(n);  // over [span.lo, span.lo + lap)
  for (int i = 0; i < n; ++i) {
    Vec2 center, street, across;
    if (StreetAt(city->drive_path, span.lo + i * kCandidateStep, &center, &street, &across)) {
      room[i] = CrossingRoom(obstacles, center, across);
    }
  }
  const int in_span = std::min(n, static_cast<int>((span.hi - span.lo) / kCandidateStep) + 1);
  const int spacing = static_cast<int>(std::lround(kCrossSpacing / kCandidateStep));
  std::vector<bool> taken(n, false);
  // The lines on straights, away from intersections, in the span: the targets are spread evenly
  // over these (over the whole span when there are none).
  std::vector<int> on_street;
  for (int i = 0; i < in_span; ++i) {
    if (room[i].tight > -1e300) on_street.push_back(i);
  }
  const int count = options.crossers;
  for (int k = 0; k < count; ++k) {
    const double q = (k + 0.5 + rng.Uniform(-0.3, 0.3)) / count;  // in (0, 1)
    const int want =
        on_street.empty()
            ? std::min(in_span - 1, static_cast<int>(q * (span.hi - span.lo) / kCandidateStep))
            : on_street[std::min(on_street.size() - 1, static_cast<size_t>(q * on_street.size()))];
    // The nearest candidate to `want` in [0, end) that passes `ok`, or -1.
    auto nearest = [&](int end, auto ok) {
      for (int d = 0; d < n; ++d) {
        for (int i : {want - d, want + d}) {
          if (i >= 0 && i < end && ok(i)) return i;
        }
      }
      return -1;
    };
    auto wide = [&](int i) { return room[i].wide >= 0 && !taken[i]; };
    auto tight = [&](int i) { return room[i].tight >= 0 && !taken[i]; };
    int pick = nearest(in_span, wide);
    if (pick < 0) pick = nearest(in_span, tight);
    if (pick < 0) pick = nearest(n, tight);
    if (pick < 0) pick = nearest(n, [&](int i) { return room[i].tight >= 0; });
    if (pick < 0) {
      pick = static_cast<int>(
          std::max_element(room.begin(), room.end(),
                           [](const Room& a, const Room& b) { return a.tight < b.tight; }) -
          room.begin());
    }
    for (int i = std::max(0, pick - spacing); i <= std::min(n - 1, pick + spacing); ++i) {
      taken[i] = true;
    }
    Crosser c;
    c.drive_s = span.lo + pick * kCandidateStep;
    StreetAt(city->drive_path, c.drive_s, &c.center, &c.street, &c.across);
    c.half_span = kCrossHalfSpan;
    c.speed = rng.Uniform(kCrosserSpeedMin, kCrosserSpeedMax);
    c.radius = rng.Uniform(kCrosserRadiusMin, kCrosserRadiusMax);
    c.height = rng.Uniform(kCrosserHeightMin, kCrosserHeightMax);
    // A random phase that keeps the crosser out of the sensor's way whenever it passes, and has it
    // on the road ahead of the sensor as it comes (the best of a few draws where no draw does).
    double best_phase = 0.0, best_score = -1.0;
    for (int attempt = 0; attempt < 64 && best_score < 3.0; ++attempt) {
      c.phase = rng.Uniform();
      double gap;
      const bool seen = CrossesInView(c, *city, options, &gap);
      // Out of the sensor's way first, then in view.
      const double score = (gap >= kPassGap ? 2.0 : gap / kPassGap) + (seen ? 1.0 : 0.0);
      if (score > best_score) {
        best_score = score;
        best_phase = c.phase;
      }
    }
    c.phase = best_phase;
    city->crossers.push_back(c);
  }
}

// Movers drive clockwise kMoverOffset inside the street centre lines, each timed to meet the
// sensor at its own place, the places spread evenly (with some jitter) over the driven span.
void PlaceMovers(const CityOptions& options, const Vec2& loop_center, const Vec2& loop_half,
                 City* city) {
  Rng rng(HashSeed(options.seed, 0x3017E5ull));
  const DriveSpan span = DrivenSpan(*city, options);
  const LoopPath path(loop_center, loop_half - Vec2::Constant(kMoverOffset),
                      kLoopCornerRadius - kMoverOffset);
  const int count = options.movers;
  for (int k = 0; k < count; ++k) {
    const double meet_s =
        span.lo + (k + 0.5 + rng.Uniform(-0.3, 0.3)) * (span.hi - span.lo) / count;
    Mover m;
    m.path = path;
    m.speed = rng.Uniform(kMoverSpeedMin, kMoverSpeedMax);
    m.size = Vec3(kMoverLength, kMoverWidth, kMoverHeight);
    Vec2 p;
    double heading;
    city->drive_path.Eval(meet_s, &p, &heading);
    const double t_meet = (meet_s - city->start_s) / (options.step * kFrameRateHz);
    m.s0 = std::fmod(path.Nearest(p) + m.speed * t_meet, path.length());
    city->movers.push_back(m);
  }
}

}  // namespace

LoopPath::LoopPath(const Vec2& center, const Vec2& half_extent, double corner_radius)
    : center_(center), half_(half_extent), radius_(corner_radius) {
  straight_x_ = 2 * (half_.x() - radius_);
  straight_y_ = 2 * (half_.y() - radius_);
  arc_ = 0.5 * kPi * radius_;
  length_ = 2 * straight_x_ + 2 * straight_y_ + 4 * arc_;
}

void LoopPath::Segments(std::array<Vec2, 4>* straight_start,
                        std::array<Vec2, 4>* arc_center) const {
  const double cx = center_.x(), cy = center_.y(), a = half_.x(), b = half_.y(), r = radius_;
  *straight_start = {Vec2(cx - a + r, cy - b), Vec2(cx + a, cy - b + r), Vec2(cx + a - r, cy + b),
                     Vec2(cx - a, cy + b - r)};
  *arc_center = {Vec2(cx + a - r, cy - b + r), Vec2(cx + a - r, cy + b - r),
                 Vec2(cx - a + r, cy + b - r), Vec2(cx - a + r, cy - b + r)};
}

void LoopPath::Eval(double s, Vec2* position, double* heading) const {
  s = std::fmod(s, length_);
  if (s < 0) s += length_;
  const double r = radius_;
  // Straights: start point and heading; arcs: centre and start angle.
  std::array<Vec2, 4> straight_start, arc_center;
  Segments(&straight_start, &arc_center);
  for (int k = 0; k < 4; ++k) {
    const double dir = k * kPi / 2;
    const double len = (k % 2 == 0) ? straight_x_ : straight_y_;
    if (s <= len) {
      *position = straight_start[k] + s * Vec2(std::cos(dir), std::sin(dir));
      *heading = WrapAngle(dir);
      return;
    }
    s -= len;
    if (s <= arc_ || k == 3) {
      const double theta = dir - kPi / 2 + std::min(s, arc_) / r;
      *position = arc_center[k] + r * Vec2(std::cos(theta), std::sin(theta));
      *heading = WrapAngle(theta + kPi / 2);
      return;
    }
    s -= arc_;
  }
}

double LoopPath::Nearest(const Vec2& p) const {
  std::array<Vec2, 4> straight_start, arc_center;
  Segments(&straight_start, &arc_center);
  double best = 1e300, best_s = 0.0, base = 0.0;
  auto consider = [&](const Vec2& q, double s) {
    const double d = (p - q).squaredNorm();
    if (d < best) {
      best = d;
      best_s = s;
    }
  };
  for (int k = 0; k < 4; ++k) {
    const double dir = k * kPi / 2;
    const double len = (k % 2 == 0) ? straight_x_ : straight_y_;
    const Vec2 u(std::cos(dir), std::sin(dir));
    const double along = std::clamp((p - straight_start[k]).dot(u), 0.0, len);
    consider(straight_start[k] + along * u, base + along);
    base += len;
    const double start = dir - kPi / 2;
    const Vec2 q = p - arc_center[k];
    const double turned = std::clamp(WrapAngle(std::atan2(q.y(), q.x()) - start), 0.0, kPi / 2);
    consider(arc_center[k] + radius_ * Vec2(std::cos(start + turned), std::sin(start + turned)),
             base + turned * radius_);
    base += arc_;
  }
  return best_s < length_ ? best_s : best_s - length_;
}

absl::Status ValidateCityOptions(const CityOptions& options) {
  for (const auto& [name, value] : {std::pair<const char*, int>{"walkers", options.walkers},
                                    {"crossers", options.crossers},
                                    {"movers", options.movers},
                                    {"frames", options.frames}}) {
    if (value < 0) {
      return absl::InvalidArgumentError(
          absl::StrCat("CityOptions.", name, " must be >= 0, got ", value));
    }
  }
  if (!(std::isfinite(options.step) && options.step > 0)) {
    return absl::InvalidArgumentError(
        absl::StrCat("CityOptions.step must be finite and > 0, got ", options.step));
  }
  const BuildingOptions& b = options.buildings;
  auto check = [](const char* range, double min, double max, double lo, double hi) {
    if (std::isfinite(min) && std::isfinite(max) && lo <= min && min <= max && max <= hi) {
      return absl::OkStatus();
    }
    return absl::InvalidArgumentError(absl::StrFormat(
        "CityOptions.buildings.%s_min, %s_max must satisfy %g <= min <= max <= %g, got %g, %g",
        range, range, lo, hi, min, max));
  };
  RIM_RETURN_IF_ERROR(check("setback", b.setback_min, b.setback_max, 0.0, kMaxBuildingSetback));
  RIM_RETURN_IF_ERROR(
      check("height", b.height_min, b.height_max, kMinBuildingHeight, kMaxBuildingHeight));
  const CityFeatures& f = options.features;
  for (const auto& [name, value] : {std::pair<const char*, double>{"parked_cars", f.parked_cars},
                                    {"balconies", f.balconies},
                                    {"annexes", f.annexes},
                                    {"yawed", f.yawed},
                                    {"canopies", f.canopies}}) {
    if (!(std::isfinite(value) && value >= 0.0 && value <= 1.0)) {
      return absl::InvalidArgumentError(
          absl::StrCat("CityOptions.features.", name, " must be in [0, 1], got ", value));
    }
  }
  return absl::OkStatus();
}

City GenerateCity(const CityOptions& options) {
  City city;
  city.scene = CityBuilder(options.seed, options.buildings, options.features).Build();
  const Vec2 loop_center(kBlockPitch, 0.5 * kBlockPitch);
  const Vec2 loop_half(kBlockPitch, 0.5 * kBlockPitch);
  // Counter-clockwise travel keeps the right-hand lane on the outside of the loop.
  city.drive_path = LoopPath(loop_center, loop_half + Vec2::Constant(kLaneOffset),
                             kLoopCornerRadius + kLaneOffset);
  // Start 50 m before the first corner, so that even short runs include a turn.
  city.start_s = 2 * (loop_half.x() - kLoopCornerRadius) - 50.0;

  // Walkers: a separate random stream, so the static scene is the same with or without them.
  Rng rng(HashSeed(options.seed, 0xAA1Cull));
  for (int k = 0; k < options.walkers; ++k) {
    Walker w;
    const double lateral = rng.Uniform(kWalkerMin, kWalkerMax);
    const bool inside = rng.Bernoulli(0.5);  // inner or outer sidewalk of the loop
    const double offset = inside ? -lateral : lateral;
    w.path = LoopPath(loop_center, loop_half + Vec2::Constant(offset), kLoopCornerRadius + offset);
    w.s0 = rng.Uniform(0.0, w.path.length());
    w.speed = rng.Uniform(0.8, 1.6) * (rng.Bernoulli(0.5) ? 1.0 : -1.0);
    w.radius = rng.Uniform(0.22, 0.28);
    w.height = rng.Uniform(1.6, 1.9);
    city.walkers.push_back(w);
  }
  // Crossers and movers: a random stream each, too.
  PlaceCrossers(options, &city);
  PlaceMovers(options, loop_center, loop_half, &city);
  return city;
}

std::vector<Eigen::Isometry3d> CityTrajectory(const City& city, int frames, double step,
                                              double sensor_height) {
  std::vector<Eigen::Isometry3d> poses;
  poses.reserve(std::max(frames, 0));
  for (int k = 0; k < frames; ++k) {
    Vec2 p;
    double heading;
    city.drive_path.Eval(city.start_s + k * step, &p, &heading);
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = Eigen::AngleAxisd(heading, Vec3::UnitZ()).toRotationMatrix();
    pose.translation() = Vec3(p.x(), p.y(), city.scene.ground_z + sensor_height);
    poses.push_back(pose);
  }
  return poses;
}

std::vector<Primitive> WalkersAt(const City& city, double t) {
  std::vector<Primitive> out;
  out.reserve(city.walkers.size());
  for (const Walker& w : city.walkers) {
    Vec2 p;
    double heading;
    w.path.Eval(w.s0 + w.speed * t, &p, &heading);
    out.push_back(
        {Cylinder{p, w.radius, city.scene.ground_z - kSink, w.height}, Material::kPerson});
  }
  return out;
}

double CrosserLateral(const Crosser& crosser, double t) {
  const double h = crosser.half_span;
  double u = std::fmod(crosser.phase + t * crosser.speed / (4 * h), 1.0);
  if (u < 0) u += 1.0;
  return u < 0.5 ? -h + 4 * h * u : 3 * h - 4 * h * u;
}

std::vector<Primitive> CrossersAt(const City& city, double t) {
  std::vector<Primitive> out;
  out.reserve(city.crossers.size());
  for (const Crosser& c : city.crossers) {
    const Vec2 p = c.center + CrosserLateral(c, t) * c.across;
    out.push_back(
        {Cylinder{p, c.radius, city.scene.ground_z - kSink, city.scene.ground_z + c.height},
         Material::kPerson});
  }
  return out;
}

std::vector<Primitive> MoversAt(const City& city, double t) {
  std::vector<Primitive> out;
  out.reserve(city.movers.size());
  for (const Mover& m : city.movers) {
    Vec2 p;
    double heading;
    m.path.Eval(m.s0 - m.speed * t, &p, &heading);
    out.push_back({MakeBoxZ(p, 0.5 * m.size.head<2>(), WrapAngle(heading + kPi),
                            city.scene.ground_z - kSink, city.scene.ground_z + m.size.z()),
                   Material::kCar});
  }
  return out;
}

std::vector<Primitive> MovingAt(const City& city, double t) {
  std::vector<Primitive> out = WalkersAt(city, t);
  const std::vector<Primitive> crossers = CrossersAt(city, t), movers = MoversAt(city, t);
  out.insert(out.end(), crossers.begin(), crossers.end());
  out.insert(out.end(), movers.begin(), movers.end());
  return out;
}

}  // namespace rim::sim
