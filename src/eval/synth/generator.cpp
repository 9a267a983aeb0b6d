#include "ground_texture_bow/eval/synth/generator.h"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <functional>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <thread>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/parallel.h"
#include "ground_texture_bow/core/progress.h"
#include "noise.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace synth {

namespace {

constexpr uint64_t kDatabaseVisit = 1;
constexpr uint64_t kTrainVisit = 2;
constexpr uint64_t kDriveVisit = 3;
constexpr uint64_t kLaterDriveVisit = 50;  // + k for the k-th later drive
constexpr uint64_t kFirstQueryVisit = 100;
constexpr uint64_t kFirstSessionVisit = 300;  // + k for the k-th maintenance session

// FNV-1a: a stable string hash (std::hash may differ between standard libraries).
uint64_t Fnv1a(const std::string& s) {
  uint64_t h = 0xcbf29ce484222325ULL;
  for (unsigned char c : s) {
    h ^= c;
    h *= 0x100000001b3ULL;
  }
  return h;
}

double Round7(double v) { return std::round(v * 1e7) / 1e7; }

Pose2D Rounded(Pose2D p) {
  // Poses are written with 7 decimals; render from exactly what is written.
  return {Round7(p.x), Round7(p.y), Round7(WrapAngle(p.theta))};
}

std::string ImageName(const std::string& split, size_t index) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "_%06zu.png", index);
  return split + buf;
}

constexpr uint64_t kSessionSeed = 0x5e55000;  // + day

std::string SessionSplitName(int day) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "session_day%03d", day);
  return buf;
}

std::string QuerySplitName(int day) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "query_day%03d", day);
  return buf;
}

struct Layout {
  double fw, fh;  // footprint, metres
  double sx, sy;  // lawnmower steps, metres
  int cols, rows;
};

Layout LawnmowerLayout(const SynthOptions& o, double aw, double ah) {
  Layout l;
  l.fw = o.camera.width * o.camera.meters_per_pixel;
  l.fh = o.camera.height * o.camera.meters_per_pixel;
  l.sx = std::max(1e-6, (1.0 - o.overlap) * l.fw);
  l.sy = std::max(1e-6, (1.0 - o.overlap) * l.fh);
  l.cols = aw <= l.fw ? 1 : static_cast<int>(std::ceil((aw - l.fw) / l.sx - 1e-9)) + 1;
  l.rows = ah <= l.fh ? 1 : static_cast<int>(std::ceil((ah - l.fh) / l.sy - 1e-9)) + 1;
  return l;
}

// Random pose with its centre inside [x0, x1] x [y0, y1] and any heading.
Pose2D RandomPose(CellRng& rng, double x0, double x1, double y0, double y1) {
  return {rng.Uniform(x0, std::max(x0, x1)), rng.Uniform(y0, std::max(y0, y1)),
          rng.Uniform(-M_PI, M_PI)};
}

}  // namespace

void OdometryNoise::Check() const {
  auto need = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument(what);
  };
  need(std::isfinite(scale_bias) && std::abs(scale_bias) < 0.5,
       "odometry scale_bias must be a fraction in (-0.5, 0.5)");
  need(std::isfinite(scale_noise) && scale_noise >= 0 && scale_noise < 0.5,
       "odometry scale_noise must be in [0, 0.5)");
  need(std::isfinite(turn_bias) && std::abs(turn_bias) < 0.5,
       "odometry turn_bias must be a fraction in (-0.5, 0.5)");
  need(std::isfinite(heading_bias), "odometry heading_bias must be finite (rad/m)");
  need(std::isfinite(heading_noise) && heading_noise >= 0,
       "odometry heading_noise must be >= 0 (rad/sqrt(m))");
}

void SynthOptions::Check() const {
  camera.Check();
  odometry.Check();
  auto need = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument(what);
  };
  need(area_width > 0 && std::isfinite(area_width), "area_width must be a positive size in metres");
  need(area_height > 0 && std::isfinite(area_height),
       "area_height must be a positive size in metres");
  need(overlap >= 0 && overlap <= 0.95, "overlap must be in [0, 0.95]");
  need(train_images >= 0, "train_images must be >= 0");
  need(queries_per_split >= 0, "queries_per_split must be >= 0");
  for (int d : query_days) need(d >= 0 && d <= 100000, "query_days must be in [0, 100000]");
  std::vector<int> days = query_days;
  std::sort(days.begin(), days.end());
  need(std::adjacent_find(days.begin(), days.end()) == days.end(), "query_days must be distinct");
  need(path_fraction >= 0 && path_fraction <= 1, "path_fraction must be in [0, 1]");
  need(aging >= 0 && std::isfinite(aging), "aging must be >= 0");
  need(position_jitter >= 0, "position_jitter must be >= 0");
  need(heading_jitter >= 0, "heading_jitter must be >= 0");
  need(threads >= 0, "threads must be >= 0");
  need(std::isfinite(drive_length) && drive_length >= 0 && drive_length <= 1e4,
       "drive_length must be in [0, 10000] metres");
  need(std::isfinite(drive_spacing) && drive_spacing >= 1e-4,
       "drive_spacing must be >= 0.0001 metres");
  need(drive_length / drive_spacing <= 5e6, "the drive would exceed 5 million images");
  need(later_drive_days.empty() || drive_length > 0, "later drives need a drive (--drive)");
  need(later_drive_days.size() <= 20, "at most 20 later drives");
  for (double d : later_drive_days) {
    need(std::isfinite(d) && d > 0 && d <= 3650, "later drive days must be in (0, 3650]");
  }
  need(std::isfinite(later_drive_length) && later_drive_length >= 0 &&
           later_drive_length / drive_spacing <= 5e6,
       "later_drive_length must be >= 0 and at most 5 million images");
  need(drive_length == 0 || photos.empty(), "a drive needs a synthetic floor, not --photo");
  need(query_trail >= 0 && query_trail <= 20, "query_trail must be in [0, 20]");
  need(std::isfinite(trail_spacing) && trail_spacing >= 1e-4 && trail_spacing <= 1.0,
       "trail_spacing must be in [0.0001, 1] metres");
  need(session_days.size() <= 20, "at most 20 maintenance sessions");
  for (int d : session_days) need(d > 0 && d <= 100000, "session_days must be in (0, 100000]");
  need(session_images >= 0 && session_images <= 100000, "session_images must be in [0, 100000]");
  need(photo_meters_per_pixel >= 0 && std::isfinite(photo_meters_per_pixel),
       "photo_meters_per_pixel must be >= 0 (0: the camera's meters_per_pixel)");
  need(photos.empty() || train_images == 0 || !train_photos.empty(),
       "a photo floor's train split needs training photos (--train-photo), or --train 0");
  need(!(photos.empty() && !train_photos.empty()), "training photos need map photos (--photo)");
  for (const auto& k : only) {
    need(k == "train" || k == "database" || k == "queries" || k == "drive",
         "only: unknown split kind '" + k + "' (valid: train, database, queries, drive)");
  }
  const Layout l = LawnmowerLayout(*this, area_width, area_height);
  need(static_cast<double>(l.cols) * l.rows <= 5e7,
       "the database would exceed 50 million images; reduce the area or the overlap");
}

