#include "ground_texture_bow/eval/synth/camera.h"

#include <cmath>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

namespace gtbow {
namespace synth {
namespace {

Vec2 Apply(const Homography& h, double u, double v) {
  const double w = h[6] * u + h[7] * v + h[8];
  return {(h[0] * u + h[1] * v + h[2]) / w, (h[3] * u + h[4] * v + h[5]) / w};
}

TEST(Camera, HomographyMatchesDatasetGeometry) {
  const Camera cam(CameraOptions{});
  const ImageGeometry g = cam.options().Geometry();
  const Pose2D p{0.7, -0.2, 2.1};
  const Homography h = cam.FloorFromImagePixel(p, 1.0, 0.0, 0.0);
  for (Vec2 px : {Vec2{0, 0}, Vec2{639, 0}, Vec2{319.5, 239.5}, Vec2{100.25, 470}}) {
    const Vec2 a = Apply(h, px.x, px.y);
    const Vec2 b = FloorFromImage(p, g, px);
    EXPECT_NEAR(a.x, b.x, 1e-12);
    EXPECT_NEAR(a.y, b.y, 1e-12);
  }
  // A scale change scales about the centre; tilt leaves the centre in place.
  const Homography s = cam.FloorFromImagePixel(p, 1.02, 1e-5, -2e-5);
  const Vec2 c = Apply(s, 319.5, 239.5);
  EXPECT_NEAR(c.x, 0.7, 1e-12);
  EXPECT_NEAR(c.y, -0.2, 1e-12);
  const Homography k = cam.FloorFromImagePixel(p, 1.02, 0, 0);
  const Vec2 e = Apply(k, 419.5, 239.5);
  EXPECT_NEAR(std::hypot(e.x - 0.7, e.y + 0.2), 100 * 0.00025 * 1.02, 1e-12);
}

TEST(Camera, SensorEffects) {
  const Floor flat(Surface::kFlat, 1);
  CameraOptions o;
  const Camera cam(o);
  const cv::Mat img = cam.Capture(flat, {0, 0, 0}, {}, {}, 3);
  ASSERT_EQ(img.type(), CV_8U);
  ASSERT_EQ(img.cols, 640);
  ASSERT_EQ(img.rows, 480);
  // Vignetting: corners darker than the centre.
  const double centre = cv::mean(img(cv::Rect(300, 220, 40, 40)))[0];
  const double corner = cv::mean(img(cv::Rect(0, 0, 40, 40)))[0];
  EXPECT_GT(centre - corner, 0.1 * centre);
  // Noise: a flat floor is not flat in the image.
  cv::Scalar mean, sd;
  cv::meanStdDev(img(cv::Rect(300, 220, 40, 40)), mean, sd);
  EXPECT_GT(sd[0], 1.0);
  // Lighting: a brighter visit gives a brighter image.
  const cv::Mat bright = cam.Capture(flat, {0, 0, 0}, {}, {1.3, 0, 0}, 3);
  EXPECT_GT(cv::mean(bright)[0], 1.2 * cv::mean(img)[0]);
  // Exposure changes between shots.
  double lo = 1e9, hi = 0;
  for (uint64_t s = 0; s < 8; ++s) {
    const double m = cv::mean(cam.Capture(flat, {0, 0, 0}, {}, {}, s))[0];
    lo = std::min(lo, m);
    hi = std::max(hi, m);
  }
  EXPECT_GT(hi - lo, 3.0);
  // Ideal camera: exactly the floor's 0.5 grey.
  CameraOptions ideal;
  ideal.sensor_effects = false;
  const cv::Mat clean = Camera(ideal).Capture(flat, {0, 0, 0}, {}, {}, 3);
  EXPECT_EQ(cv::countNonZero(clean != 128), 0);
}

// Motion blur smears along the driving direction (image u) only.
TEST(Camera, MotionBlurIsAlongTheDrivingDirection) {
  const Floor floor(Surface::kAsphalt, 2);
  auto capture = [&](double blur) {
    CameraOptions o;
    o.motion_blur = blur;
    o.noise_sigma = 0.0;
    o.shot_noise = 0.0;
    o.defocus_sigma = 0.0;
    // Same shot seed: the same jitter and exposure, blur length differs.
    return Camera(o).Capture(floor, {0.1, 0.1, 0.3}, {}, {}, 11);
  };
  auto energy = [](const cv::Mat& img, int dx, int dy) {
    cv::Mat f, g;
    img.convertTo(f, CV_32F);
    cv::Sobel(f, g, CV_32F, dx, dy);
    return cv::norm(g);
  };
  const cv::Mat sharp = capture(0.0), streaked = capture(8.0);
  const double loss_u = energy(streaked, 1, 0) / energy(sharp, 1, 0);
  const double loss_v = energy(streaked, 0, 1) / energy(sharp, 0, 1);
  EXPECT_LT(loss_u, 0.9 * loss_v) << loss_u << " " << loss_v;
}

TEST(Camera, CheckNamesTheBadField) {
  auto expect_field = [](CameraOptions o, const std::string& field) {
    try {
      o.Check();
      FAIL() << field;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  CameraOptions o;
  o.width = 0;
  expect_field(o, "width");
  o = {};
  o.meters_per_pixel = -1;
  expect_field(o, "meters_per_pixel");
  o = {};
  o.supersample = 9;
  expect_field(o, "supersample");
  o = {};
  o.vignetting = 1.5;
  expect_field(o, "vignetting");
  o = {};
  o.motion_blur = -1;
  expect_field(o, "motion_blur");
  o = {};
  o.light_directional = 2;
  expect_field(o, "light_directional");
  o = {};
  o.light_elevation = 2;
  expect_field(o, "light_elevation");
  EXPECT_NO_THROW(CameraOptions{}.Check());
}

}  // namespace
}  // namespace synth
}  // namespace gtbow
