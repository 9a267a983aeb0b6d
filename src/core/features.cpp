#include "ground_texture_bow/core/features.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <stdexcept>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "ground_texture_bow/core/enum_names.h"
#include "orb_detect.h"

namespace gtbow {

namespace {
constexpr EnumName<FeatureType> kFeatureTypes[] = {{"orb", FeatureType::kOrb},
                                                   {"sift", FeatureType::kSift}};
constexpr EnumName<Contrast> kContrasts[] = {
    {"none", Contrast::kNone}, {"normalize", Contrast::kNormalize}, {"clahe", Contrast::kClahe}};
constexpr EnumName<MarkPolarity> kPolarities[] = {{"both", MarkPolarity::kBoth},
                                                  {"bright", MarkPolarity::kBright},
                                                  {"dark", MarkPolarity::kDark}};
// The bin holding the median of a histogram's `total` samples (the robust deviations below).
int MedianBin(const uint32_t* hist, int bins, size_t total) {
  const size_t half = total / 2;
  size_t acc = 0;
  int bin = 0;
  while (bin < bins - 1 && (acc += hist[bin]) <= half) ++bin;
  return bin;
}
}  // namespace

MarkPolarity ParseMarkPolarity(const std::string& name) {
  return ParseEnumName(name, "transient polarity", kPolarities);
}
std::string MarkPolarityName(MarkPolarity p) { return EnumValueName(p, kPolarities); }

FeatureType ParseFeatureType(const std::string& name) {
  return ParseEnumName(name, "feature type", kFeatureTypes);
}
std::string FeatureTypeName(FeatureType type) { return EnumValueName(type, kFeatureTypes); }
Contrast ParseContrast(const std::string& name) {
  return ParseEnumName(name, "contrast", kContrasts);
}
std::string ContrastName(Contrast c) { return EnumValueName(c, kContrasts); }

bool IsPlainExtractor(const FeatureOptions& o) {
  return o.contrast == Contrast::kNone && o.orb_min_fast_threshold == 0 && o.grid_cols == 0 &&
         o.grid_rows == 0 && o.transient_median == 0;
}

FeatureOptions QueryFeatureOptions(const FeatureOptions& options) {
  FeatureOptions q = options;
  if (q.query_num_features > 0) q.num_features = q.query_num_features;
  q.query_num_features = 0;
  q.query_escalate = false;
  q.query_escalate_backoff = 0;
  return q;
}

void FeatureOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("features: ") + what);
  };
  need(num_features > 0, "num_features must be positive");
  need(query_num_features >= 0, "query_num_features must be >= 0 (0: num_features)");
  need(!query_escalate || query_num_features > num_features,
       "query_escalate needs query_num_features above num_features");
  need(query_escalate_backoff >= 0, "query_escalate_backoff must be >= 0 (0: off)");
  need(orb_scale_factor > 1.0f, "orb_scale_factor must be > 1");
  need(orb_num_levels >= 1 && orb_num_levels <= 32, "orb_num_levels must be in 1..32");
  need(orb_edge_threshold >= 0, "orb_edge_threshold must be >= 0");
  need(orb_first_level >= 0, "orb_first_level must be >= 0");
  need(orb_wta_k >= 2 && orb_wta_k <= 4, "orb_wta_k must be 2, 3 or 4");
  need(orb_patch_size >= 2, "orb_patch_size must be >= 2");
  need(orb_fast_threshold >= 0, "orb_fast_threshold must be >= 0");
  need(contrast_target > 0 && std::isfinite(contrast_target), "contrast_target must be positive");
  need(contrast_max_gain >= 1 && std::isfinite(contrast_max_gain),
       "contrast_max_gain must be >= 1");
  need(clahe_clip > 0 && std::isfinite(clahe_clip), "clahe_clip must be positive");
  need(clahe_tiles >= 1 && clahe_tiles <= 64, "clahe_tiles must be in 1..64");
  need(orb_min_fast_threshold >= 0 && orb_min_fast_threshold <= orb_fast_threshold,
       "orb_min_fast_threshold must be in 0..orb_fast_threshold");
  need((grid_cols == 0) == (grid_rows == 0),
       "grid_cols and grid_rows must both be 0 (off) or both positive");
  need(grid_cols >= 0 && grid_cols <= 64 && grid_rows >= 0 && grid_rows <= 64,
       "grid_cols and grid_rows must be in 0..64");
  need(grid_oversample >= 1 && grid_oversample <= 16, "grid_oversample must be in [1, 16]");
  need(transient_median == 0 ||
           (transient_median >= 3 && transient_median <= 31 && transient_median % 2 == 1),
       "transient_median must be 0 (off) or odd in 3..31");
  need(transient_k > 0 && std::isfinite(transient_k), "transient_k must be positive");
  need(transient_grow >= 0 && transient_grow <= 16, "transient_grow must be in 0..16");
  need(transient_median == 0 ||
           (transient_fill >= transient_median && transient_fill <= 63 && transient_fill % 2 == 1),
       "transient_fill must be odd, at least transient_median and at most 63");
  need(type == FeatureType::kOrb || IsPlainExtractor(*this),
       "contrast, orb_min_fast_threshold, the grid and transient_median are implemented for ORB "
       "only");
  need(sift_octave_layers >= 1, "sift_octave_layers must be >= 1");
  need(sift_contrast_threshold >= 0, "sift_contrast_threshold must be >= 0");
  need(sift_edge_threshold > 0, "sift_edge_threshold must be > 0");
  need(sift_sigma > 0, "sift_sigma must be > 0");
}