double SquareAreaForImages(const SynthOptions& o, int images) {
  if (images <= 0) throw std::invalid_argument("database image count must be positive");
  double lo = 1e-4, hi = 1e4;
  for (int it = 0; it < 100; ++it) {
    const double mid = std::sqrt(lo * hi);
    const Layout l = LawnmowerLayout(o, mid, mid);
    if (static_cast<double>(l.cols) * l.rows < images)
      lo = mid;
    else
      hi = mid;
  }
  return hi;
}

namespace {

// Drops the splits that `only` leaves out (after planning, so that poses stay those of the
// full dataset).
void KeepOnly(const SynthOptions& o, DatasetPlan* plan) {
  if (o.only.empty()) return;
  auto kind = [](const std::string& split) {
    if (split.rfind("drive_day", 0) == 0) return std::string("drive");
    const bool query = split.rfind("query_", 0) == 0 || split.rfind("trail_", 0) == 0 ||
                       split.rfind("session_", 0) == 0;
    return query ? std::string("queries") : split;
  };
  auto wanted = [&](const std::string& split) {
    return std::find(o.only.begin(), o.only.end(), kind(split)) != o.only.end();
  };
  std::vector<PlannedImage> kept;
  for (auto& im : plan->images) {
    if (wanted(im.split)) kept.push_back(std::move(im));
  }
  plan->images.swap(kept);
  if (!wanted("drive")) {
    plan->drive_odometry.clear();
    plan->later_drive_odometry.clear();
  }
  if (!wanted("queries")) plan->trail_odometry.clear();
  for (auto it = plan->splits.begin(); it != plan->splits.end();) {
    it = wanted(it->first) ? std::next(it) : plan->splits.erase(it);
  }
  for (auto it = plan->info.query_days.begin(); it != plan->info.query_days.end();) {
    it = wanted(it->first) ? std::next(it) : plan->info.query_days.erase(it);
  }
}

// A pose whose footprint (enlarged by kPhotoMargin, for the camera's scale and tilt jitter)
// lies inside a region: the allowed box of the centre for heading theta. False when the
// footprint cannot fit at that heading.
constexpr double kPhotoMargin = 1.03;

bool CentreBox(const PhotoRegion& r, double fw, double fh, double theta, double* x0, double* x1,
               double* y0, double* y1) {
  const double c = std::abs(std::cos(theta)), sn = std::abs(std::sin(theta));
  const double hx = kPhotoMargin * 0.5 * (fw * c + fh * sn);
  const double hy = kPhotoMargin * 0.5 * (fw * sn + fh * c);
  *x0 = r.x0 + hx;
  *x1 = r.x0 + r.width() - hx;
  *y0 = r.y0 + hy;
  *y1 = r.y0 + r.height() - hy;
  return *x0 <= *x1 && *y0 <= *y1;
}

// Split-name-safe label: lowercase letters, digits and '_'.
std::string SafeLabel(const std::string& s) {
  std::string out;
  for (unsigned char c : s) {
    if (std::isalnum(c)) {
      out += static_cast<char>(std::tolower(c));
    } else if (!out.empty() && out.back() != '_') {
      out += '_';
    }
  }
  while (!out.empty() && out.back() == '_') out.pop_back();
  return out.empty() ? "photo" : out;
}

// The trail of a query (SynthOptions::query_trail): its images, oldest last in the split
// (j = 1 the nearest), on a line from the query toward `middle`, and their odometry relative
// to the query. `fit` keeps a pose's footprint where images can be taken. `ordinal` is the
// query's place in its split.
void AddTrail(const SynthOptions& o, const PlannedImage& query, size_t ordinal, Vec2 middle,
              const std::function<Pose2D(Pose2D)>& fit, DatasetPlan* plan) {
  if (o.query_trail <= 0) return;
  const std::string split = "trail_" + query.split.substr(std::string("query_").size());
  CellRng rng(HashCombine(HashCombine(o.seed, 0x7a17),
                          HashCombine(query.visit, ordinal) + std::hash<std::string>{}(split)));
  double dx = middle.x - query.pose.x, dy = middle.y - query.pose.y;
  const double norm = std::hypot(dx, dy);
  if (norm < 1e-9) {
    const double a = rng.Uniform(-M_PI, M_PI);
    dx = std::cos(a);
    dy = std::sin(a);
  } else {
    dx /= norm;
    dy /= norm;
  }
  // True poses, the query last; each step back turns the heading a little (a gentle curve).
  std::vector<Pose2D> truth(static_cast<size_t>(o.query_trail) + 1);
  truth.back() = query.pose;
  const double turn = 0.02 * rng.Normal();
  for (int j = 1; j <= o.query_trail; ++j) {
    Pose2D p{query.pose.x + j * o.trail_spacing * dx, query.pose.y + j * o.trail_spacing * dy,
             WrapAngle(query.pose.theta + j * turn)};
    truth[truth.size() - 1 - static_cast<size_t>(j)] = Rounded(fit(p));
  }
  const std::vector<Pose2D> odom = SimulateOdometry(truth, o.odometry, rng.Next());
  const Pose2D query_from_odom = Inverse(odom.back());
  std::vector<std::string>& names = plan->splits[split];
  std::vector<PoseRecord>& rel = plan->trail_odometry[split];
  for (int j = 1; j <= o.query_trail; ++j) {
    const size_t t = truth.size() - 1 - static_cast<size_t>(j);
    PlannedImage im = query;
    im.split = split;
    im.name = ImageName(split, ordinal * static_cast<size_t>(o.query_trail) + j - 1);
    im.pose = truth[t];
    names.push_back(im.name);
    plan->images.push_back(im);
    Pose2D r = Compose(query_from_odom, odom[t]);
    r.theta = WrapAngle(r.theta);
    rel.push_back({im.name, r});
  }
}

}  // namespace

