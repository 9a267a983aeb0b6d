#include "ground_texture_bow/core/features.h"

#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "ground_texture_bow/core/synth/camera.h"

namespace gtbow {
namespace {

cv::Mat Asphalt(double theta = 0.0) {
  synth::CameraOptions o;
  o.sensor_effects = false;
  return synth::Camera(o).Capture(synth::Floor(synth::Surface::kAsphalt, 3), {0.5, 0.5, theta}, {}, {}, 1);
}

TEST(Features, OrbRecordsFollowThePaperDefaults) {
  FeatureExtractor fx(FeatureOptions{});
  const ImageFeatures f = fx.Extract(Asphalt());
  EXPECT_GT(f.size(), 200u);
  EXPECT_LE(f.size(), 250u);
  EXPECT_EQ(f.descriptors.rows, static_cast<int>(f.size()));
  EXPECT_EQ(f.descriptors.cols, 32);
  EXPECT_EQ(f.descriptors.type(), CV_8U);
  int max_octave = 0;
  for (const auto& k : f.keypoints) {
    EXPECT_GE(k.angle, 0.0f);
    EXPECT_LT(k.angle, 2 * M_PI);
    EXPECT_GE(k.octave, 0);
    EXPECT_LT(k.octave, 8);
    EXPECT_GT(k.size, 0.0f);
    max_octave = std::max(max_octave, k.octave);
  }
  EXPECT_GE(max_octave, 3);  // keypoints spread over the pyramid
}

TEST(Features, OrientationFollowsImageRotation) {
  // Rotate the image by 90 degrees: matched keypoints' angles differ by about 90 degrees.
  FeatureExtractor fx(FeatureOptions{});
  const cv::Mat a = Asphalt();
  cv::Mat b;
  cv::rotate(a, b, cv::ROTATE_90_CLOCKWISE);
  const ImageFeatures fa = fx.Extract(a), fb = fx.Extract(b);
  int agree = 0, total = 0;
  for (const auto& ka : fa.keypoints) {
    // (x, y) -> (H - 1 - y, x) under a clockwise rotation.
    const float bx = a.rows - 1 - ka.y, by = ka.x;
    for (const auto& kb : fb.keypoints) {
      if (std::hypot(kb.x - bx, kb.y - by) < 1.5f && kb.octave == ka.octave) {
        ++total;
        const double d = std::remainder(kb.angle - ka.angle - M_PI / 2, 2 * M_PI);
        agree += std::abs(d) < 0.2 ? 1 : 0;
        break;
      }
    }
  }
  ASSERT_GT(total, 50);
  EXPECT_GT(double(agree) / total, 0.9);
}

TEST(Features, SiftAndBadInput) {
  FeatureOptions o;
  o.type = FeatureType::kSift;
  FeatureExtractor sift(o);
  const ImageFeatures f = sift.Extract(Asphalt());
  EXPECT_GT(f.size(), 100u);
  EXPECT_LE(f.size(), 250u);
  EXPECT_EQ(f.descriptors.cols, 128);
  EXPECT_EQ(f.descriptors.type(), CV_32F);

  FeatureExtractor orb(FeatureOptions{});
  EXPECT_THROW(orb.Extract(cv::Mat()), std::invalid_argument);
  EXPECT_THROW(orb.Extract(cv::Mat(10, 10, CV_8UC3)), std::invalid_argument);
  // A blank floor has no features: an empty result, not an error.
  EXPECT_EQ(orb.Extract(cv::Mat(480, 640, CV_8U, cv::Scalar(100))).size(), 0u);
  FeatureOptions bad;
  bad.orb_scale_factor = 1.0f;
  EXPECT_THROW(FeatureExtractor{bad}, std::invalid_argument);
  EXPECT_THROW(ParseFeatureType("surf"), std::invalid_argument);
}

}  // namespace
}  // namespace gtbow
