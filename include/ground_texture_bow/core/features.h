// Local features of ground images: ORB (the paper's default) or SIFT, through OpenCV.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

namespace gtbow {

enum class FeatureType { kOrb, kSift };

// Parses "orb" or "sift"; throws std::invalid_argument otherwise.
FeatureType ParseFeatureType(const std::string& name);
std::string FeatureTypeName(FeatureType type);

// Contrast adaptation before detection (the descriptors are computed on the same image).
//  kNone:      the image as it is (the paper).
//  kNormalize: a faint floor is stretched linearly about its mean until its fine detail (the
//              image minus its Gaussian blur, sigma 2 px) has the grey-level deviation
//              `contrast_target`; the gain is at least 1 and at most `contrast_max_gain`, so a
//              floor with enough contrast is left unchanged.
//  kClahe:     contrast-limited adaptive histogram equalisation (OpenCV CLAHE) of every image.
enum class Contrast { kNone, kNormalize, kClahe };
Contrast ParseContrast(const std::string& name);  // "none", "normalize" or "clahe"
std::string ContrastName(Contrast contrast);

// Which transient marks are filled: both polarities, or only those brighter (dust, grit,
// scratches on a sealed floor) or darker than the floor around them.
enum class MarkPolarity { kBoth, kBright, kDark };
MarkPolarity ParseMarkPolarity(const std::string& name);  // "both", "bright" or "dark"
std::string MarkPolarityName(MarkPolarity polarity);

struct FeatureOptions {
  FeatureType type = FeatureType::kOrb;  // detector and descriptor
  int num_features = 250;                // keypoints kept per image (paper: 250)
  // Keypoints of an image that is only queried (localization), not added to the map; 0: the
  // same as num_features. The map's memory is unchanged; on a floor that has changed, the
  // marks that came since (debris, scuffs) take the strongest places, and more keypoints keep
  // room for the floor that lasted (issue 28). Not recorded in maps: a map made without it
  // loads with it.
  int query_num_features = 0;
  // An image that is only localized (the node's localization mode, the localize service) is
  // first extracted as a keyframe is (num_features keypoints) and verified without guided
  // matching; only when that gives no fix with verification.escalate_min_inliers inliers is it
  // extracted again with query_num_features and localized in full (EscalatedFix, pose.h). Most
  // images of a floor that has not changed localize in the first pass, at a keyframe's cost. Needs
  // query_num_features above num_features. Not used for sequence queries, the maintenance mode or
  // the candidate services, which take query_num_features keypoints at once. Not recorded in maps.
  bool query_escalate = false;
  // With query_escalate, in the node's localization mode (a stream of images, in order): after a
  // first pass that gave no fix that stands, the next 1, 3, 7, ... images (doubling with each
  // such first pass in a row, at most this many) go straight to the full pass (EscalationBackoff,
  // pose.h). Where the floor has aged, most first passes would fail and cost their time for
  // nothing. 0: every image tries the first pass. The localize service, whose images are not a
  // stream, always tries it. Not recorded in maps.
  int query_escalate_backoff = 0;
  // ORB (cv::ORB); the defaults are the paper's (8 levels at scale 1.2).
  float orb_scale_factor = 1.2f;  // pyramid scale step
  int orb_num_levels = 8;         // pyramid levels
  int orb_edge_threshold = 31;    // border without features, pixels
  int orb_first_level = 0;        // pyramid level of the source image
  int orb_wta_k = 2;              // points per BRIEF comparison (2, 3 or 4)
  bool orb_fast_score = false;    // rank by FAST score instead of Harris
  int orb_patch_size = 31;        // descriptor patch, pixels
  int orb_fast_threshold = 20;    // FAST threshold, grey levels
  // ORB's keypoints found with a FAST threshold ladder per pyramid level (3x and 1.5x the
  // threshold first, each level falling back where it has too few corners): the same
  // keypoints as cv::ORB, with less work on textured floors (src/core/orb_detect.h). Used with
  // the floor adaptations below (contrast, grid, adaptive threshold) at orb_first_level 0;
  // false detects with cv::ORB itself. Not recorded in maps.
  bool orb_threshold_ladder = true;
  // Adaptation to the floor (ORB). All off is the paper's plain ORB.
  Contrast contrast = Contrast::kNone;  // contrast adaptation before detection
  double contrast_target = 12.0;        // kNormalize: fine-detail deviation to reach, grey levels
  double contrast_max_gain = 4.0;       // kNormalize: largest gain
  double clahe_clip = 2.0;              // kClahe: clip limit
  int clahe_tiles = 8;                  // kClahe: tiles along each image axis
  // Adaptive FAST threshold: when an image yields fewer than num_features keypoints, detect
  // again with the threshold halved, down to this (0: the threshold is fixed).
  int orb_min_fast_threshold = 0;
  // Spread keypoints over a grid_cols x grid_rows grid (0: off): candidates are detected
  // `grid_oversample` times num_features, then each cell's share (num_features / cells) is
  // taken best-first, and the remainder filled best-first.
  int grid_cols = 0;
  int grid_rows = 0;
  double grid_oversample = 2.0;
  // With the grid: cells left with under half their share of candidates (a faint part of an
  // otherwise rough floor, which the global ranking left none) are searched again on their own
  // (masked, at the lowest FAST threshold). Off in the presets: it cost accuracy and doubled
  // extraction time on the real-floor benchmark (docs/RESULTS.md).
  bool grid_refill = false;
  // Transient marks (issue 28): debris, scuffs and the like come and go, and on a faint floor
  // they are the strongest corners of an image, outvoting the floor that lasts. Before the
  // contrast step, a pixel further than `transient_k` robust deviations (1.4826 x the image's
  // median absolute difference) from the median of its `transient_median` x `transient_median`
  // neighbourhood is taken for a mark (of `transient_polarity`: brighter, darker or either);
  // the marks, grown by `transient_grow` pixels, take the mean of the unmarked pixels of the
  // `transient_fill` x `transient_fill` window. Small, strong marks go; a floor's own texture,
  // within a few deviations of its neighbourhood, stays. 0: off (the paper). OpenCV's median
  // is fast for 3 and 5 only.
  int transient_median = 0;  // odd, 3..31, or 0 (off)
  double transient_k = 7.0;  // threshold, robust deviations
  int transient_grow = 1;    // pixels
  int transient_fill = 11;   // odd, >= transient_median
  MarkPolarity transient_polarity = MarkPolarity::kBoth;
  // SIFT (cv::SIFT).
  int sift_octave_layers = 3;             // layers per octave
  double sift_contrast_threshold = 0.04;  // DoG contrast threshold
  double sift_edge_threshold = 10.0;      // edge response threshold
  double sift_sigma = 1.6;                // Gaussian of octave 0, pixels