std::vector<PhotoRegion> LoadPhotoFloor(const SynthOptions& o) {
  const double mpp =
      o.photo_meters_per_pixel > 0 ? o.photo_meters_per_pixel : o.camera.meters_per_pixel;
  const double fw = o.camera.width * o.camera.meters_per_pixel,
               fh = o.camera.height * o.camera.meters_per_pixel;
  std::vector<PhotoRegion> regions;
  double cursor = 0.0;
  std::map<std::string, int> used;
  auto add = [&](const std::filesystem::path& path) {
    PhotoRegion r = LoadPhotoRegion(path, mpp);
    double a, b, c, d;
    if (!CentreBox(r, fw, fh, 0.0, &a, &b, &c, &d) &&
        !CentreBox(r, fw, fh, M_PI / 2, &a, &b, &c, &d)) {
      char buf[256];
      std::snprintf(buf, sizeof(buf),
                    ": the photo is %d x %d px (%.1f x %.1f mm at %.3f mm/px), smaller than one "
                    "image (%.1f x %.1f mm, plus %.0f%% for the camera's scale jitter)",
                    r.reflectance.cols, r.reflectance.rows, r.width() * 1e3, r.height() * 1e3,
                    mpp * 1e3, fw * 1e3, fh * 1e3, (kPhotoMargin - 1.0) * 100);
      throw std::invalid_argument("photo " + path.string() + buf);
    }
    r.label = SafeLabel(r.label);
    if (used[r.label]++ > 0) r.label += "_" + std::to_string(used[r.label]);
    r.x0 = cursor;
    r.y0 = 0.0;
    cursor += r.width() + 0.1;  // regions 10 cm apart
    regions.push_back(std::move(r));
  };
  for (const auto& p : o.photos) add(p);
  cursor += 0.4;  // the training photos 0.5 m from the map
  for (const auto& p : o.train_photos) add(p);
  return regions;
}

