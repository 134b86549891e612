// The static city (CityBuilder): a grid of streets, the buildings of every block with their
// balconies and annexes, and along each street side its trees (some with broad canopies), street
// lights and parked cars.
#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <utility>
#include <vector>

#include "sim/city.h"
#include "sim/city_internal.h"
#include "sim/rng.h"

namespace rim::sim {
using namespace city_internal;
namespace {

constexpr double kDeg = kPi / 180.0;

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

}  // namespace

Scene city_internal::BuildCityScene(uint64_t seed, const BuildingOptions& buildings,
                                    const CityFeatures& features) {
  return CityBuilder(seed, buildings, features).Build();
}

}  // namespace rim::sim