FeatureExtractor::FeatureExtractor(const FeatureOptions& options) : options_(options) {
  options_.Check();
  if (options_.type == FeatureType::kOrb) {
    auto orb = [&](int n, int threshold) -> cv::Ptr<cv::Feature2D> {
      return cv::ORB::create(n, options_.orb_scale_factor, options_.orb_num_levels,
                             options_.orb_edge_threshold, options_.orb_first_level,
                             options_.orb_wta_k,
                             options_.orb_fast_score ? cv::ORB::FAST_SCORE : cv::ORB::HARRIS_SCORE,
                             options_.orb_patch_size, threshold);
    };
    detector_ = orb(options_.num_features, options_.orb_fast_threshold);
    adaptive_ = options_.orb_min_fast_threshold > 0 || options_.grid_cols > 0;
    if (adaptive_) {
      const int candidates =
          options_.grid_cols > 0
              ? static_cast<int>(std::ceil(options_.num_features * options_.grid_oversample))
              : options_.num_features;
      int t = options_.orb_fast_threshold;
      detectors_.push_back(orb(candidates, t));
      detector_thresholds_.push_back(t);
      while (options_.orb_min_fast_threshold > 0 && t > options_.orb_min_fast_threshold) {
        t = std::max(options_.orb_min_fast_threshold, t / 2);
        detectors_.push_back(orb(candidates, t));
        detector_thresholds_.push_back(t);
      }
      detector_candidates_ = candidates;
      ladder_ = options_.orb_threshold_ladder &&
                OrbLadderApplies(options_.orb_first_level, options_.orb_edge_threshold,
                                 options_.orb_patch_size);
    }
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
  const cv::Mat image = Preprocess(gray);
  // Grid cell of a point (row-major).
  const auto CellOf = [this](const cv::Point2f& p, const cv::Size& size) {
    const int cols = options_.grid_cols, rows = options_.grid_rows;
    const int cx = std::clamp(static_cast<int>(p.x * cols / size.width), 0, cols - 1);
    const int cy = std::clamp(static_cast<int>(p.y * rows / size.height), 0, rows - 1);
    return static_cast<size_t>(cy) * cols + cx;
  };
  if (!adaptive_) {
    detector_->detectAndCompute(image, cv::noArray(), kps, desc);
  } else {
    // Detection at falling thresholds until the image yields num_features candidates; the
    // descriptors of the chosen ones only, below (describing every candidate, twice as many,
    // cost about half as much again as the detection).
    for (size_t i = 0; i < detectors_.size(); ++i) {
      kps.clear();
      if (ladder_) {
        OrbDetectOptions o;
        o.num_features = detector_candidates_;
        o.scale_factor = options_.orb_scale_factor;
        o.num_levels = options_.orb_num_levels;
        o.edge_threshold = options_.orb_edge_threshold;
        o.patch_size = options_.orb_patch_size;
        o.fast_score = options_.orb_fast_score;
        o.fast_threshold = detector_thresholds_[i];
        o.rungs = DefaultOrbRungs(o.fast_threshold);
        kps = DetectOrbKeypoints(image, o);
      } else {
        detectors_[i]->detect(image, kps);
      }
      if (kps.size() >= static_cast<size_t>(options_.num_features)) break;
    }
    if (options_.grid_cols > 0 && options_.grid_refill) {
      // Cells with under half their share of candidates (a faint part of an otherwise rough
      // floor: the global ranking left it none) are searched again on their own, at the lowest
      // threshold.
      const int cols = options_.grid_cols, rows = options_.grid_rows;
      const size_t quota = (options_.num_features + cols * rows - 1) / (cols * rows);
      std::vector<size_t> count(static_cast<size_t>(cols) * rows, 0);
      for (const auto& k : kps) ++count[CellOf(k.pt, image.size())];
      cv::Mat mask(image.size(), CV_8U, cv::Scalar(0));
      bool short_cells = false;
      for (int cy = 0; cy < rows; ++cy) {
        for (int cx = 0; cx < cols; ++cx) {
          if (2 * count[static_cast<size_t>(cy) * cols + cx] >= quota)
            continue;  // under half its share
          short_cells = true;
          const int x0 = cx * image.cols / cols, x1 = (cx + 1) * image.cols / cols;
          const int y0 = cy * image.rows / rows, y1 = (cy + 1) * image.rows / rows;
          mask(cv::Rect(x0, y0, x1 - x0, y1 - y0)).setTo(255);
        }
      }
      if (short_cells) {
        std::vector<cv::KeyPoint> more;
        detectors_.back()->detect(image, more, mask);
        for (size_t i = 0; i < more.size(); ++i) {
          if (2 * count[CellOf(more[i].pt, image.size())] >= quota) continue;
          bool dup = false;
          for (const auto& k : kps) dup = dup || (k.pt == more[i].pt && k.octave == more[i].octave);
          if (dup) continue;
          kps.push_back(more[i]);
        }
      }
    }
    const size_t want = static_cast<size_t>(options_.num_features);
    std::vector<size_t> order(kps.size());
    std::iota(order.begin(), order.end(), 0);
    // Strongest first; ties by level and position, so that the order does not depend on the
    // order the detector listed them in (cv::ORB and the threshold ladder list a level's
    // keypoints in different orders).
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) {
      const cv::KeyPoint &p = kps[a], &q = kps[b];
      if (p.response != q.response) return p.response > q.response;
      if (p.octave != q.octave) return p.octave < q.octave;
      if (p.pt.y != q.pt.y) return p.pt.y < q.pt.y;
      return p.pt.x < q.pt.x;
    });
    std::vector<size_t> chosen;
    if (options_.grid_cols > 0 && kps.size() > want) {
      // Best-first, at most a cell's share per cell, then the rest best-first.
      const int cols = options_.grid_cols, rows = options_.grid_rows;
      const size_t quota = (want + cols * rows - 1) / (cols * rows);
      std::vector<size_t> per_cell(static_cast<size_t>(cols) * rows, 0);
      std::vector<uint8_t> taken(kps.size(), 0);
      for (size_t i : order) {
        size_t& n = per_cell[CellOf(kps[i].pt, image.size())];
        if (n < quota && chosen.size() < want) {
          ++n;
          taken[i] = 1;
          chosen.push_back(i);
        }
      }
      for (size_t i : order) {
        if (chosen.size() >= want) break;
        if (!taken[i]) chosen.push_back(i);
      }
    } else {
      chosen.assign(order.begin(), order.begin() + std::min(want, order.size()));
    }
    std::vector<cv::KeyPoint> kept;
    kept.reserve(chosen.size());
    for (size_t i : chosen) kept.push_back(kps[i]);
    kps.swap(kept);
    // Descriptors of the chosen keypoints (their orientation and pyramid level are kept), in
    // the order chosen: ORB's compute groups them by pyramid level, so each carries its rank.
    if (!kps.empty()) {
      for (size_t i = 0; i < kps.size(); ++i) kps[i].class_id = static_cast<int>(i);
      cv::Mat by_level;
      detector_->compute(image, kps, by_level);
      std::vector<int> row(kps.size(), -1);
      for (size_t i = 0; i < kps.size(); ++i)
        row[static_cast<size_t>(kps[i].class_id)] = static_cast<int>(i);
      std::vector<cv::KeyPoint> ranked;
      ranked.reserve(kps.size());
      desc.create(static_cast<int>(kps.size()), by_level.cols, by_level.type());
      for (size_t r = 0; r < row.size(); ++r) {
        if (row[r] < 0) continue;  // dropped by compute (none are: they were detected there)
        by_level.row(row[r]).copyTo(desc.row(static_cast<int>(ranked.size())));
        ranked.push_back(kps[static_cast<size_t>(row[r])]);
        ranked.back().class_id = -1;
      }
      desc = desc.rowRange(0, static_cast<int>(ranked.size()));
      kps.swap(ranked);
    }
  }
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

