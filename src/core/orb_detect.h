// ORB keypoint detection with a FAST threshold ladder per pyramid level: the same keypoints as
// OpenCV's ORB (cv::ORB::detect, Harris or FAST ranking, first pyramid level 0, no mask),
// found with less work. Private to the core (features.cpp).
//
// OpenCV's ORB detects FAST corners (with non-maximum suppression) at its one threshold on
// every level, keeps the 2F strongest by FAST score (F of them with the FAST ranking), ranks
// those by Harris response and keeps F. A textured floor gives tens of thousands of corners at
// level 0, each scored. Here each level is first searched at higher thresholds (`rungs`,
// highest first). A corner at a higher threshold is a corner at the lower one with the same
// score, and suppression keeps it exactly when it kept it at the lower one (a neighbour that
// drops out scored below the higher threshold, so below it). So when a rung leaves a level at
// least the 2F (F) candidates it keeps, they are the ones the base threshold would keep, and
// the rest of the level follows unchanged. A level short of them is searched again at the
// next rung, and finally at the base threshold.
#pragma once

#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

namespace gtbow {

struct OrbDetectOptions {
  int num_features = 500;
  float scale_factor = 1.2f;
  int num_levels = 8;
  int edge_threshold = 31;
  int patch_size = 31;
  bool fast_score = false;  // rank by FAST score (cv::ORB::FAST_SCORE) instead of Harris
  int fast_threshold = 20;  // the base threshold, cv::ORB's fastThreshold
  std::vector<int> rungs;   // higher thresholds tried first, highest first (empty: none)
};

struct OrbDetectStats {
  int levels = 0;           // levels searched
  int levels_on_rungs = 0;  // levels whose candidates came from a rung
};

// Whether DetectOrbKeypoints can stand for cv::ORB with these parameters: the source image at
// level 0, and keypoints far enough from the border (edge_threshold at least half the patch, and
// 4) that their orientation and Harris response read no pixel outside the level (cv::ORB would
// read its mirrored border there).
bool OrbLadderApplies(int first_level, int edge_threshold, int patch_size);

// The rungs the feature extractor uses for a base threshold t: 3t and 3t/2 (those above t
// and at most 255).
std::vector<int> DefaultOrbRungs(int fast_threshold);

// Keypoints as cv::ORB::create(num_features, scale_factor, num_levels, edge_threshold, 0, 2,
// fast_score ? FAST_SCORE : HARRIS_SCORE, patch_size, fast_threshold)->detect(image) gives
// them: the same set with the same position, size, angle, response and octave (the order
// within a level may differ). `image`: 8-bit, one channel. Throws std::invalid_argument for
// another image type or parameters OrbLadderApplies refuses.
std::vector<cv::KeyPoint> DetectOrbKeypoints(const cv::Mat& image, const OrbDetectOptions& options,
                                             OrbDetectStats* stats = nullptr);

}  // namespace gtbow