DatasetPlan PlanPhotoDataset(const SynthOptions& o, const std::vector<PhotoRegion>& regions) {
  o.Check();
  if (o.photos.empty() || regions.size() != o.photos.size() + o.train_photos.size()) {
    throw std::invalid_argument("PlanPhotoDataset: regions do not match the options' photos");
  }
  DatasetPlan plan;
  plan.info.format_version = 1;
  const size_t nmap = o.photos.size();
  std::string labels;
  for (size_t i = 0; i < nmap; ++i) labels += (i > 0 ? ", " : "") + regions[i].label;
  plan.info.surface = "photo: " + labels;
  plan.info.name = "photo_floor_seed" + std::to_string(o.seed);
  plan.info.geometry = o.camera.Geometry();
  const double fw = o.camera.width * o.camera.meters_per_pixel,
               fh = o.camera.height * o.camera.meters_per_pixel;
  // Random pose inside region r at any heading its footprint fits.
  auto random_pose = [&](CellRng& rng, const PhotoRegion& r) {
    double x0, x1, y0, y1;
    for (int attempt = 0; attempt < 10000; ++attempt) {
      const double theta = rng.Uniform(-M_PI, M_PI);
      if (CentreBox(r, fw, fh, theta, &x0, &x1, &y0, &y1)) {
        return Rounded({rng.Uniform(x0, x1), rng.Uniform(y0, y1), theta});
      }
    }
    // Only near-axis headings fit (a narrow photo): use one that does.
    const double theta = CentreBox(r, fw, fh, 0.0, &x0, &x1, &y0, &y1) ? 0.0 : M_PI / 2;
    CentreBox(r, fw, fh, theta, &x0, &x1, &y0, &y1);
    return Rounded({rng.Uniform(x0, x1), rng.Uniform(y0, y1), theta});
  };
  // A pose moved, if needed, so that its footprint lies inside region r.
  auto fit = [&](Pose2D p, const PhotoRegion& r) {
    double x0, x1, y0, y1;
    if (!CentreBox(r, fw, fh, p.theta, &x0, &x1, &y0, &y1)) {
      p.theta = std::round(p.theta / (M_PI / 2)) * (M_PI / 2);
      if (!CentreBox(r, fw, fh, p.theta, &x0, &x1, &y0, &y1)) {
        p.theta += M_PI / 2;
        CentreBox(r, fw, fh, p.theta, &x0, &x1, &y0, &y1);
      }
    }
    p.x = std::clamp(p.x, x0, x1);
    p.y = std::clamp(p.y, y0, y1);
    return p;
  };
  // Training images: random poses over the training photos, in turn.
  if (o.train_images > 0) {
    CellRng rng(HashCombine(o.seed, 0x7a1));
    std::vector<std::string> names;
    for (int i = 0; i < o.train_images; ++i) {
      PlannedImage im;
      im.split = "train";
      im.name = ImageName("train", i);
      im.pose = random_pose(rng, regions[nmap + i % o.train_photos.size()]);
      im.visit = kTrainVisit;
      names.push_back(im.name);
      plan.images.push_back(im);
    }
    plan.splits["train"] = std::move(names);
  }
  // Database: a lawnmower path over each map photo, spaced evenly so that it ends at the edges.
  {
    CellRng rng(HashCombine(o.seed, 0xdb));
    std::vector<std::string>& names = plan.splits["database"];
    size_t index = 0;
    for (size_t ri = 0; ri < nmap; ++ri) {
      const PhotoRegion& r = regions[ri];
      double x0, x1, y0, y1;
      CentreBox(r, fw, fh, 0.0, &x0, &x1, &y0, &y1);
      const bool upright = x0 <= x1 && y0 <= y1;  // else the path runs with the camera turned
      const double theta0 = upright ? 0.0 : M_PI / 2;
      CentreBox(r, fw, fh, theta0, &x0, &x1, &y0, &y1);
      const double step_x = (1.0 - o.overlap) * (upright ? fw : fh);
      const double step_y = (1.0 - o.overlap) * (upright ? fh : fw);
      const int cols = static_cast<int>(std::ceil((x1 - x0) / std::max(1e-9, step_x) - 1e-9)) + 1;
      const int rows = static_cast<int>(std::ceil((y1 - y0) / std::max(1e-9, step_y) - 1e-9)) + 1;
      for (int row = 0; row < rows; ++row) {
        const bool forward = (row % 2) == 0;
        for (int c = 0; c < cols; ++c) {
          const int cc = forward ? c : cols - 1 - c;
          const double x = cols == 1 ? 0.5 * (x0 + x1) : x0 + (x1 - x0) * cc / (cols - 1);
          const double y = rows == 1 ? 0.5 * (y0 + y1) : y0 + (y1 - y0) * row / (rows - 1);
          Pose2D p{x + o.position_jitter * rng.Normal(), y + o.position_jitter * rng.Normal(),
                   theta0 + (forward ? 0.0 : M_PI) + o.heading_jitter * rng.Normal()};
          PlannedImage im;
          im.split = "database";
          im.name = ImageName("database", index++);
          im.pose = Rounded(fit(p, r));
          im.visit = kDatabaseVisit;
          names.push_back(im.name);
          plan.images.push_back(im);
        }
      }
    }
  }
  // Queries: per day, and per photo when there are several, at random poses.
  for (size_t k = 0; k < o.query_days.size() && o.queries_per_split > 0; ++k) {
    const int day = o.query_days[k];
    for (size_t ri = 0; ri < nmap; ++ri) {
      const std::string split = QuerySplitName(day) + (nmap > 1 ? "_" + regions[ri].label : "");
      plan.info.query_days[split] = day;
      CellRng rng(HashCombine(HashCombine(o.seed, 0x9e000 + static_cast<uint64_t>(day)), ri));
      std::vector<std::string>& names = plan.splits[split];
      for (int i = 0; i < o.queries_per_split; ++i) {
        PlannedImage im;
        im.split = split;
        im.name = ImageName(split, i);
        im.pose = random_pose(rng, regions[ri]);
        im.day = day;
        im.visit = kFirstQueryVisit + k;
        names.push_back(im.name);
        plan.images.push_back(im);
        const PhotoRegion& r = regions[ri];
        AddTrail(
            o, im, static_cast<size_t>(i), {r.x0 + 0.5 * r.width(), r.y0 + 0.5 * r.height()},
            [&](Pose2D p) { return fit(p, r); }, &plan);
      }
    }
  }
  // Maintenance sessions: every photo in turn, at random poses.
  for (size_t k = 0; k < o.session_days.size(); ++k) {
    const int day = o.session_days[k];
    const std::string split = SessionSplitName(day);
    std::vector<std::string>& names = plan.splits[split];
    const int per = o.session_images > 0 ? o.session_images : o.queries_per_split;
    for (size_t ri = 0; ri < nmap; ++ri) {
      CellRng rng(HashCombine(HashCombine(o.seed, kSessionSeed + static_cast<uint64_t>(day)), ri));
      for (int i = 0; i < per; ++i) {
        PlannedImage im;
        im.split = split;
        im.name = ImageName(split, names.size());
        im.pose = random_pose(rng, regions[ri]);
        im.day = day;
        im.visit = kFirstSessionVisit + k;
        names.push_back(im.name);
        plan.images.push_back(im);
      }
    }
  }
  KeepOnly(o, &plan);
  return plan;
}