cv::Mat FeatureExtractor::Preprocess(const cv::Mat& gray) const {
  return AdaptContrast(RemoveTransients(gray));
}

cv::Mat FeatureExtractor::AdaptContrast(const cv::Mat& gray) const {
  switch (options_.contrast) {
    case Contrast::kNone:
      return gray;
    case Contrast::kNormalize: {
      // The deviation of the fine detail, estimated robustly (1.4826 x the median absolute
      // high-pass value, from a histogram in 1/8 grey-level steps) so that a few scuffs, stains
      // or bits of debris on a faint floor do not lower its gain.
      cv::Mat f, blur;
      gray.convertTo(f, CV_32F);
      cv::GaussianBlur(f, blur, cv::Size(), 2.0);
      const cv::Mat hp = cv::abs(f - blur);
      constexpr int kBins = 1024;
      std::vector<uint32_t> hist(kBins, 0);
      for (int r = 0; r < hp.rows; ++r) {
        const float* p = hp.ptr<float>(r);
        for (int c = 0; c < hp.cols; ++c)
          ++hist[std::min(kBins - 1, static_cast<int>(p[c] * 8.0f))];
      }
      const int bin = MedianBin(hist.data(), kBins, hp.total());
      const double sd = 1.4826 * (bin + 0.5) / 8.0;
      const double gain = std::clamp(options_.contrast_target / std::max(sd, 1e-6), 1.0,
                                     options_.contrast_max_gain);
      if (gain <= 1.0) return gray;
      const double m = cv::mean(gray)[0];
      cv::Mat out;
      gray.convertTo(out, CV_8U, gain, 128.0 - gain * m);  // saturating
      return out;
    }
    case Contrast::kClahe: {
      cv::Mat out;
      cv::createCLAHE(options_.clahe_clip, cv::Size(options_.clahe_tiles, options_.clahe_tiles))
          ->apply(gray, out);
      return out;
    }
  }
  return gray;
}