  // Throws std::invalid_argument naming the first bad field.
  void Check() const;
};

// One keypoint. Angles are radians in [0, 2 pi), counter-clockwise in image coordinates as
// OpenCV measures them; `octave` is the pyramid level (ORB) or the SIFT octave (>= 0 after
// removing OpenCV's packing; -1 for SIFT's upsampled octave).
struct Keypoint {
  float x = 0;         // pixels
  float y = 0;         // pixels
  float angle = 0;     // radians
  float size = 0;      // diameter of the meaningful neighbourhood, pixels
  float response = 0;  // detector score
  int octave = 0;      // pyramid level
};

// Keypoints and their descriptors: row i of `descriptors` belongs to keypoints[i]
// (CV_8U, 32 bytes per row for ORB; CV_32F, 128 floats per row for SIFT).
struct ImageFeatures {
  std::vector<Keypoint> keypoints;
  cv::Mat descriptors;
  size_t size() const { return keypoints.size(); }
};

class FeatureExtractor {
 public:
  explicit FeatureExtractor(const FeatureOptions& options);
  ~FeatureExtractor();
  FeatureExtractor(const FeatureExtractor&) = delete;
  FeatureExtractor& operator=(const FeatureExtractor&) = delete;

  // Extracts features from an 8-bit grayscale image. Throws std::invalid_argument for an empty
  // or non-8-bit-gray image. A featureless image gives an empty result, not an error.
  ImageFeatures Extract(const cv::Mat& gray) const;

  const FeatureOptions& options() const { return options_; }
  // The image the detector and descriptor see (after transient removal and contrast
  // adaptation).
  cv::Mat Preprocess(const cv::Mat& gray) const;
  // The image with its transient marks filled by the mean of the unmarked pixels around them
  // (transient_median; the image itself when off or when it has none).
  cv::Mat RemoveTransients(const cv::Mat& gray) const;

 private:
  cv::Mat AdaptContrast(const cv::Mat& gray) const;
  FeatureOptions options_;
  cv::Ptr<cv::Feature2D> detector_;
  // ORB adaptation: detectors at the FAST thresholds tried in turn (first: orb_fast_threshold),
  // each asking for the number of candidates the grid needs.
  std::vector<cv::Ptr<cv::Feature2D>> detectors_;
  std::vector<int> detector_thresholds_;  // their FAST thresholds
  int detector_candidates_ = 0;           // and the candidates each asks for
  bool adaptive_ = false;
  bool ladder_ = false;  // detectors_ replaced by DetectOrbKeypoints (orb_threshold_ladder)
};

// True when the options make the paper's plain ORB or SIFT (no adaptation to the floor).
bool IsPlainExtractor(const FeatureOptions& options);

// The options an image that is only queried is extracted with: num_features becomes
// query_num_features when that is set.
FeatureOptions QueryFeatureOptions(const FeatureOptions& options);

}  // namespace gtbow