namespace {

// The base curve of the drive: a rounded rectangle, counter-clockwise from the start of its
// bottom side. At() returns the point at arc length u (wrapped to one lap) and the
// inward unit normal there.
struct RoundedRect {
  double x0, y0, x1, y1, r;
  double Perimeter() const { return 2 * (x1 - x0 - 2 * r) + 2 * (y1 - y0 - 2 * r) + 2 * M_PI * r; }
  void At(double u, Vec2* p, Vec2* inward) const {
    const double lx = x1 - x0 - 2 * r, ly = y1 - y0 - 2 * r, arc = 0.5 * M_PI * r;
    u = std::fmod(u, Perimeter());
    if (u < 0) u += Perimeter();
    // Sides and corners in order: bottom (+x), corner, right (+y), corner, top (-x), corner,
    // left (-y), corner.
    const double side_len[4] = {lx, ly, lx, ly};
    const Vec2 start[4] = {{x0 + r, y0}, {x1, y0 + r}, {x1 - r, y1}, {x0, y1 - r}};
    const Vec2 dir[4] = {{1, 0}, {0, 1}, {-1, 0}, {0, -1}};
    const Vec2 centre[4] = {{x1 - r, y0 + r}, {x1 - r, y1 - r}, {x0 + r, y1 - r}, {x0 + r, y0 + r}};
    for (int k = 0; k < 4; ++k) {
      if (u <= side_len[k]) {
        *p = {start[k].x + u * dir[k].x, start[k].y + u * dir[k].y};
        *inward = {-dir[k].y, dir[k].x};  // left of the direction of travel
        return;
      }
      u -= side_len[k];
      if (u <= arc || k == 3) {
        const double a = -0.5 * M_PI + k * 0.5 * M_PI + std::min(u, arc) / r;
        *p = {centre[k].x + r * std::cos(a), centre[k].y + r * std::sin(a)};
        *inward = {-std::cos(a), -std::sin(a)};
        return;
      }
      u -= arc;
    }
  }
};

}  // namespace

std::vector<Pose2D> DrivePath(double width, double height, const ImageGeometry& g, double length,
                              double spacing, double start_laps) {
  const double fw = g.width * g.meters_per_pixel, fh = g.height * g.meters_per_pixel;
  const double inset = 0.5 * std::hypot(fw, fh);
  RoundedRect rect{inset, inset, width - inset, height - inset, 0.0};
  const double w = rect.x1 - rect.x0, h = rect.y1 - rect.y0;
  if (!(w > 0.5 * fh && h > 0.5 * fh)) {
    char buf[200];
    std::snprintf(buf, sizeof(buf),
                  "the database area %.3f x %.3f m is too small for a drive: the path keeps half "
                  "a footprint diagonal (%.3f m) from its edges",
                  width, height, inset);
    throw std::invalid_argument(buf);
  }
  // Sideways shift of each lap (left of the direction of travel, i.e. inwards), blended over the
  // lap with a smoothstep; the corners' radius exceeds the largest inward shift.
  const double corner = 0.5 * std::min(w, h);
  rect.r = std::min(corner, std::max(0.15, 0.3 * std::min(w, h)));
  const double amplitude = std::min(0.35 * fh, 0.6 * rect.r);
  auto shift = [&](int lap) { return amplitude * std::sin(2.4 * lap + 0.3); };
  const double perimeter = rect.Perimeter();
  auto point = [&](double u) {
    Vec2 p, n;
    rect.At(u, &p, &n);
    const int lap = static_cast<int>(std::floor(u / perimeter));
    const double f = u / perimeter - lap;
    const double s = shift(lap) + (shift(lap + 1) - shift(lap)) * f * f * (3 - 2 * f);
    return Vec2{p.x + s * n.x, p.y + s * n.y};
  };
  const double du = std::min(5e-4, 0.1 * spacing);
  std::vector<Pose2D> poses;
  const size_t n = static_cast<size_t>(std::floor(length / spacing + 1e-9)) + 1;
  poses.reserve(n);
  double u = start_laps * perimeter;
  Vec2 prev = point(u);
  double travelled = 0.0, next = 0.0;
  while (poses.size() < n) {
    const Vec2 cur = point(u + du);
    const double step = std::hypot(cur.x - prev.x, cur.y - prev.y);
    while (poses.size() < n && travelled + step >= next) {
      const double f = step > 0 ? (next - travelled) / step : 0.0;
      poses.push_back({prev.x + f * (cur.x - prev.x), prev.y + f * (cur.y - prev.y),
                       std::atan2(cur.y - prev.y, cur.x - prev.x)});
      next += spacing;
    }
    travelled += step;
    prev = cur;
    u += du;
  }
  return poses;
}

std::vector<Pose2D> SimulateOdometry(const std::vector<Pose2D>& truth, const OdometryNoise& noise,
                                     uint64_t seed) {
  noise.Check();
  std::vector<Pose2D> odom;
  if (truth.empty()) return odom;
  odom.reserve(truth.size());
  odom.push_back(truth[0]);
  CellRng rng(HashCombine(seed, 0x0d0));
  for (size_t i = 1; i < truth.size(); ++i) {
    const Pose2D rel = Compose(Inverse(truth[i - 1]), truth[i]);
    const double d = std::hypot(rel.x, rel.y);
    const double n1 = rng.Normal(), n2 = rng.Normal();
    const double s = 1.0 + noise.scale_bias + noise.scale_noise * n1;
    const double dtheta = WrapAngle(rel.theta) * (1.0 + noise.turn_bias) + noise.heading_bias * d +
                          noise.heading_noise * std::sqrt(d) * n2;
    Pose2D next = Compose(odom.back(), {rel.x * s, rel.y * s, dtheta});
    next.theta = WrapAngle(next.theta);
    odom.push_back(next);
  }
  return odom;
}

