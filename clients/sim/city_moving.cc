// What moves in the city: the LoopPath that the sensor, the walkers and the movers follow; the
// crossers and the movers laid out along the stretch the run drives; and every moving thing as
// solids at a given time.
#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "sim/city.h"
#include "sim/city_internal.h"
#include "sim/rng.h"

namespace rim::sim {
using namespace city_internal;
namespace {

double WrapAngle(double a) {
  a = std::fmod(a + kPi, 2 * kPi);
  if (a < 0) a += 2 * kPi;
  return a - kPi;
}

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

// Crossing lines spread evenly (with some jitter) over the straights of the driven span, each
// moved to the nearest clear line not taken by another crosser: one that keeps kCrossCarGap from
// the parked cars if the span has one left, else one between parked cars, else the nearest such
// line beyond the span (a line with the most room when no line at all is clear).
void city_internal::PlaceCrossers(const CityOptions& options, City* city) {
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
void city_internal::PlaceMovers(const CityOptions& options, const Vec2& loop_center,
                                const Vec2& loop_half, City* city) {
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
