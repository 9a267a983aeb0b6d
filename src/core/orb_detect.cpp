#include "orb_detect.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

namespace gtbow {

namespace {

// OpenCV's share of num_features per level: geometric in 1 / scale_factor, the last level
// taking what remains.
std::vector<int> FeaturesPerLevel(const OrbDetectOptions& o) {
  std::vector<int> per(static_cast<size_t>(o.num_levels));
  const float factor = static_cast<float>(1.0 / static_cast<double>(o.scale_factor));
  float desired = o.num_features * (1 - factor) /
                  (1 - static_cast<float>(std::pow(static_cast<double>(factor), o.num_levels)));
  int sum = 0;
  for (int l = 0; l + 1 < o.num_levels; ++l) {
    per[l] = cvRound(desired);
    sum += per[l];
    desired *= factor;
  }
  per.back() = std::max(o.num_features - sum, 0);
  return per;
}

// Harris response of a 7 x 7 block of Sobel-like derivatives, in OpenCV's arithmetic (integer
// sums; the float expression evaluated in its order) so that the responses are equal bit for
// bit.
float HarrisResponse(const cv::Mat& level, int x, int y) {
  constexpr int kBlock = 7, kHalf = kBlock / 2;
  const int step = static_cast<int>(level.step);
  int a = 0, b = 0, c = 0;
  for (int i = 0; i < kBlock; ++i) {
    const uchar* row = level.ptr<uchar>(y - kHalf + i) + (x - kHalf);
    for (int j = 0; j < kBlock; ++j) {
      const uchar* p = row + j;
      const int dx =
          (p[1] - p[-1]) * 2 + (p[-step + 1] - p[-step - 1]) + (p[step + 1] - p[step - 1]);
      const int dy =
          (p[step] - p[-step]) * 2 + (p[step - 1] - p[-step - 1]) + (p[step + 1] - p[-step + 1]);
      a += dx * dx;
      b += dy * dy;
      c += dx * dy;
    }
  }
  const float scale = 1.f / ((1 << 2) * kBlock * 255.f);
  const float scale4 = scale * scale * scale * scale;
  const float sum = static_cast<float>(a) + b;
  return (static_cast<float>(a) * b - static_cast<float>(c) * c - 0.04f * sum * sum) * scale4;
}

// The half-widths of each row of the circular patch (symmetric in x and y), as ORB's
// orientation uses them.
std::vector<int> CircleRows(int half) {
  std::vector<int> umax(static_cast<size_t>(half) + 2);
  const int vmax = cvFloor(half * std::sqrt(2.f) / 2 + 1);
  const int vmin = cvCeil(half * std::sqrt(2.f) / 2);
  for (int v = 0; v <= vmax; ++v) {
    umax[v] = cvRound(std::sqrt(static_cast<double>(half) * half - static_cast<double>(v) * v));
  }
  for (int v = half, v0 = 0; v >= vmin; --v) {
    while (umax[v0] == umax[v0 + 1]) ++v0;
    umax[v] = v0;
    ++v0;
  }
  return umax;
}

// The angle (degrees) of the intensity centroid of the circular patch around (x, y).
float CentroidAngle(const cv::Mat& level, int x, int y, int half, const std::vector<int>& umax) {
  const int step = static_cast<int>(level.step);
  const uchar* centre = level.ptr<uchar>(y) + x;
  int m01 = 0, m10 = 0;
  for (int u = -half; u <= half; ++u) m10 += u * centre[u];
  for (int v = 1; v <= half; ++v) {
    int column_sum = 0;
    const int d = umax[v];
    for (int u = -d; u <= d; ++u) {
      const int below = centre[u + v * step], above = centre[u - v * step];
      column_sum += below - above;
      m10 += u * (below + above);
    }
    m01 += v * column_sum;
  }
  return cv::fastAtan2(static_cast<float>(m01), static_cast<float>(m10));
}

}  // namespace

bool OrbLadderApplies(int first_level, int edge_threshold, int patch_size) {
  return first_level == 0 && edge_threshold >= patch_size / 2 && edge_threshold >= 4;
}

std::vector<int> DefaultOrbRungs(int fast_threshold) {
  std::vector<int> rungs;
  for (int t : {3 * fast_threshold, 3 * fast_threshold / 2}) {
    if (t > fast_threshold && t <= 255) rungs.push_back(t);
  }
  return rungs;
}

std::vector<cv::KeyPoint> DetectOrbKeypoints(const cv::Mat& image, const OrbDetectOptions& o,
                                             OrbDetectStats* stats) {
  if (image.empty() || image.type() != CV_8UC1) {
    throw std::invalid_argument("DetectOrbKeypoints: expected an 8-bit single-channel image");
  }
  if (!OrbLadderApplies(0, o.edge_threshold, o.patch_size) || o.num_levels < 1 ||
      o.scale_factor <= 1.0f) {
    throw std::invalid_argument(
        "DetectOrbKeypoints: needs edge_threshold >= max(patch_size / 2, 4), num_levels >= 1 and "
        "scale_factor > 1");
  }
  const std::vector<int> per = FeaturesPerLevel(o);
  const int levels = o.num_levels;
  // The pyramid as ORB builds it: each level resized from the one before (bit-exact linear).
  std::vector<cv::Mat> pyramid(static_cast<size_t>(levels));
  std::vector<float> scales(static_cast<size_t>(levels), 1.0f);
  pyramid[0] = image;
  for (int l = 1; l < levels; ++l) {
    scales[l] = static_cast<float>(std::pow(static_cast<double>(o.scale_factor), l));
    const cv::Size size(cvRound(image.cols / scales[l]), cvRound(image.rows / scales[l]));
    cv::resize(pyramid[l - 1], pyramid[l], size, 0, 0, cv::INTER_LINEAR_EXACT);
  }
  const int half = o.patch_size / 2;
  const std::vector<int> umax = CircleRows(half);
  std::vector<cv::KeyPoint> out, level_points;
  for (int l = 0; l < levels; ++l) {
    const cv::Mat& level = pyramid[l];
    const size_t wanted = static_cast<size_t>(o.fast_score ? per[l] : 2 * per[l]);
    const auto detect = [&](int threshold) {
      level_points.clear();
      cv::FAST(level, level_points, threshold, true);
      cv::KeyPointsFilter::runByImageBorder(level_points, level.size(), o.edge_threshold);
    };
    bool on_rung = false;
    for (int t : o.rungs) {
      if (t <= o.fast_threshold) continue;
      detect(t);
      if (level_points.size() >= wanted) {
        on_rung = true;
        break;
      }
    }
    if (!on_rung) detect(o.fast_threshold);
    if (stats != nullptr) {
      ++stats->levels;
      stats->levels_on_rungs += on_rung ? 1 : 0;
    }
    cv::KeyPointsFilter::retainBest(level_points, static_cast<int>(wanted));
    if (!o.fast_score) {
      for (auto& k : level_points) {
        k.response = HarrisResponse(level, cvRound(k.pt.x), cvRound(k.pt.y));
      }
      cv::KeyPointsFilter::retainBest(level_points, per[l]);
    }
    for (auto& k : level_points) {
      k.octave = l;
      k.size = o.patch_size * scales[l];
      k.angle = CentroidAngle(level, cvRound(k.pt.x), cvRound(k.pt.y), half, umax);
      k.pt *= scales[l];
      out.push_back(k);
    }
  }
  return out;
}

}  // namespace gtbow