DatasetPlan PlanDataset(const SynthOptions& o) {
  o.Check();
  if (!o.photos.empty()) return PlanPhotoDataset(o, LoadPhotoFloor(o));
  DatasetPlan plan;
  plan.info.format_version = 1;
  plan.info.surface = SurfaceName(o.surface);
  plan.info.name = plan.info.surface + "_synth_seed" + std::to_string(o.seed);
  plan.info.geometry = o.camera.Geometry();
  const Layout l = LawnmowerLayout(o, o.area_width, o.area_height);

  // Training area: same surface, to the right of the map with a 0.5 m gap.
  {
    CellRng rng(HashCombine(o.seed, 0x7a1));
    const double side = std::max(0.5, std::sqrt(o.train_images * l.fw * l.fh / 0.3));
    const double x0 = o.area_width + 0.5;
    std::vector<std::string> names;
    for (int i = 0; i < o.train_images; ++i) {
      PlannedImage im;
      im.split = "train";
      im.name = ImageName("train", i);
      im.pose = Rounded(
          RandomPose(rng, x0 + 0.5 * l.fw, x0 + side - 0.5 * l.fw, 0.5 * l.fh, side - 0.5 * l.fh));
      im.day = 0.0;
      im.visit = kTrainVisit;
      names.push_back(im.name);
      plan.images.push_back(im);
    }
    if (!names.empty()) plan.splits["train"] = std::move(names);
  }
  // Database: a boustrophedon (lawnmower) path; the camera heading follows the robot.
  {
    CellRng rng(HashCombine(o.seed, 0xdb));
    std::vector<std::string>& names = plan.splits["database"];
    size_t index = 0;
    for (int r = 0; r < l.rows; ++r) {
      const bool forward = (r % 2) == 0;
      for (int c = 0; c < l.cols; ++c) {
        const int cc = forward ? c : l.cols - 1 - c;
        PlannedImage im;
        im.split = "database";
        im.name = ImageName("database", index++);
        im.pose = Rounded({0.5 * l.fw + cc * l.sx + o.position_jitter * rng.Normal(),
                           0.5 * l.fh + r * l.sy + o.position_jitter * rng.Normal(),
                           (forward ? 0.0 : M_PI) + o.heading_jitter * rng.Normal()});
        im.day = 0.0;
        im.visit = kDatabaseVisit;
        names.push_back(im.name);
        plan.images.push_back(im);
      }
    }
  }
  // Queries: one split per day, half along smooth paths and half at random poses.
  const double qx0 = 0.5 * l.fw, qx1 = std::max(qx0, o.area_width - 0.5 * l.fw);
  const double qy0 = 0.5 * l.fh, qy1 = std::max(qy0, o.area_height - 0.5 * l.fh);
  for (size_t k = 0; k < o.query_days.size() && o.queries_per_split > 0; ++k) {
    const int day = o.query_days[k];
    const std::string split = QuerySplitName(day);
    plan.info.query_days[split] = day;
    CellRng rng(HashCombine(o.seed, 0x9e000 + static_cast<uint64_t>(day)));
    std::vector<std::string>& names = plan.splits[split];
    const int n_path = static_cast<int>(std::round(o.path_fraction * o.queries_per_split));
    Pose2D walker{};
    int left_on_path = 0;
    for (int i = 0; i < o.queries_per_split; ++i) {
      Pose2D p;
      if (i < n_path) {
        if (left_on_path == 0) {
          walker = RandomPose(rng, qx0, qx1, qy0, qy1);
          left_on_path = 20;
        } else {
          walker.theta += 0.15 * rng.Normal();
          const double step = 0.03;
          double nx = walker.x + step * std::cos(walker.theta);
          double ny = walker.y + step * std::sin(walker.theta);
          if (nx < qx0 || nx > qx1) {
            walker.theta = M_PI - walker.theta;
            nx = std::clamp(nx, qx0, qx1);
          }
          if (ny < qy0 || ny > qy1) {
            walker.theta = -walker.theta;
            ny = std::clamp(ny, qy0, qy1);
          }
          walker.x = nx;
          walker.y = ny;
        }
        --left_on_path;
        p = walker;
      } else {
        p = RandomPose(rng, qx0, qx1, qy0, qy1);
      }
      PlannedImage im;
      im.split = split;
      im.name = ImageName(split, i);
      im.pose = Rounded(p);
      im.day = day;
      im.visit = kFirstQueryVisit + k;
      names.push_back(im.name);
      plan.images.push_back(im);
      AddTrail(
          o, im, static_cast<size_t>(i), {0.5 * (qx0 + qx1), 0.5 * (qy0 + qy1)},
          [&](Pose2D p) {
            p.x = std::clamp(p.x, qx0, qx1);
            p.y = std::clamp(p.y, qy0, qy1);
            return p;
          },
          &plan);
    }
  }
  // Maintenance sessions: random poses over the query area.
  for (size_t k = 0; k < o.session_days.size(); ++k) {
    const int day = o.session_days[k];
    const std::string split = SessionSplitName(day);
    CellRng rng(HashCombine(o.seed, kSessionSeed + static_cast<uint64_t>(day)));
    std::vector<std::string>& names = plan.splits[split];
    const int per = o.session_images > 0 ? o.session_images : o.queries_per_split;
    for (int i = 0; i < per; ++i) {
      PlannedImage im;
      im.split = split;
      im.name = ImageName(split, static_cast<size_t>(i));
      im.pose = Rounded(RandomPose(rng, qx0, qx1, qy0, qy1));
      im.day = day;
      im.visit = kFirstSessionVisit + k;
      names.push_back(im.name);
      plan.images.push_back(im);
    }
  }
  // The drive: one recording session over the database area, with its odometry.
  if (o.drive_length > 0) {
    const std::vector<Pose2D> truth = DrivePath(o.area_width, o.area_height, o.camera.Geometry(),
                                                o.drive_length, o.drive_spacing);
    std::vector<Pose2D> rounded;
    rounded.reserve(truth.size());
    for (const Pose2D& p : truth) rounded.push_back(Rounded(p));
    const std::vector<Pose2D> odom = SimulateOdometry(rounded, o.odometry, o.seed);
    std::vector<std::string>& names = plan.splits["drive"];
    for (size_t i = 0; i < rounded.size(); ++i) {
      PlannedImage im;
      im.split = "drive";
      im.name = ImageName("drive", i);
      im.pose = rounded[i];
      im.day = 0.0;
      im.visit = kDriveVisit;
      names.push_back(im.name);
      plan.images.push_back(im);
      plan.drive_odometry.push_back({im.name, odom[i]});
    }
    // Later sessions: the same laps on later days, starting elsewhere, odometry from the origin.
    for (size_t k = 0; k < o.later_drive_days.size(); ++k) {
      const double day = o.later_drive_days[k];
      char split[32];
      std::snprintf(split, sizeof(split), "drive_day%03d", static_cast<int>(std::lround(day)));
      const std::vector<Pose2D> path =
          DrivePath(o.area_width, o.area_height, o.camera.Geometry(),
                    o.later_drive_length > 0 ? o.later_drive_length : o.drive_length,
                    o.drive_spacing, static_cast<double>(k + 1) / 3.0);
      std::vector<Pose2D> later;
      later.reserve(path.size());
      for (const Pose2D& p : path) later.push_back(Rounded(p));
      const std::vector<Pose2D> wheel =
          SimulateOdometry(later, o.odometry, HashCombine(o.seed, kLaterDriveVisit + k));
      const Pose2D boot = Inverse(wheel.front());
      std::vector<std::string>& later_names = plan.splits[split];
      std::vector<PoseRecord>& later_odom = plan.later_drive_odometry[split];
      for (size_t i = 0; i < later.size(); ++i) {
        PlannedImage im;
        im.split = split;
        im.name = ImageName(split, i);
        im.pose = later[i];
        im.day = day;
        im.visit = kLaterDriveVisit + k;
        later_names.push_back(im.name);
        plan.images.push_back(im);
        Pose2D odom = i == 0 ? Pose2D{0, 0, 0} : Compose(boot, wheel[i]);  // exactly the origin
        odom.theta = WrapAngle(odom.theta);
        later_odom.push_back({im.name, odom});
      }
    }
  }
  KeepOnly(o, &plan);
  return plan;
}

