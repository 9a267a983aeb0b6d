#include "ground_texture_bow/core/features.h"

#include <cmath>
#include <stdexcept>

#include <opencv2/features2d.hpp>

namespace gtbow {

FeatureType ParseFeatureType(const std::string& name) {
  if (name == "orb") return FeatureType::kOrb;
  if (name == "sift") return FeatureType::kSift;
  throw std::invalid_argument("unknown feature type '" + name + "' (valid: orb, sift)");
}

std::string FeatureTypeName(FeatureType type) { return type == FeatureType::kOrb ? "orb" : "sift"; }

void FeatureOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("features: ") + what);
  };
  need(num_features > 0, "num_features must be positive");
  need(orb_scale_factor > 1.0f, "orb_scale_factor must be > 1");
  need(orb_num_levels >= 1 && orb_num_levels <= 32, "orb_num_levels must be in 1..32");
  need(orb_edge_threshold >= 0, "orb_edge_threshold must be >= 0");
  need(orb_first_level >= 0, "orb_first_level must be >= 0");
  need(orb_wta_k >= 2 && orb_wta_k <= 4, "orb_wta_k must be 2, 3 or 4");
  need(orb_patch_size >= 2, "orb_patch_size must be >= 2");
  need(orb_fast_threshold >= 0, "orb_fast_threshold must be >= 0");
  need(sift_octave_layers >= 1, "sift_octave_layers must be >= 1");
  need(sift_contrast_threshold >= 0, "sift_contrast_threshold must be >= 0");
  need(sift_edge_threshold > 0, "sift_edge_threshold must be > 0");
  need(sift_sigma > 0, "sift_sigma must be > 0");
}

FeatureExtractor::FeatureExtractor(const FeatureOptions& options) : options_(options) {
  options_.Check();
  if (options_.type == FeatureType::kOrb) {
    detector_ = cv::ORB::create(options_.num_features, options_.orb_scale_factor,
                                options_.orb_num_levels, options_.orb_edge_threshold,
                                options_.orb_first_level, options_.orb_wta_k,
                                options_.orb_fast_score ? cv::ORB::FAST_SCORE : cv::ORB::HARRIS_SCORE,
                                options_.orb_patch_size, options_.orb_fast_threshold);
  } else {
    detector_ = cv::SIFT::create(options_.num_features, options_.sift_octave_layers,
                                 options_.sift_contrast_threshold, options_.sift_edge_threshold,
                                 options_.sift_sigma);
  }
}

FeatureExtractor::~FeatureExtractor() = default;

ImageFeatures FeatureExtractor::Extract(const cv::Mat& gray) const {
  if (gray.empty()) throw std::invalid_argument("FeatureExtractor: empty image");
  if (gray.type() != CV_8UC1) {
    throw std::invalid_argument("FeatureExtractor: expected an 8-bit single-channel image");
  }
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  detector_->detectAndCompute(gray, cv::noArray(), kps, desc);
  ImageFeatures out;
  out.keypoints.reserve(kps.size());
  // SIFT may return more than num_features on ties; keep the strongest.
  const size_t keep = std::min(kps.size(), static_cast<size_t>(options_.num_features));
  for (size_t i = 0; i < keep; ++i) {
    const cv::KeyPoint& k = kps[i];
    Keypoint p;
    p.x = k.pt.x;
    p.y = k.pt.y;
    float a = k.angle < 0 ? 0.0f : static_cast<float>(k.angle * M_PI / 180.0);
    if (a >= static_cast<float>(2 * M_PI)) a -= static_cast<float>(2 * M_PI);
    p.angle = a;
    p.size = k.size;
    p.response = k.response;
    if (options_.type == FeatureType::kSift) {
      int octave = k.octave & 255;  // OpenCV packs octave, layer and scale
      p.octave = octave >= 128 ? octave - 256 : octave;
    } else {
      p.octave = k.octave;
    }
    out.keypoints.push_back(p);
  }
  out.descriptors = keep == kps.size() ? desc : desc.rowRange(0, static_cast<int>(keep)).clone();
  return out;
}

}  // namespace gtbow
