#include "ground_texture_bow/core/features.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "ground_texture_bow/eval/synth/camera.h"
#include "orb_detect.h"

namespace gtbow {
namespace {

cv::Mat Asphalt(double theta = 0.0) {
  synth::CameraOptions o;
  o.sensor_effects = false;
  return synth::Camera(o).Capture(synth::Floor(synth::Surface::kAsphalt, 3), {0.5, 0.5, theta}, {},
                                  {}, 1);
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

// A faint floor: the asphalt texture squeezed to a tenth of its contrast around mid grey, with
// sensor noise (what a smooth concrete floor gives a camera).
cv::Mat Faint(const cv::Mat& img, double scale = 0.1) {
  cv::Mat f, noise(img.size(), CV_32F);
  img.convertTo(f, CV_32F);
  cv::randn(noise, 0, 1.0);
  cv::Mat out;
  cv::Mat(128 + scale * (f - cv::mean(f)[0]) + noise).convertTo(out, CV_8U);
  return out;
}

TEST(Features, ContrastNormalisationStretchesOnlyFaintFloors) {
  FeatureOptions o;
  o.contrast = Contrast::kNormalize;
  const FeatureExtractor fx(o);
  const cv::Mat rough = Asphalt();
  // A rough floor is left as it is (gain 1): exactly the paper's ORB.
  EXPECT_EQ(cv::norm(fx.Preprocess(rough), rough, cv::NORM_INF), 0.0);
  const ImageFeatures plain = FeatureExtractor(FeatureOptions{}).Extract(rough),
                      same = fx.Extract(rough);
  ASSERT_EQ(plain.size(), same.size());
  EXPECT_EQ(cv::norm(plain.descriptors, same.descriptors, cv::NORM_HAMMING), 0.0);
  // A faint one is stretched, and yields many more keypoints than plain ORB on it.
  const cv::Mat faint = Faint(rough);
  const cv::Mat stretched = fx.Preprocess(faint);
  cv::Scalar m0, s0, m1, s1;
  cv::meanStdDev(faint, m0, s0);
  cv::meanStdDev(stretched, m1, s1);
  EXPECT_GT(s1[0], 2.5 * s0[0]);
  EXPECT_NEAR(m1[0], 128, 3);
  const size_t n_plain = FeatureExtractor(FeatureOptions{}).Extract(faint).size();
  const size_t n_norm = fx.Extract(faint).size();
  std::printf("faint floor: plain ORB %zu keypoints, contrast-normalised %zu\n", n_plain, n_norm);
  EXPECT_GT(n_norm, 2 * n_plain + 50);
  // CLAHE equalises every image.
  o.contrast = Contrast::kClahe;
  EXPECT_GT(cv::norm(FeatureExtractor(o).Preprocess(rough), rough, cv::NORM_L1), 0.0);
  EXPECT_GT(FeatureExtractor(o).Extract(faint).size(), 2 * n_plain + 50);
}

TEST(Features, ClaheAndAGridSpreadKeypointsOverFaintParts) {
  // Texture in the left quarter, a faint floor elsewhere: plain ORB crowds into the texture;
  // CLAHE equalises each tile's contrast and the grid takes each cell's share (the presets).
  cv::Mat img = Faint(Asphalt(), 0.15);
  const cv::Mat rough = Asphalt(0.7);
  rough(cv::Rect(0, 0, 160, 480)).copyTo(img(cv::Rect(0, 0, 160, 480)));
  auto share_outside = [](const ImageFeatures& f) {
    size_t n = 0;
    for (const auto& k : f.keypoints) n += k.x > 200 ? 1 : 0;
    return static_cast<double>(n) / std::max<size_t>(1, f.size());
  };
  const ImageFeatures plain = FeatureExtractor(FeatureOptions{}).Extract(img);
  FeatureOptions g;
  g.contrast = Contrast::kClahe;
  g.grid_cols = 4;
  g.grid_rows = 3;
  const ImageFeatures no_refill = FeatureExtractor(g).Extract(img);
  g.grid_refill = true;
  const ImageFeatures grid = FeatureExtractor(g).Extract(img);
  FeatureOptions c = g;
  c.grid_cols = c.grid_rows = 0;
  const ImageFeatures clahe = FeatureExtractor(c).Extract(img);
  std::printf(
      "keypoints outside the textured quarter: plain %.0f%% of %zu, clahe %.0f%% of %zu, clahe + "
      "grid "
      "%.0f%% of %zu, with refill %.0f%% of %zu\n",
      100 * share_outside(plain), plain.size(), 100 * share_outside(clahe), clahe.size(),
      100 * share_outside(no_refill), no_refill.size(), 100 * share_outside(grid), grid.size());
  EXPECT_LT(share_outside(plain), 0.1);
  EXPECT_GT(share_outside(grid), 0.6);  // 9 of the 12 cells lie outside
  EXPECT_GT(share_outside(grid), share_outside(clahe));
  EXPECT_GT(share_outside(grid), share_outside(no_refill));
  EXPECT_EQ(grid.size(), 250u);
  EXPECT_EQ(grid.descriptors.rows, 250);
  // Deterministic.
  const ImageFeatures again = FeatureExtractor(g).Extract(img);
  EXPECT_EQ(cv::norm(grid.descriptors, again.descriptors, cv::NORM_HAMMING), 0.0);
}

TEST(Features, AnAdaptiveThresholdFindsKeypointsOnAFaintFloor) {
  const cv::Mat faint = Faint(Asphalt(), 0.08);
  const size_t fixed = FeatureExtractor(FeatureOptions{}).Extract(faint).size();
  FeatureOptions a;
  a.orb_min_fast_threshold = 5;
  const ImageFeatures adaptive = FeatureExtractor(a).Extract(faint);
  std::printf("faint floor: FAST threshold 20: %zu keypoints, adaptive (down to 5): %zu\n", fixed,
              adaptive.size());
  EXPECT_GT(adaptive.size(), 2 * fixed + 50);
  EXPECT_EQ(adaptive.descriptors.rows, static_cast<int>(adaptive.size()));
  // A rough floor reaches num_features at the first threshold: the same keypoints as plain ORB.
  const cv::Mat rough = Asphalt();
  const ImageFeatures plain = FeatureExtractor(FeatureOptions{}).Extract(rough),
                      same = FeatureExtractor(a).Extract(rough);
  ASSERT_EQ(plain.size(), same.size());
  size_t common = 0;
  for (const auto& k : plain.keypoints) {
    for (const auto& m : same.keypoints)
      common += (k.x == m.x && k.y == m.y && k.octave == m.octave) ? 1 : 0;
  }
  EXPECT_GT(common, plain.size() * 9 / 10);
  // Adaptation is for ORB; a grid needs both sizes.
  FeatureOptions sift = a;
  sift.type = FeatureType::kSift;
  EXPECT_THROW(FeatureExtractor{sift}, std::invalid_argument);
  FeatureOptions half;
  half.grid_cols = 4;
  EXPECT_THROW(FeatureExtractor{half}, std::invalid_argument);
}

// Transient marks (issue 28): debris dots and thin scuffs on a faint floor are the strongest
// corners, and the transient step fills them with the floor's local median before detection.
TEST(Features, TransientMarksAreFilledAndKeypointsLeaveThem) {
  const cv::Mat floor = Faint(Asphalt(), 0.15);
  cv::Mat marked = floor.clone(), where = cv::Mat::zeros(floor.size(), CV_8U);
  cv::RNG rng(7);
  for (int i = 0; i < 120; ++i) {  // debris: dots of radius 1 to 2.5 px, dark or bright
    const cv::Point c(rng.uniform(20, floor.cols - 20), rng.uniform(20, floor.rows - 20));
    const int r = rng.uniform(1, 3);
    const int v = rng.uniform(0, 2) ? 235 : 20;
    cv::circle(marked, c, r, v, cv::FILLED);
    cv::circle(where, c, r, 255, cv::FILLED);
  }
  for (int i = 0; i < 12; ++i) {  // scuffs: lines 1-2 px wide, 20-80 px long
    const cv::Point a(rng.uniform(20, floor.cols - 100), rng.uniform(20, floor.rows - 100));
    const cv::Point b = a + cv::Point(rng.uniform(20, 80), rng.uniform(-20, 80));
    const int v = rng.uniform(0, 2) ? 220 : 35, w = rng.uniform(1, 3);
    cv::line(marked, a, b, v, w);
    cv::line(where, a, b, 255, w);
  }
  FeatureOptions o;  // the presets' extractor: CLAHE and a 4 x 3 grid
  o.contrast = Contrast::kClahe;
  o.grid_cols = 4;
  o.grid_rows = 3;
  FeatureOptions t = o;
  t.transient_median = 7;
  const FeatureExtractor plain(o), transient(t);
  // Off: the image as it was.
  EXPECT_EQ(cv::norm(plain.RemoveTransients(marked), marked, cv::NORM_INF), 0.0);
  // The marks' pixels come back near the clean floor; the rest of the floor is hardly touched.
  const cv::Mat filled = transient.RemoveTransients(marked);
  cv::Mat err_before, err_after;
  cv::absdiff(marked, floor, err_before);
  cv::absdiff(filled, floor, err_after);
  const double before = cv::mean(err_before, where)[0], after = cv::mean(err_after, where)[0];
  cv::Mat rest;
  cv::dilate(where, rest, cv::Mat::ones(7, 7, CV_8U));
  cv::bitwise_not(rest, rest);
  cv::Mat changed;
  cv::compare(transient.RemoveTransients(floor), floor, changed, cv::CMP_NE);
  const double changed_clean = cv::countNonZero(changed) / static_cast<double>(floor.total());
  cv::compare(filled, marked, changed, cv::CMP_NE);
  const double changed_rest =
      cv::countNonZero(changed & rest) / static_cast<double>(cv::countNonZero(rest));
  std::printf(
      "transient marks: error on the marks %.1f -> %.1f grey levels; pixels changed: %.2f%% of "
      "the unmarked floor, %.2f%% of the clean one\n",
      before, after, 100 * changed_rest, 100 * changed_clean);
  EXPECT_LT(after, 0.2 * before);
  EXPECT_LT(changed_rest, 0.05);
  EXPECT_LT(changed_clean, 0.05);
  // Keypoints on or beside a mark: most of plain ORB's, few with the marks filled.
  auto on_marks = [&](const ImageFeatures& f) {
    cv::Mat near;
    cv::dilate(where, near, cv::Mat::ones(7, 7, CV_8U));
    size_t n = 0;
    for (const auto& k : f.keypoints) {
      n += near.at<uint8_t>(cvRound(k.y), cvRound(k.x)) ? 1 : 0;
    }
    return static_cast<double>(n) / std::max<size_t>(1, f.size());
  };
  const ImageFeatures fp = plain.Extract(marked), ft = transient.Extract(marked);
  std::printf(
      "keypoints within 3 px of a mark: %.0f%% of %zu, with the marks filled %.0f%% of %zu\n",
      100 * on_marks(fp), fp.size(), 100 * on_marks(ft), ft.size());
  EXPECT_GT(on_marks(fp), 0.4);
  EXPECT_LT(on_marks(ft), 0.5 * on_marks(fp));
  EXPECT_EQ(ft.size(), 250u);
  // Bright marks only: the dark ones stay as they were, the bright ones are filled.
  FeatureOptions b = t;
  b.transient_polarity = MarkPolarity::kBright;
  const cv::Mat bright_filled = FeatureExtractor(b).RemoveTransients(marked);
  cv::Mat dark_marks, bright_marks;
  cv::compare(marked, 60, dark_marks, cv::CMP_LT);
  cv::compare(marked, 200, bright_marks, cv::CMP_GT);
  dark_marks &= where;
  bright_marks &= where;
  cv::Mat err, dark_changed;
  cv::compare(bright_filled, marked, dark_changed, cv::CMP_NE);
  dark_changed &= dark_marks;
  // (only where a grown bright mark touches a dark one)
  EXPECT_LT(cv::countNonZero(dark_changed), cv::countNonZero(dark_marks) / 10);
  cv::absdiff(bright_filled, floor, err);
  EXPECT_LT(cv::mean(err, bright_marks)[0], 0.2 * cv::mean(err_before, bright_marks)[0]);
  // An even window, and a fill smaller than the window, are refused.
  FeatureOptions bad = t;
  bad.transient_median = 6;
  EXPECT_THROW(FeatureExtractor{bad}, std::invalid_argument);
  bad = t;
  bad.transient_fill = 5;
  EXPECT_THROW(FeatureExtractor{bad}, std::invalid_argument);
  // An image only queried takes query_num_features keypoints.
  FeatureOptions q = o;
  q.query_num_features = 500;
  EXPECT_EQ(FeatureExtractor(QueryFeatureOptions(q)).Extract(marked).size(), 500u);
  EXPECT_EQ(FeatureExtractor(q).Extract(marked).size(), 250u);
}

// Bright marks filled by the mean of the unmarked pixels of an 11 x 11 window.
FeatureOptions BrightMarkFill() {
  FeatureOptions o;
  o.transient_median = 5;
  o.transient_grow = 1;
  o.transient_fill = 11;
  o.transient_polarity = MarkPolarity::kBright;
  return o;
}

// `marked` with each pixel of `marks` from row `first_row` on replaced by the brute-force fill:
// the mean of the unmarked pixels of its 11 x 11 window, the 5 x 5 median where all are marked
// (counted in `*all_marked`).
cv::Mat BruteForceFill(const cv::Mat& marked, const cv::Mat& marks, int first_row,
                       int* all_marked) {
  cv::Mat median;
  cv::medianBlur(marked, median, 5);
  cv::Mat want = marked.clone();
  *all_marked = 0;
  for (int r = first_row; r < marked.rows; ++r) {
    for (int c = 0; c < marked.cols; ++c) {
      if (!marks.at<uint8_t>(r, c)) continue;
      int n = 0, total = 0;
      for (int y = std::max(0, r - 5); y < std::min(marked.rows, r + 6); ++y) {
        for (int x = std::max(0, c - 5); x < std::min(marked.cols, c + 6); ++x) {
          if (marks.at<uint8_t>(y, x)) continue;
          ++n;
          total += marked.at<uint8_t>(y, x);
        }
      }
      *all_marked += n == 0 ? 1 : 0;
      want.at<uint8_t>(r, c) =
          n > 0 ? static_cast<uint8_t>((total + n / 2) / n) : median.at<uint8_t>(r, c);
    }
  }
  return want;
}

// The fill of RemoveTransients sums each mark's window directly when marks are few and reads
// integral images when they are many: both give the mean of the unmarked pixels of the
// window (the median where all are marked), here against a brute-force fill of known marks.
TEST(Features, TransientFillMatchesBruteForceWithFewAndManyMarks) {
  for (const int spacing : {40, 4}) {  // 0.6% and 56% of the pixels marked
    cv::Mat floor(120, 160, CV_8U);
    for (int r = 0; r < floor.rows; ++r) {
      for (int c = 0; c < floor.cols; ++c) floor.at<uint8_t>(r, c) = 100 + (r * 7 + c * 3) % 3;
    }
    cv::Mat dots = cv::Mat::zeros(floor.size(), CV_8U);
    for (int r = 2; r < floor.rows; r += spacing) {
      for (int c = 3; c < floor.cols; c += spacing) dots.at<uint8_t>(r, c) = 255;
    }
    cv::Mat marked = floor.clone();
    marked.setTo(250, dots);
    const cv::Mat filled = FeatureExtractor(BrightMarkFill()).RemoveTransients(marked);
    cv::Mat marks;  // the dots grown by one pixel
    cv::dilate(dots, marks, cv::Mat::ones(3, 3, CV_8U));
    int all_marked = 0;
    const cv::Mat want = BruteForceFill(marked, marks, 0, &all_marked);
    EXPECT_EQ(cv::norm(filled, want, cv::NORM_INF), 0.0) << "dots every " << spacing << " px";
    EXPECT_GT(cv::countNonZero(marks), 0);
  }
}

// Above about 8.4 Mpx a bright image's sum no longer fits 32 bits: the many-marks fill reads
// exact sums there too (marks in the last rows, where the integral image is largest).
TEST(Features, TransientFillIsExactOnImagesAbove8Megapixels) {
  cv::Mat floor(3100, 3100, CV_8U);  // 9.6 Mpx at about 231: a sum of 2.2e9
  for (int r = 0; r < floor.rows; ++r) {
    uint8_t* f = floor.ptr<uint8_t>(r);
    for (int c = 0; c < floor.cols; ++c) f[c] = static_cast<uint8_t>(230 + (r * 7 + c * 3) % 3);
  }
  cv::Mat dots = cv::Mat::zeros(floor.size(), CV_8U);
  for (int r = floor.rows - 300; r < floor.rows; r += 4) {
    for (int c = 1; c < floor.cols; c += 4) dots.at<uint8_t>(r, c) = 255;
  }
  cv::Mat marked = floor.clone();
  marked.setTo(255, dots);
  const cv::Mat filled = FeatureExtractor(BrightMarkFill()).RemoveTransients(marked);
  cv::Mat marks;
  cv::dilate(dots, marks, cv::Mat::ones(3, 3, CV_8U));
  ASSERT_GT(cv::countNonZero(marks) * 121.0, 2.0 * floor.total());  // the integral-image path
  int all_marked = 0;
  const cv::Mat want = BruteForceFill(marked, marks, floor.rows - 302, &all_marked);
  ASSERT_EQ(all_marked, 0);
  cv::Mat differs;
  cv::compare(filled, want, differs, cv::CMP_NE);
  differs.setTo(0, ~marks);
  const int wrong = cv::countNonZero(differs);
  EXPECT_EQ(wrong, 0);
  cv::Mat changed;  // and nothing else changed
  cv::compare(filled, marked, changed, cv::CMP_NE);
  changed.setTo(0, marks);
  EXPECT_EQ(cv::countNonZero(changed), 0);
}

// The grid extractor's keypoints come strongest-chosen first (not grouped by pyramid level),
// each with the descriptor ORB computes for it.
TEST(Features, GridKeypointsKeepTheirRankAndDescriptors) {
  const cv::Mat image = Faint(Asphalt(), 0.5);
  FeatureOptions o;
  o.contrast = Contrast::kClahe;
  o.grid_cols = 4;
  o.grid_rows = 3;
  const FeatureExtractor extractor(o);
  const ImageFeatures f = extractor.Extract(image);
  ASSERT_EQ(f.size(), 250u);
  // The first 21 (a cell's share of 250 over 12 cells) include the image's strongest keypoint.
  float strongest = 0;
  for (const auto& k : f.keypoints) strongest = std::max(strongest, k.response);
  bool found = false;
  for (size_t i = 0; i < 21; ++i) found = found || f.keypoints[i].response == strongest;
  EXPECT_TRUE(found);
  bool levels_mixed = false;  // not sorted by pyramid level
  for (size_t i = 1; i < f.size(); ++i) {
    levels_mixed = levels_mixed || f.keypoints[i].octave < f.keypoints[i - 1].octave;
  }
  EXPECT_TRUE(levels_mixed);
  // Each descriptor is the one ORB gives that keypoint when it describes all 500 candidates.
  std::vector<cv::KeyPoint> candidates;
  cv::Mat desc;
  cv::ORB::create(500, o.orb_scale_factor, o.orb_num_levels, o.orb_edge_threshold, 0, 2,
                  cv::ORB::HARRIS_SCORE, o.orb_patch_size, o.orb_fast_threshold)
      ->detectAndCompute(extractor.Preprocess(image), cv::noArray(), candidates, desc);
  for (size_t i = 0; i < f.size(); ++i) {
    int row = -1;
    for (size_t j = 0; j < candidates.size(); ++j) {
      if (candidates[j].pt == cv::Point2f(f.keypoints[i].x, f.keypoints[i].y) &&
          candidates[j].octave == f.keypoints[i].octave) {
        row = static_cast<int>(j);
      }
    }
    ASSERT_GE(row, 0) << i;
    EXPECT_EQ(cv::norm(desc.row(row), f.descriptors.row(static_cast<int>(i)), cv::NORM_HAMMING),
              0.0)
        << i;
  }
}

// The threshold ladder finds cv::ORB's keypoints: the same set, each with the same position,
// size, angle, response and level, on textured and faint floors at two sizes, with Harris and
// FAST ranking; the ladder's rungs take some levels and not others (so both ways are checked).
TEST(Features, OrbThresholdLadderFindsOrbsKeypoints) {
  const auto by_place = [](const cv::KeyPoint& a, const cv::KeyPoint& b) {
    if (a.octave != b.octave) return a.octave < b.octave;
    if (a.pt.y != b.pt.y) return a.pt.y < b.pt.y;
    return a.pt.x < b.pt.x;
  };
  synth::CameraOptions small;
  small.sensor_effects = false;
  small.width = 320;
  small.height = 240;
  const cv::Mat asphalt = Asphalt();
  const cv::Mat asphalt_small = synth::Camera(small).Capture(
      synth::Floor(synth::Surface::kAsphalt, 5), {0.4, 0.6, 1.0}, {}, {}, 1);
  const cv::Mat concrete = synth::Camera(small).Capture(
      synth::Floor(synth::Surface::kSmoothConcrete, 7), {0.5, 0.5, 0.3}, {}, {}, 1);
  cv::Mat clahe_faint, clahe_concrete;
  cv::createCLAHE(2.0, cv::Size(8, 8))->apply(Faint(asphalt, 0.3), clahe_faint);
  cv::createCLAHE(2.0, cv::Size(8, 8))->apply(concrete, clahe_concrete);
  int on_rungs = 0, off_rungs = 0;
  for (const cv::Mat* image :
       std::vector<const cv::Mat*>{&asphalt, &asphalt_small, &clahe_faint, &clahe_concrete}) {
    for (int n : {500, 1000}) {
      for (bool fast_score : {false, true}) {
        OrbDetectOptions o;
        o.num_features = n;
        o.fast_score = fast_score;
        o.rungs = DefaultOrbRungs(o.fast_threshold);
        ASSERT_EQ(o.rungs, (std::vector<int>{60, 30}));
        OrbDetectStats stats;
        std::vector<cv::KeyPoint> ours = DetectOrbKeypoints(*image, o, &stats), theirs;
        cv::ORB::create(n, o.scale_factor, o.num_levels, o.edge_threshold, 0, 2,
                        fast_score ? cv::ORB::FAST_SCORE : cv::ORB::HARRIS_SCORE, o.patch_size,
                        o.fast_threshold)
            ->detect(*image, theirs);
        std::sort(ours.begin(), ours.end(), by_place);
        std::sort(theirs.begin(), theirs.end(), by_place);
        const std::string what = std::to_string(image->cols) + " x " + std::to_string(image->rows) +
                                 ", " + std::to_string(n) +
                                 (fast_score ? ", FAST score" : ", Harris");
        ASSERT_EQ(ours.size(), theirs.size()) << what;
        for (size_t i = 0; i < ours.size(); ++i) {
          const cv::KeyPoint &a = ours[i], &b = theirs[i];
          ASSERT_TRUE(a.pt == b.pt && a.size == b.size && a.angle == b.angle &&
                      a.response == b.response && a.octave == b.octave && a.class_id == b.class_id)
              << what << ", keypoint " << i;
        }
        EXPECT_EQ(stats.levels, o.num_levels);
        on_rungs += stats.levels_on_rungs;
        off_rungs += stats.levels - stats.levels_on_rungs;
      }
    }
  }
  EXPECT_GT(on_rungs, 0);
  EXPECT_GT(off_rungs, 0);
  // Keypoints whose patch would cross the border (cv::ORB reads its mirrored border there): the
  // extractor keeps cv::ORB, the detector refuses.
  EXPECT_FALSE(OrbLadderApplies(0, 10, 31));
  EXPECT_FALSE(OrbLadderApplies(1, 31, 31));
  EXPECT_TRUE(OrbLadderApplies(0, 15, 31));
  OrbDetectOptions near_border;
  near_border.edge_threshold = 10;
  EXPECT_THROW(DetectOrbKeypoints(asphalt, near_border), std::invalid_argument);
  EXPECT_THROW(DetectOrbKeypoints(cv::Mat(), OrbDetectOptions{}), std::invalid_argument);
  // Through the extractor (CLAHE and the grid, as the presets): the same keypoints and
  // descriptors, in the same order, with the ladder and with cv::ORB.
  FeatureOptions o;
  o.contrast = Contrast::kClahe;
  o.grid_cols = 4;
  o.grid_rows = 3;
  FeatureOptions plain = o;
  plain.orb_threshold_ladder = false;
  for (const cv::Mat* image : std::vector<const cv::Mat*>{&asphalt, &asphalt_small, &concrete}) {
    const ImageFeatures a = FeatureExtractor(o).Extract(*image);
    const ImageFeatures b = FeatureExtractor(plain).Extract(*image);
    ASSERT_EQ(a.size(), b.size());
    for (size_t i = 0; i < a.size(); ++i) {
      EXPECT_TRUE(a.keypoints[i].x == b.keypoints[i].x && a.keypoints[i].y == b.keypoints[i].y &&
                  a.keypoints[i].angle == b.keypoints[i].angle &&
                  a.keypoints[i].response == b.keypoints[i].response &&
                  a.keypoints[i].octave == b.keypoints[i].octave)
          << i;
    }
    EXPECT_EQ(cv::norm(a.descriptors, b.descriptors, cv::NORM_HAMMING), 0.0);
  }
}

}  // namespace
}  // namespace gtbow