Lighting VisitLighting(uint64_t seed, uint64_t visit) {
  if (visit == kDatabaseVisit || visit == kTrainVisit) return {};
  CellRng rng(HashCombine(HashCombine(seed, 0x11947), visit));
  Lighting l;
  l.gain = 1.0 + 0.1 * rng.Uniform(-1.0, 1.0);
  l.gradient_u = 0.12 * rng.Uniform(-1.0, 1.0);
  l.gradient_v = 0.12 * rng.Uniform(-1.0, 1.0);
  // Drawn after the fields above so that those keep their values.
  l.gamma = 1.0 + 0.15 * rng.Uniform(-1.0, 1.0);
  l.directional_scale = 1.0 + 0.25 * rng.Uniform(-1.0, 1.0);
  l.azimuth_offset = 0.25 * rng.Uniform(-1.0, 1.0);
  return l;
}

cv::Mat RenderPlannedImage(const Floor& floor, const Camera& camera, const SynthOptions& o,
                           const PlannedImage& im) {
  FloorState state;
  state.day = im.day;
  state.visit_seed = HashCombine(o.seed, im.visit);
  state.aging = o.aging;
  const uint64_t shot = HashCombine(HashCombine(o.seed, Fnv1a(im.name)), im.visit);
  return camera.Capture(floor, im.pose, state, VisitLighting(o.seed, im.visit), shot);
}

Scene::Scene(const SynthOptions& options)
    : options_(options),
      plan_(PlanDataset(options)),
      floor_(options.surface, options.seed),
      camera_(options.camera) {
  if (!options.photos.empty()) {
    throw std::invalid_argument("synth::Scene renders synthetic surfaces, not photo floors");
  }
}

cv::Mat Scene::Render(const PlannedImage& image) const {
  return RenderPlannedImage(floor_, camera_, options_, image);
}