cv::Mat FeatureExtractor::RemoveTransients(const cv::Mat& gray) const {
  if (options_.transient_median == 0) return gray;
  cv::Mat median, deviation;
  cv::medianBlur(gray, median, options_.transient_median);
  cv::absdiff(gray, median, deviation);
  // The robust deviation: the median of |image - median| from its histogram.
  std::array<uint32_t, 256> hist{};
  for (int r = 0; r < deviation.rows; ++r) {
    const uint8_t* p = deviation.ptr<uint8_t>(r);
    for (int c = 0; c < deviation.cols; ++c) ++hist[p[c]];
  }
  const int mad = MedianBin(hist.data(), 256, deviation.total());
  // +0.5: an image without fine detail (mad 0) does not flag its sensor noise.
  const double sigma = 1.4826 * mad + 0.5;
  const double threshold = std::floor(options_.transient_k * sigma);
  if (threshold >= 255) return gray;
  cv::Mat marks;
  if (options_.transient_polarity == MarkPolarity::kBright) {
    cv::subtract(gray, median, deviation);  // saturating: brighter than the median only
  } else if (options_.transient_polarity == MarkPolarity::kDark) {
    cv::subtract(median, gray, deviation);
  }
  cv::threshold(deviation, marks, threshold, 255, cv::THRESH_BINARY);  // deviation > threshold
  if (cv::countNonZero(marks) == 0) return gray;
  if (options_.transient_grow > 0) {
    const int side = 2 * options_.transient_grow + 1;
    cv::dilate(marks, marks, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(side, side)));
  }
  // The fill: the mean of the unmarked pixels of the transient_fill x transient_fill window;
  // where the whole window is marked, the median. Few marks (the usual case: well under 1% of
  // an aged image's pixels) sum their windows directly; many read integral images, which cost
  // two passes over the whole image. Both give the same values.
  const int reach = options_.transient_fill / 2;
  const int side = 2 * reach + 1;
  std::vector<cv::Point> marked;
  cv::findNonZero(marks, marked);
  cv::Mat out = gray.clone();
  const auto fill = [&](const cv::Point& p, int32_t n, int32_t total) {
    out.at<uint8_t>(p) = n > 0 ? static_cast<uint8_t>((total + n / 2) / n) : median.at<uint8_t>(p);
  };
  if (marked.size() * static_cast<size_t>(side) * side < 2 * gray.total()) {
    for (const cv::Point& p : marked) {
      const int r0 = std::max(0, p.y - reach), r1 = std::min(gray.rows, p.y + reach + 1);
      const int c0 = std::max(0, p.x - reach), c1 = std::min(gray.cols, p.x + reach + 1);
      int32_t n = 0, total = 0;
      for (int r = r0; r < r1; ++r) {
        const uint8_t* g = gray.ptr<uint8_t>(r);
        const uint8_t* m = marks.ptr<uint8_t>(r);
        for (int c = c0; c < c1; ++c) {
          const int32_t unmarked = m[c] == 0 ? 1 : 0;
          n += unmarked;
          total += unmarked * g[c];
        }
      }
      fill(p, n, total);
    }
    return out;
  }
  cv::Mat keep, kept, sum, count;
  cv::threshold(marks, keep, 0, 1, cv::THRESH_BINARY_INV);  // 1 where unmarked
  cv::multiply(gray, keep, kept);
  // Exact double sums: a bright image's 32-bit integral wraps above about 8.4 Mpx.
  cv::integral(kept, sum, CV_64F);
  cv::integral(keep, count, CV_32S);
  for (const cv::Point& p : marked) {
    const int r0 = std::max(0, p.y - reach), r1 = std::min(gray.rows, p.y + reach + 1);
    const int c0 = std::max(0, p.x - reach), c1 = std::min(gray.cols, p.x + reach + 1);
    const double* s0 = sum.ptr<double>(r0);
    const double* s1 = sum.ptr<double>(r1);
    const int32_t* n0 = count.ptr<int32_t>(r0);
    const int32_t* n1 = count.ptr<int32_t>(r1);
    fill(p, n1[c1] - n1[c0] - n0[c1] + n0[c0],
         static_cast<int32_t>(s1[c1] - s1[c0] - s0[c1] + s0[c0]));
  }
  return out;
}

}  // namespace gtbow
