#include "ground_texture_bow/core/geometry.h"

#include <cmath>

namespace gtbow {

Vec2 FloorFromImage(const Pose2D& p, const ImageGeometry& g, Vec2 pixel) {
  const double du = (pixel.x - 0.5 * (g.width - 1)) * g.meters_per_pixel;
  const double dv = (pixel.y - 0.5 * (g.height - 1)) * g.meters_per_pixel;
  const double c = std::cos(p.theta);
  const double s = std::sin(p.theta);
  return {p.x + c * du - s * dv, p.y + s * du + c * dv};
}

Vec2 ImageFromFloor(const Pose2D& p, const ImageGeometry& g, Vec2 floor) {
  const double dx = floor.x - p.x;
  const double dy = floor.y - p.y;
  const double c = std::cos(p.theta);
  const double s = std::sin(p.theta);
  // R(theta)^T * d, back to pixels.
  const double du = (c * dx + s * dy) / g.meters_per_pixel;
  const double dv = (-s * dx + c * dy) / g.meters_per_pixel;
  return {du + 0.5 * (g.width - 1), dv + 0.5 * (g.height - 1)};
}

std::array<Vec2, 4> Footprint(const Pose2D& p, const ImageGeometry& g) {
  // The footprint is W*s by H*s metres centred on (x, y): its corners lie half a pixel
  // beyond the outermost pixel centres.
  const double hw = 0.5 * g.width * g.meters_per_pixel;
  const double hh = 0.5 * g.height * g.meters_per_pixel;
  const double c = std::cos(p.theta);
  const double s = std::sin(p.theta);
  // Counter-clockwise in a right-handed frame (x right, y up); with the image convention
  // (v down) the order still yields positive area because R is a proper rotation.
  const std::array<Vec2, 4> local = {{{-hw, -hh}, {hw, -hh}, {hw, hh}, {-hw, hh}}};
  std::array<Vec2, 4> out{};
  for (size_t i = 0; i < 4; ++i) {
    out[i] = {p.x + c * local[i].x - s * local[i].y, p.y + s * local[i].x + c * local[i].y};
  }
  return out;
}

double PolygonArea(const std::vector<Vec2>& poly) {
  double a = 0.0;
  const size_t n = poly.size();
  for (size_t i = 0; i < n; ++i) {
    const Vec2& p = poly[i];
    const Vec2& q = poly[(i + 1) % n];
    a += p.x * q.y - q.x * p.y;
  }
  return 0.5 * a;
}

namespace {

double Cross(Vec2 a, Vec2 b, Vec2 p) {
  return (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x);
}

Vec2 LineIntersection(Vec2 p, Vec2 q, Vec2 a, Vec2 b) {
  const double cp = Cross(a, b, p);
  const double cq = Cross(a, b, q);
  const double t = cp / (cp - cq);
  return {p.x + t * (q.x - p.x), p.y + t * (q.y - p.y)};
}

}  // namespace

std::vector<Vec2> ConvexIntersection(const std::vector<Vec2>& subject,
                                     const std::vector<Vec2>& clip) {
  std::vector<Vec2> output = subject;
  const size_t n = clip.size();
  for (size_t i = 0; i < n && !output.empty(); ++i) {
    const Vec2 a = clip[i];
    const Vec2 b = clip[(i + 1) % n];
    std::vector<Vec2> input;
    input.swap(output);
    for (size_t j = 0; j < input.size(); ++j) {
      const Vec2 cur = input[j];
      const Vec2 prev = input[(j + input.size() - 1) % input.size()];
      const bool cur_in = Cross(a, b, cur) >= 0.0;
      const bool prev_in = Cross(a, b, prev) >= 0.0;
      if (cur_in) {
        if (!prev_in) output.push_back(LineIntersection(prev, cur, a, b));
        output.push_back(cur);
      } else if (prev_in) {
        output.push_back(LineIntersection(prev, cur, a, b));
      }
    }
  }
  return output;
}

double Overlap(const Pose2D& query, const Pose2D& database, const ImageGeometry& g) {
  // Quick reject: centres further apart than the footprint diagonal cannot overlap.
  const double diag = std::hypot(g.width, g.height) * g.meters_per_pixel;
  if (std::hypot(query.x - database.x, query.y - database.y) >= diag) return 0.0;
  const auto q = Footprint(query, g);
  const auto d = Footprint(database, g);
  const std::vector<Vec2> qv(q.begin(), q.end());
  const std::vector<Vec2> dv(d.begin(), d.end());
  const double area_q = std::abs(PolygonArea(qv));
  if (area_q <= 0.0) return 0.0;
  const auto inter = ConvexIntersection(qv, dv);
  if (inter.size() < 3) return 0.0;
  const double ratio = std::abs(PolygonArea(inter)) / area_q;
  return ratio > 1.0 ? 1.0 : ratio;
}

bool IsRelevant(const Pose2D& query, const Pose2D& database, const ImageGeometry& g) {
  return Overlap(query, database, g) >= kRelevantOverlap;
}

Pose2D Compose(const Pose2D& a, const Pose2D& b) {
  const double c = std::cos(a.theta), s = std::sin(a.theta);
  return {a.x + c * b.x - s * b.y, a.y + s * b.x + c * b.y, a.theta + b.theta};
}

Pose2D Inverse(const Pose2D& p) {
  const double c = std::cos(p.theta), s = std::sin(p.theta);
  return {-(c * p.x + s * p.y), s * p.x - c * p.y, -p.theta};
}

double WrapAngle(double angle) {
  angle = std::remainder(angle, 2.0 * M_PI);
  if (angle <= -M_PI) angle += 2.0 * M_PI;
  return angle;
}

}  // namespace gtbow