SynthSummary GenerateDataset(const SynthOptions& o, const fs::path& out, bool force,
                             bool progress) {
  const auto start = std::chrono::steady_clock::now();
  std::vector<PhotoRegion> regions;
  if (!o.photos.empty()) regions = LoadPhotoFloor(o);
  const DatasetPlan plan = regions.empty() ? PlanDataset(o) : PlanPhotoDataset(o, regions);
  const Floor floor = regions.empty() ? Floor(o.surface, o.seed) : Floor(regions, o.seed);
  const Camera camera(o.camera);
  const fs::path staging = StageDirectory(out, force);
  SynthSummary summary;
  try {
    fs::create_directories(staging / "images");
    ProgressBar bar("synth", plan.images.size(), progress);
    // Noisy texture barely compresses beyond entropy coding: Huffman-only is as small and fast.
    const std::vector<int> png = {cv::IMWRITE_PNG_COMPRESSION, 1, cv::IMWRITE_PNG_STRATEGY,
                                  cv::IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY};
    // Parallelism is across images: OpenCV's own threads would only oversubscribe the cores.
    const int cv_threads = cv::getNumThreads();
    cv::setNumThreads(1);
    try {
      ParallelForEach(plan.images.size(), o.threads, [&](size_t i) {
        const cv::Mat img = RenderPlannedImage(floor, camera, o, plan.images[i]);
        const fs::path path = staging / "images" / plan.images[i].name;
        if (!cv::imwrite(path.string(), img, png)) {
          throw std::runtime_error("cannot write image " + path.string());
        }
        bar.Add();
      });
    } catch (...) {
      cv::setNumThreads(cv_threads);
      throw;
    }
    cv::setNumThreads(cv_threads);
    bar.Finish();

    std::vector<PoseRecord> poses;
    poses.reserve(plan.images.size());
    for (const auto& im : plan.images) poses.push_back({im.name, im.pose});
    WriteDatasetFiles(staging, plan.info, poses, plan.splits);
    if (!plan.drive_odometry.empty()) {
      // The columns of poses.csv: the odometry pose of each drive image (OdometryNoise).
      WriteFileAtomic(staging / "drive_odometry.csv", FormatPosesCsv(plan.drive_odometry));
    }
    for (const auto& [split, odom] : plan.later_drive_odometry) {
      WriteFileAtomic(staging / (split + "_odometry.csv"), FormatPosesCsv(odom));
    }
    for (const auto& [split, odom] : plan.trail_odometry) {
      // Each trail image's odometry pose in its query's frame (SynthOptions::query_trail).
      WriteFileAtomic(staging / (split + "_odometry.csv"), FormatPosesCsv(odom));
    }
    // Provenance: how this dataset was made (an extra file the format allows).
    std::ostringstream prov;
    prov << "# gtbow synth parameters\nsurface: "
         << (regions.empty() ? SurfaceName(o.surface) : "photo") << "\nseed: " << o.seed
         << "\narea_width: " << o.area_width << "\narea_height: " << o.area_height
         << "\noverlap: " << o.overlap << "\ntrain_images: " << o.train_images
         << "\nqueries_per_split: " << o.queries_per_split << "\naging: " << o.aging
         << "\nsupersample: " << o.camera.supersample
         << "\nsensor_effects: " << (o.camera.sensor_effects ? "true" : "false")
         << "\nrenderer_version: " << kRendererVersion << "\nmotion_blur: " << o.camera.motion_blur
         << "\nlight_directional: " << o.camera.light_directional
         << "\nlight_azimuth: " << o.camera.light_azimuth
         << "\nlight_elevation: " << o.camera.light_elevation << "\n";
    if (o.drive_length > 0) {
      prov << "drive_length: " << o.drive_length << "\ndrive_spacing: " << o.drive_spacing << "\n";
      if (!o.later_drive_days.empty()) {
        prov << "later_drive_days: [";
        for (size_t k = 0; k < o.later_drive_days.size(); ++k)
          prov << (k ? ", " : "") << o.later_drive_days[k];
        prov << "]\nlater_drive_length: " << o.later_drive_length << "\n";
      }
    }
    if (o.query_trail > 0) {
      prov << "query_trail: " << o.query_trail << "\ntrail_spacing: " << o.trail_spacing << "\n";
    }
    if (!o.session_days.empty()) {
      prov << "session_days: [";
      for (size_t k = 0; k < o.session_days.size(); ++k)
        prov << (k ? ", " : "") << o.session_days[k];
      prov << "]\nsession_images: " << o.session_images << "\n";
    }
    if (o.drive_length > 0 || o.query_trail > 0) {
      prov << "odometry_scale_bias: " << o.odometry.scale_bias
           << "\nodometry_scale_noise: " << o.odometry.scale_noise
           << "\nodometry_turn_bias: " << o.odometry.turn_bias
           << "\nodometry_heading_bias: " << o.odometry.heading_bias
           << "\nodometry_heading_noise: " << o.odometry.heading_noise << "\n";
    }
    if (!regions.empty()) {
      // Each photograph: file name, checksum of its bytes, scale and where it lies on the floor.
      prov << "photo_regions:\n";
      for (size_t i = 0; i < regions.size(); ++i) {
        const auto& r = regions[i];
        const std::string bytes = ReadFile(r.path);
        char line[512];
        std::snprintf(
            line, sizeof(line),
            "  - {file: \"%s\", use: %s, label: %s, checksum: %016llx, meters_per_pixel: %.9g, "
            "x0: %.6f, y0: %.6f, width: %.6f, height: %.6f}\n",
            r.path.filename().string().c_str(), i < o.photos.size() ? "map" : "train",
            r.label.c_str(),
            static_cast<unsigned long long>(Checksum64(bytes.data(), bytes.size())),
            r.meters_per_pixel, r.x0, r.y0, r.width(), r.height());
        prov << line;
      }
    }
    WriteFileAtomic(staging / "synth.yaml", prov.str());
    for (const auto& entry : fs::recursive_directory_iterator(staging)) {
      if (entry.is_regular_file()) summary.bytes += entry.file_size();
    }
    CommitStagedDirectory(staging, out);
  } catch (...) {
    DiscardStagedDirectory(staging);
    throw;
  }
  for (const auto& [split, names] : plan.splits) summary.split_sizes[split] = names.size();
  summary.images = plan.images.size();
  // Mean overlap of consecutive database images along the path.
  const ImageGeometry g = o.camera.Geometry();
  double sum = 0.0;
  size_t n = 0;
  const PlannedImage* prev = nullptr;
  for (const auto& im : plan.images) {
    if (im.split != "database") continue;
    if (prev != nullptr) {
      const double ov = Overlap(im.pose, prev->pose, g);
      if (ov > 0.0) {  // skip the turns between lanes
        sum += ov;
        ++n;
      }
    }
    prev = &im;
  }
  summary.mean_neighbour_overlap = n > 0 ? sum / n : 0.0;
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace synth
}  // namespace gtbow
