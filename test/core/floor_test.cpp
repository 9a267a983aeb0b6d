// Tests of the procedural floor seen through the camera: exact geometry, determinism, floor-
// fixed texture, multi-scale structure, ageing, and ORB repeatability as in real ground texture.
#include "ground_texture_bow/eval/synth/floor.h"

#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/eval/synth/camera.h"

namespace gtbow {
namespace synth {
namespace {

CameraOptions Ideal() {
  CameraOptions o;
  o.sensor_effects = false;
  return o;
}

// Intensity-weighted centroid of bright pixels within `win` px of `guess`.
bool BrightCentroid(const cv::Mat& img, Vec2 guess, int win, Vec2* out) {
  double sw = 0, su = 0, sv = 0, peak = 0;
  for (int v = std::max(0, int(guess.y) - win); v <= std::min(img.rows - 1, int(guess.y) + win);
       ++v) {
    for (int u = std::max(0, int(guess.x) - win); u <= std::min(img.cols - 1, int(guess.x) + win);
         ++u) {
      const double w = std::max(0.0, img.at<uint8_t>(v, u) - 160.0);
      peak = std::max(peak, double(img.at<uint8_t>(v, u)));
      sw += w;
      su += w * u;
      sv += w * v;
    }
  }
  if (sw <= 0 || peak < 220) return false;
  *out = {su / sw, sv / sw};
  return true;
}

TEST(Floor, MarkerRendersWherePoseSays) {
  const Floor floor(Surface::kFlat, 3);
  const Camera cam(Ideal());
  const ImageGeometry geo = cam.options().Geometry();
  for (double heading : {0.0, 0.5, M_PI / 2, 2.8, -1.9}) {
    const Pose2D pose{1.23, -0.45, heading};
    FloorState st;
    // Markers at known floor points, placed at chosen pixels of this view.
    std::vector<Vec2> pixels = {{100.0, 80.0}, {319.5, 239.5}, {530.25, 400.75}};
    for (const Vec2& px : pixels) {
      const Vec2 f = FloorFromImage(pose, geo, px);
      st.markers.push_back({f.x, f.y, 0.001});
    }
    const cv::Mat img = cam.Capture(floor, pose, st, {}, 1);
    for (const FloorMarker& m : st.markers) {
      const Vec2 expect = ImageFromFloor(pose, geo, {m.x, m.y});
      Vec2 got;
      ASSERT_TRUE(BrightCentroid(img, expect, 6, &got)) << "heading " << heading;
      EXPECT_NEAR(got.x, expect.x, 0.15) << "heading " << heading;
      EXPECT_NEAR(got.y, expect.y, 0.15) << "heading " << heading;
    }
  }
}

TEST(Floor, HeightAndTiltJitterStayWithinTwoPercent) {
  const Floor floor(Surface::kFlat, 3);
  CameraOptions o;
  o.noise_sigma = 0.0;
  o.shot_noise = 0.0;
  o.vignetting = 0.0;
  const Camera cam(o);
  const ImageGeometry geo = o.Geometry();
  const Pose2D pose{0.2, 0.1, 0.3};
  FloorState st;
  const Vec2 corner_px{40.0, 40.0};
  const Vec2 f = FloorFromImage(pose, geo, corner_px);
  st.markers.push_back({f.x, f.y, 0.001});
  double max_err = 0.0;
  for (uint64_t shot = 0; shot < 12; ++shot) {
    const cv::Mat img = cam.Capture(floor, pose, st, {}, shot);
    Vec2 got;
    ASSERT_TRUE(BrightCentroid(img, corner_px, 12, &got));
    max_err = std::max(max_err, std::hypot(got.x - corner_px.x, got.y - corner_px.y));
  }
  const double radius = std::hypot(319.5 - 40.0, 239.5 - 40.0);
  EXPECT_GT(max_err, 0.2);                  // the jitter is there
  EXPECT_LT(max_err, 0.02 * radius + 0.5);  // and bounded by +-2% scale
}

TEST(Floor, DeterministicForSameSeed) {
  const Camera cam(CameraOptions{});
  FloorState st;
  st.day = 40;
  st.visit_seed = 9;
  const cv::Mat a = cam.Capture(Floor(Surface::kAsphalt, 5), {0.3, 0.2, 1.0}, st, {}, 17);
  const cv::Mat b = cam.Capture(Floor(Surface::kAsphalt, 5), {0.3, 0.2, 1.0}, st, {}, 17);
  const cv::Mat c = cam.Capture(Floor(Surface::kAsphalt, 6), {0.3, 0.2, 1.0}, st, {}, 17);
  EXPECT_EQ(cv::norm(a, b, cv::NORM_L1), 0.0);
  EXPECT_GT(cv::norm(a, c, cv::NORM_L1) / a.total(), 10.0);
}

// Normalised cross-correlation of two float images over a mask.
double Ncc(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  cv::Scalar ma, sa, mb, sb;
  cv::meanStdDev(a, ma, sa, mask);
  cv::meanStdDev(b, mb, sb, mask);
  cv::Mat pa = a - ma[0], pb = b - mb[0];
  cv::Mat prod = pa.mul(pb);
  return cv::mean(prod, mask)[0] / (sa[0] * sb[0]);
}

// Warps image `b` (pose pb) into the frame of image `a` (pose pa) through the ground truth.
void WarpInto(const cv::Mat& b, const Pose2D& pa, const Pose2D& pb, const ImageGeometry& g,
              cv::Mat* warped, cv::Mat* mask) {
  cv::Mat mx(b.size(), CV_32F), my(b.size(), CV_32F);
  *mask = cv::Mat::zeros(b.size(), CV_8U);
  for (int v = 0; v < b.rows; ++v) {
    for (int u = 0; u < b.cols; ++u) {
      const Vec2 q = ImageFromFloor(pb, g, FloorFromImage(pa, g, {double(u), double(v)}));
      mx.at<float>(v, u) = float(q.x);
      my.at<float>(v, u) = float(q.y);
      if (q.x > 2 && q.y > 2 && q.x < b.cols - 3 && q.y < b.rows - 3) mask->at<uint8_t>(v, u) = 255;
    }
  }
  cv::remap(b, *warped, mx, my, cv::INTER_LINEAR);
}

TEST(Floor, TextureIsFixedToTheFloorForEverySurface) {
  const Camera cam(Ideal());
  const ImageGeometry g = cam.options().Geometry();
  const Pose2D pa{0.5, 0.5, 0.0}, pb{0.53, 0.51, 0.6};
  for (Surface s : {Surface::kAsphalt, Surface::kConcrete, Surface::kCarpet, Surface::kLaminate}) {
    const Floor floor(s, 11);
    cv::Mat a, b, w, mask;
    cam.Capture(floor, pa, {}, {}, 1).convertTo(a, CV_32F);
    cam.Capture(floor, pb, {}, {}, 2).convertTo(b, CV_32F);
    WarpInto(b, pa, pb, g, &w, &mask);
    ASSERT_GT(cv::countNonZero(mask), 50000);
    const double ncc = Ncc(a, w, mask);
    std::printf("%s: NCC of two views through the ground truth %.3f\n", SurfaceName(s).c_str(),
                ncc);
    EXPECT_GT(ncc, 0.85) << SurfaceName(s);
  }
}

TEST(Floor, EverySurfaceHasStructureAtSeveralScalesAndPlacesDiffer) {
  const Camera cam(Ideal());
  for (Surface s : {Surface::kAsphalt, Surface::kConcrete, Surface::kCarpet, Surface::kLaminate}) {
    const Floor floor(s, 4);
    cv::Mat img;
    cam.Capture(floor, {1.0, 2.0, 0.2}, {}, {}, 1).convertTo(img, CV_32F, 1.0 / 255);
    // Energy of a Laplacian pyramid: detail at 1, 2, 4 and 8 pixel scales (0.25 to 2 mm).
    cv::Mat level = img;
    std::vector<double> band;
    for (int k = 0; k < 4; ++k) {
      cv::Mat down, up;
      cv::pyrDown(level, down);
      cv::pyrUp(down, up, level.size());
      cv::Scalar mean, sd;
      cv::meanStdDev(level - up, mean, sd);
      band.push_back(sd[0]);
      level = down;
    }
    for (int k = 0; k < 4; ++k) EXPECT_GT(band[k], 0.004) << SurfaceName(s) << " band " << k;
    // Another place of the same surface is uncorrelated.
    cv::Mat other;
    cam.Capture(floor, {1.7, 2.4, 0.2}, {}, {}, 1).convertTo(other, CV_32F, 1.0 / 255);
    const cv::Mat all(img.size(), CV_8U, cv::Scalar(255));
    EXPECT_LT(std::abs(Ncc(img, other, all)), 0.15) << SurfaceName(s);
  }
}

TEST(Floor, WearAccumulatesAndDebrisComesAndGoes) {
  const Floor floor(Surface::kAsphalt, 2);
  const Camera cam(Ideal());
  const Pose2D p{3.0, 1.0, 0.0};
  auto render = [&](double day, uint64_t visit) {
    FloorState st;
    st.day = day;
    st.visit_seed = visit;
    cv::Mat f;
    cam.Capture(floor, p, st, {}, 1).convertTo(f, CV_32F);
    return f;
  };
  const cv::Mat d0 = render(0, 1);
  const double same_day_other_visit = cv::norm(d0, render(0, 2), cv::NORM_L1) / d0.total();
  const double d30 = cv::norm(d0, render(30, 3), cv::NORM_L1) / d0.total();
  const double d180 = cv::norm(d0, render(180, 3), cv::NORM_L1) / d0.total();
  EXPECT_GT(same_day_other_visit, 0.05);  // transient debris differs between visits
  EXPECT_GT(d30, same_day_other_visit);
  EXPECT_GT(d180, 1.5 * d30);  // progressive wear
  // No wear at all when ageing is off: only the debris of the visit differs.
  FloorState off;
  off.day = 180;
  off.aging = 0.0;
  cv::Mat clean;
  cam.Capture(floor, p, off, {}, 1).convertTo(clean, CV_32F);
  FloorState off0 = off;
  off0.day = 0;
  cv::Mat clean0;
  cam.Capture(floor, p, off0, {}, 1).convertTo(clean0, CV_32F);
  EXPECT_EQ(cv::norm(clean, clean0, cv::NORM_L1), 0.0);
}

// ORB keypoints of image a that land inside image b through the ground truth, and the share
// of them that b re-detects within `tol` px.
double OrbRepeatability(const cv::Mat& a, const Pose2D& pa, const cv::Mat& b, const Pose2D& pb,
                        const ImageGeometry& g, double tol, int* mapped) {
  auto orb = cv::ORB::create(250, 1.2f, 8);
  std::vector<cv::KeyPoint> ka, kb;
  orb->detect(a, ka);
  orb->detect(b, kb);
  int inside = 0, hit = 0;
  for (const auto& k : ka) {
    const Vec2 q = ImageFromFloor(pb, g, FloorFromImage(pa, g, {k.pt.x, k.pt.y}));
    if (q.x < 32 || q.y < 32 || q.x > b.cols - 33 || q.y > b.rows - 33) continue;
    ++inside;
    for (const auto& l : kb) {
      if (std::hypot(l.pt.x - q.x, l.pt.y - q.y) <= tol) {
        ++hit;
        break;
      }
    }
  }
  *mapped = inside;
  return inside > 0 ? double(hit) / inside : 0.0;
}

// Inliers of the best rotation + translation between ORB matches (RANSAC, 3 px).
int ConsistentMatches(const cv::Mat& a, const cv::Mat& b) {
  auto orb = cv::ORB::create(250, 1.2f, 8);
  std::vector<cv::KeyPoint> ka, kb;
  cv::Mat da, db;
  orb->detectAndCompute(a, cv::noArray(), ka, da);
  orb->detectAndCompute(b, cv::noArray(), kb, db);
  cv::BFMatcher matcher(cv::NORM_HAMMING, true);
  std::vector<cv::DMatch> m;
  matcher.match(da, db, m);
  std::vector<cv::Point2f> pa, pb;
  for (const auto& x : m) {
    pa.push_back(ka[x.queryIdx].pt);
    pb.push_back(kb[x.trainIdx].pt);
  }
  if (pa.size() < 3) return 0;
  cv::Mat inliers;
  cv::estimateAffinePartial2D(pa, pb, inliers, cv::RANSAC, 3.0, 5000, 0.999);
  return inliers.empty() ? 0 : cv::countNonZero(inliers);
}

TEST(Floor, OrbRepeatsAcrossDaysAndDifferentPlacesDoNotMatch) {
  const Floor floor(Surface::kAsphalt, 1);
  const Camera cam(CameraOptions{});  // with every sensor effect
  const ImageGeometry g = cam.options().Geometry();
  const Pose2D map_pose{2.0, 1.0, 0.0};
  const Pose2D later_pose{2.03, 1.015, 0.7};
  FloorState day0, day90;
  day0.visit_seed = 1;
  day90.day = 90;
  day90.visit_seed = 5;
  const cv::Mat a = cam.Capture(floor, map_pose, day0, {}, 11);
  const cv::Mat b = cam.Capture(floor, later_pose, day90, {1.06, 0.05, -0.08}, 12);
  int mapped = 0;
  const double rep = OrbRepeatability(a, map_pose, b, later_pose, g, 3.0, &mapped);
  EXPECT_GT(mapped, 60);
  EXPECT_GE(rep, 0.5) << "repeatability over " << mapped << " keypoints";

  const int same = ConsistentMatches(a, b);
  const cv::Mat elsewhere = cam.Capture(floor, {2.6, 1.4, 0.7}, day90, {}, 13);
  const cv::Mat other_seed = cam.Capture(Floor(Surface::kAsphalt, 2), later_pose, day90, {}, 14);
  const int diff1 = ConsistentMatches(a, elsewhere);
  const int diff2 = ConsistentMatches(a, other_seed);
  std::printf(
      "ORB repeatability day 0 -> day 90: %.1f%% of %d keypoints; consistent matches: "
      "same place %d, elsewhere %d, other floor %d\n",
      100 * rep, mapped, same, diff1, diff2);
  EXPECT_GE(same, 40);
  EXPECT_LE(diff1, 10);
  EXPECT_LE(diff2, 10);
}

// Relief shading by a directional light: a flat surface is untouched, relief is shaded
// (brightness preserved on average), and a light from the opposite side shades it oppositely.
TEST(Floor, ReliefIsShadedByTheLightAndTurnsWithIt) {
  const Homography h = {0.00025, 0, 0, 0, 0.00025, 0, 0, 0, 1};
  auto render = [&](Surface surface, double directional, double azimuth) {
    FloorState st;
    st.directional = directional;
    st.light_azimuth = azimuth;
    cv::Mat out;
    Floor(surface, 3).Render(h, 320, 240, 2, st, &out);
    return out;
  };
  // No relief on a flat floor: the light changes nothing.
  EXPECT_EQ(
      cv::norm(render(Surface::kFlat, 0.0, 0.0), render(Surface::kFlat, 0.8, 0.0), cv::NORM_INF),
      0.0);
  const cv::Mat plain = render(Surface::kAsphalt, 0.0, 0.0);
  const cv::Mat from_u = render(Surface::kAsphalt, 0.5, 0.0);
  const cv::Mat from_minus_u = render(Surface::kAsphalt, 0.5, M_PI);
  cv::Mat s0, s1;
  cv::divide(from_u, plain + 1e-3, s0);
  cv::divide(from_minus_u, plain + 1e-3, s1);
  cv::Scalar m0, sd0;
  cv::meanStdDev(s0, m0, sd0);
  EXPECT_NEAR(m0[0], 1.0, 0.05);  // flat patches keep their reflectance
  EXPECT_GT(sd0[0], 0.1);         // slopes are shaded
  // Opposite lights shade the same slopes oppositely.
  cv::Mat d0 = s0 - 1.0, d1 = s1 - 1.0;
  const double corr = d0.dot(d1) / std::sqrt(d0.dot(d0) * d1.dot(d1));
  EXPECT_LT(corr, -0.5) << corr;
  // The shading follows the relief seen in the image: turning the camera by 180 degrees with a
  // camera-fixed light is the same as lighting the unturned view from the other side.
  cv::Mat turned;
  const Pose2D centre{0.04, 0.03, 0.0};
  const Camera cam(Ideal());
  const cv::Mat a = cam.Capture(Floor(Surface::kAsphalt, 3), centre, {}, {}, 1);
  const cv::Mat b = cam.Capture(Floor(Surface::kAsphalt, 3), {0.04, 0.03, M_PI}, {}, {}, 1);
  cv::rotate(b, turned, cv::ROTATE_180);
  cv::Mat diff;
  cv::absdiff(a, turned, diff);
  EXPECT_GT(cv::mean(diff)[0], 4.0);  // same place, same floor: only the shading differs
  Lighting flipped;
  flipped.azimuth_offset = M_PI;
  const cv::Mat c = cam.Capture(Floor(Surface::kAsphalt, 3), centre, {}, flipped, 1);
  cv::absdiff(c, turned, diff);
  EXPECT_LT(cv::mean(diff)[0], 1.5);
}

TEST(Floor, RejectsBadInput) {
  const Floor floor(Surface::kAsphalt, 1);
  cv::Mat out;
  const Homography h = {0.00025, 0, 0, 0, 0.00025, 0, 0, 0, 1};
  EXPECT_THROW(floor.Render(h, 0, 10, 2, {}, &out), std::invalid_argument);
  EXPECT_THROW(floor.Render(h, 10, 10, 0, {}, &out), std::invalid_argument);
  FloorState bad;
  bad.day = -1;
  EXPECT_THROW(floor.Render(h, 10, 10, 2, bad, &out), std::invalid_argument);
  const Homography singular = {0, 0, 0, 0, 0, 0, 0, 0, 1};
  EXPECT_THROW(floor.Render(singular, 10, 10, 2, {}, &out), std::invalid_argument);
  FloorState light;
  light.directional = 1.5;
  EXPECT_THROW(floor.Render(h, 10, 10, 2, light, &out), std::invalid_argument);
  light.directional = 0.5;
  light.light_elevation = 0.0;
  EXPECT_THROW(floor.Render(h, 10, 10, 2, light, &out), std::invalid_argument);
  EXPECT_THROW(ParseSurface("marble"), std::invalid_argument);
  EXPECT_EQ(ParseSurface(SurfaceName(Surface::kLaminate)), Surface::kLaminate);
}

TEST(Floor, LowContrastSurfacesHaveFineFaintStructure) {
  const Camera cam(Ideal());
  cv::Scalar m, asphalt_sd;
  cv::meanStdDev(cam.Capture(Floor(Surface::kAsphalt, 4), {1.0, 2.0, 0.2}, {}, {}, 1), m,
                 asphalt_sd);
  for (Surface s : {Surface::kSmoothConcrete, Surface::kEpoxy}) {
    const Floor floor(s, 4);
    const cv::Mat a = cam.Capture(floor, {1.0, 2.0, 0.2}, {}, {}, 1);
    cv::Scalar mean, sd;
    cv::meanStdDev(a, mean, sd);
    std::printf("%s: grey-level sd %.1f (asphalt %.1f)\n", SurfaceName(s).c_str(), sd[0],
                asphalt_sd[0]);
    // Faint: a few grey levels (real smooth concrete photos: 7 to 13), far below asphalt.
    EXPECT_GT(sd[0], 1.5) << SurfaceName(s);
    EXPECT_LT(sd[0], 12.0) << SurfaceName(s);
    EXPECT_LT(sd[0], 0.5 * asphalt_sd[0]) << SurfaceName(s);
    // Fine: detail at the pixel scale, fixed to the floor, different at another place.
    cv::Mat f, blur;
    a.convertTo(f, CV_32F);
    cv::GaussianBlur(f, blur, cv::Size(), 2.0);
    cv::meanStdDev(f - blur, mean, sd);
    EXPECT_GT(sd[0], 0.3) << SurfaceName(s);
    cv::Mat x, y;
    a.convertTo(x, CV_32F, 1.0 / 255);
    cam.Capture(floor, {1.7, 2.4, 0.2}, {}, {}, 1).convertTo(y, CV_32F, 1.0 / 255);
    const cv::Mat all(x.size(), CV_8U, cv::Scalar(255));
    EXPECT_LT(std::abs(Ncc(x, y, all)), 0.3) << SurfaceName(s);
  }
  EXPECT_EQ(ParseSurface("smooth_concrete"), Surface::kSmoothConcrete);
  EXPECT_EQ(ParseSurface("epoxy"), Surface::kEpoxy);
}

TEST(Floor, APhotoFloorShowsThePhotoWherePosesSay) {
  // A "photo": an ideal rendering of asphalt, 400 x 300 px at 0.5 mm per pixel.
  CameraOptions po = Ideal();
  po.width = 400;
  po.height = 300;
  po.meters_per_pixel = 0.0005;
  const cv::Mat photo = Camera(po).Capture(Floor(Surface::kAsphalt, 9), {5.0, 5.0, 0.0}, {}, {}, 1);
  PhotoRegion r;
  r.path = "photo.png";
  r.meters_per_pixel = 0.0005;
  r.x0 = 2.0;
  r.y0 = 1.0;
  photo.convertTo(r.reflectance, CV_32F, 1.0 / 255);
  const Floor floor({r}, 1);
  CameraOptions co = Ideal();
  co.width = 160;
  co.height = 120;
  co.meters_per_pixel = 0.0005;
  co.supersample = 1;
  const Camera cam(co);
  // Upright, image pixel centres on photo pixel centres: the crop of the photo.
  const Pose2D upright{2.0 + 0.0005 * 220, 1.0 + 0.0005 * 140, 0.0};
  const cv::Mat img = cam.Capture(floor, upright, {}, {}, 1);
  cv::Mat a, b;
  img.convertTo(a, CV_32F);
  photo(cv::Rect(220 - 80, 140 - 60, 160, 120)).convertTo(b, CV_32F);
  const cv::Mat all(a.size(), CV_8U, cv::Scalar(255));
  const double ncc = Ncc(a, b, all);
  std::printf("photo floor, upright view against the photo crop: NCC %.3f\n", ncc);
  EXPECT_GT(ncc, 0.9);
  // Turned by 90 degrees about the same centre: the crop turned.
  const cv::Mat turned = cam.Capture(floor, {upright.x, upright.y, M_PI / 2}, {}, {}, 1);
  cv::Mat crop, rot;
  photo(cv::Rect(220 - 60, 140 - 80, 120, 160)).copyTo(crop);
  cv::rotate(crop, rot, cv::ROTATE_90_COUNTERCLOCKWISE);
  rot.convertTo(b, CV_32F);
  turned.convertTo(a, CV_32F);
  const double ncc_turned = Ncc(a, b, all);
  cv::rotate(crop, rot, cv::ROTATE_90_CLOCKWISE);
  rot.convertTo(b, CV_32F);
  EXPECT_GT(ncc_turned, 0.85);
  EXPECT_LT(std::abs(Ncc(a, b, all)), 0.3);  // the other sense of rotation does not match
  // Bad photo floors and photos.
  EXPECT_THROW(Floor(Surface::kPhoto, 1), std::invalid_argument);
  EXPECT_THROW(Floor(std::vector<PhotoRegion>{}, 1), std::invalid_argument);
  EXPECT_THROW(ParseSurface("photo"), std::invalid_argument);
}

}  // namespace
}  // namespace synth
}  // namespace gtbow
