#include "ground_texture_bow/core/sequence.h"

#include <cmath>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

namespace gtbow {
namespace {

const ImageGeometry kGeometry{200, 100, 0.001};

ImageFeatures View(std::vector<Keypoint> keypoints, int first_row_value) {
  ImageFeatures f;
  f.keypoints = std::move(keypoints);
  f.descriptors = cv::Mat(static_cast<int>(f.keypoints.size()), 32, CV_8U);
  for (int r = 0; r < f.descriptors.rows; ++r) f.descriptors.row(r).setTo(first_row_value + r);
  return f;
}

Keypoint At(float x, float y, float angle = 0.5f) {
  Keypoint k;
  k.x = x;
  k.y = y;
  k.angle = angle;
  k.size = 31;
  return k;
}

TEST(CombineViews, OlderViewsAreMovedIntoTheNewestImagesFrame) {
  const ImageFeatures newest = View({At(10, 10), At(150, 60)}, 0);
  const ImageFeatures older = View({At(20, 30, 6.2f), At(100, 50, 1.0f)}, 100);
  // The older image 0.12 m along the newest's x and turned 0.1 rad.
  const Pose2D p0{1.0, 2.0, 0.3};
  const Pose2D p1 = Compose(p0, {0.12, 0.01, 0.1});
  const ImageFeatures c = CombineViews({&newest, &older}, {p0, p1}, kGeometry);
  ASSERT_EQ(c.keypoints.size(), 4u);
  ASSERT_EQ(c.descriptors.rows, 4);
  // The newest's own keypoints first, untouched.
  EXPECT_EQ(c.keypoints[0].x, 10.0f);
  EXPECT_EQ(c.keypoints[1].y, 60.0f);
  EXPECT_EQ(c.descriptors.at<uint8_t>(1, 0), 1);
  // An older keypoint lands where its floor point appears in the newest image: 120 px further
  // along x (outside the image), 10 px along y, turned by 0.1 rad about the older centre.
  const double cu = 0.5 * (kGeometry.width - 1), cv = 0.5 * (kGeometry.height - 1);
  for (int k = 0; k < 2; ++k) {
    const Keypoint& in = older.keypoints[k];
    const double du = in.x - cu, dv = in.y - cv;
    const double ex = cu + 120 + std::cos(0.1) * du - std::sin(0.1) * dv;
    const double ey = cv + 10 + std::sin(0.1) * du + std::cos(0.1) * dv;
    EXPECT_NEAR(c.keypoints[2 + k].x, ex, 1e-3);
    EXPECT_NEAR(c.keypoints[2 + k].y, ey, 1e-3);
    EXPECT_EQ(c.descriptors.at<uint8_t>(2 + k, 5), 100 + k);
  }
  EXPECT_NEAR(c.keypoints[2].angle, 6.2 + 0.1 - 2 * M_PI, 1e-5);  // wrapped to [0, 2 pi)
  EXPECT_NEAR(c.keypoints[3].angle, 1.1, 1e-5);
}

TEST(CombineViews, APlaceOfTheFloorCountsOnce) {
  const ImageFeatures newest = View({At(50, 50), At(120, 40)}, 0);
  // The same pose: a keypoint 1.5 px from one of the newest's is the same point seen again,
  // one 20 px away is another; two of the older view's own keypoints close together both stay.
  const ImageFeatures older = View({At(51.5f, 50), At(140, 40), At(80, 20), At(81, 20)}, 100);
  const ImageFeatures oldest = View({At(80.5f, 20), At(10, 90)}, 200);
  const Pose2D p{0, 0, 0};
  const ImageFeatures c = CombineViews({&newest, &older, &oldest}, {p, p, p}, kGeometry);
  ASSERT_EQ(c.keypoints.size(), 6u);
  EXPECT_EQ(c.keypoints[2].x, 140.0f);
  EXPECT_EQ(c.keypoints[3].x, 80.0f);
  EXPECT_EQ(c.keypoints[4].x, 81.0f);
  EXPECT_EQ(c.keypoints[5].x, 10.0f);
  EXPECT_EQ(c.descriptors.at<uint8_t>(5, 0), 201);
  // One view alone is itself.
  const ImageFeatures alone = CombineViews({&newest}, {p}, kGeometry);
  EXPECT_EQ(alone.keypoints.size(), 2u);
  EXPECT_EQ(cv::norm(alone.descriptors, newest.descriptors, cv::NORM_L1), 0.0);
}

TEST(CombineViews, MismatchedInputIsNamed) {
  const ImageFeatures a = View({At(1, 1)}, 0);
  ImageFeatures b = View({At(2, 2), At(3, 3)}, 0);
  const Pose2D p{};
  auto message = [&](auto&& call) {
    try {
      call();
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message([&] {
              CombineViews({&a, &b}, {p}, kGeometry);
            }).find("one pose per view"),
            std::string::npos);
  b.descriptors = b.descriptors.rowRange(0, 1).clone();
  EXPECT_NE(message([&] {
              CombineViews({&a, &b}, {p, p}, kGeometry);
            }).find("view 1 has 2"),
            std::string::npos);
  ImageFeatures wide = View({At(2, 2)}, 0);
  wide.descriptors = cv::Mat(1, 64, CV_8U, cv::Scalar(0));
  EXPECT_NE(message([&] {
              CombineViews({&a, &wide}, {p, p}, kGeometry);
            }).find("differ in type"),
            std::string::npos);
}

ProcessedImage Image(int width, float first_x) {
  ProcessedImage p;
  p.width = width;
  p.height = 100;
  p.features = View({At(first_x, 10)}, 0);
  return p;
}

TEST(QuerySequence, KeepsTheLastImagesWithOdometryWithinItsSpan) {
  SequenceOptions o;
  o.length = 3;
  o.max_span = 0.08;
  QuerySequence seq(o);
  for (int i = 0; i < 4; ++i) seq.Push(Image(200, static_cast<float>(i)), Pose2D{0.03 * i, 0, 0});
  ASSERT_EQ(seq.size(), 3u);
  EXPECT_EQ(seq.images()[0]->features.keypoints[0].x, 3.0f);  // newest first
  EXPECT_EQ(seq.images()[2]->features.keypoints[0].x, 1.0f);
  EXPECT_NEAR(seq.poses()[2].x, 0.03, 1e-12);
  // At 0.15 m: the image 0.06 m back stays, the one 0.09 m back is beyond 0.08 m.
  seq.Push(Image(200, 4), Pose2D{0.15, 0, 0});
  EXPECT_EQ(seq.size(), 2u);
  // An image without odometry starts again; so does another image size.
  seq.Push(Image(200, 5), std::nullopt);
  EXPECT_EQ(seq.size(), 1u);
  seq.Push(Image(200, 6), Pose2D{0.2, 0, 0});
  EXPECT_EQ(seq.size(), 1u);  // the one before has no odometry to relate it
  seq.Push(Image(200, 7), Pose2D{0.21, 0, 0});
  EXPECT_EQ(seq.size(), 2u);
  seq.Push(Image(320, 8), Pose2D{0.22, 0, 0});
  EXPECT_EQ(seq.size(), 1u);
  o.length = 0;
  EXPECT_THROW(QuerySequence{o}, std::invalid_argument);
  o.length = 2;
  o.max_span = 0;
  EXPECT_THROW(QuerySequence{o}, std::invalid_argument);
}

// What QuerySequence keeps and gtbow eval combines: the images up to the first older one
// beyond the span or without odometry, at most `length`.
TEST(ImagesInSpan, StopsAtTheFirstOlderImageBeyondTheSpan) {
  SequenceOptions o;
  o.length = 5;
  o.max_span = 0.1;
  using P = std::optional<Pose2D>;
  EXPECT_EQ(ImagesInSpan({}, o), 0u);
  EXPECT_EQ(ImagesInSpan({P{}}, o), 1u);  // no odometry: the image alone
  EXPECT_EQ(ImagesInSpan({P{}, Pose2D{0, 0, 0}}, o), 1u);
  const Pose2D at{1, 1, 0};
  EXPECT_EQ(ImagesInSpan({at, Pose2D{1.05, 1, 0}, Pose2D{1, 1.09, 0}}, o), 3u);
  // The one 0.2 m back ends the sequence; the one after it, close again, is not taken.
  EXPECT_EQ(ImagesInSpan({at, Pose2D{1.05, 1, 0}, Pose2D{1.2, 1, 0}, Pose2D{1, 1.06, 0}}, o), 2u);
  EXPECT_EQ(ImagesInSpan({at, Pose2D{1.05, 1, 0}, P{}, Pose2D{1, 1.06, 0}}, o), 2u);
  o.length = 2;
  EXPECT_EQ(ImagesInSpan({at, Pose2D{1.05, 1, 0}, Pose2D{1, 1.09, 0}}, o), 2u);
  // Exactly max_span away belongs (0.25 and 0.5 are exact in binary).
  o.max_span = 0.25;
  EXPECT_EQ(ImagesInSpan({Pose2D{0.5, 0, 0}, Pose2D{0.25, 0, 0}}, o), 2u);
  EXPECT_EQ(ImagesInSpan({Pose2D{0.5, 0, 0}, Pose2D{0.2499, 0, 0}}, o), 1u);
}

TEST(SequenceFix, TheImageAloneFirstThenTheCombinedView) {
  SequenceOptions o;
  o.length = 3;
  int singles = 0, combined = 0;
  auto fix = [](bool success, int image) {
    Localization l;
    l.success = success;
    l.image = image;
    return l;
  };
  bool used = true;
  Localization l = SequenceFix(
      o, [&] { return ++singles, fix(true, 1); }, [&] { return ++combined, fix(true, 2); }, &used);
  EXPECT_EQ(l.image, 1u);
  EXPECT_FALSE(used);
  EXPECT_EQ(combined, 0) << "the combined view is not localized when the image alone gives a fix";
  l = SequenceFix(
      o, [&] { return ++singles, fix(false, 1); }, [&] { return ++combined, fix(true, 2); }, &used);
  EXPECT_EQ(l.image, 2u);
  EXPECT_TRUE(used);
  o.single_first = false;
  l = SequenceFix(
      o, [&] { return ++singles, fix(true, 1); }, [&] { return ++combined, fix(false, 2); }, &used);
  EXPECT_FALSE(l.success);
  EXPECT_TRUE(used);
  EXPECT_EQ(singles, 2);
  EXPECT_EQ(combined, 2);
}

}  // namespace
}  // namespace gtbow
