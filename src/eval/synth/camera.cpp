#include "ground_texture_bow/eval/synth/camera.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

#include "noise.h"

namespace gtbow {
namespace synth {

void CameraOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("camera: ") + what);
  };
  need(width > 0, "width must be positive");
  need(height > 0, "height must be positive");
  need(meters_per_pixel > 0 && std::isfinite(meters_per_pixel),
       "meters_per_pixel must be positive");
  need(supersample >= 1 && supersample <= 4, "supersample must be in 1..4");
  need(noise_sigma >= 0, "noise_sigma must be >= 0");
  need(shot_noise >= 0, "shot_noise must be >= 0");
  need(defocus_sigma >= 0, "defocus_sigma must be >= 0");
  need(vignetting >= 0 && vignetting < 1, "vignetting must be in [0, 1)");
  need(exposure_jitter >= 0, "exposure_jitter must be >= 0");
  need(scale_jitter >= 0, "scale_jitter must be >= 0");
  need(tilt_jitter >= 0, "tilt_jitter must be >= 0");
  need(max_scale_change >= 0 && max_scale_change < 0.5, "max_scale_change must be in [0, 0.5)");
  need(motion_blur >= 0 && motion_blur <= 50, "motion_blur must be in [0, 50] pixels");
  need(light_directional >= 0 && light_directional <= 1, "light_directional must be in [0, 1]");
  need(std::isfinite(light_azimuth), "light_azimuth must be finite");
  need(light_elevation > 0 && light_elevation <= M_PI / 2,
       "light_elevation must be in (0, pi/2] radians");
}

Camera::Camera(const CameraOptions& options) : options_(options) { options_.Check(); }

Homography Camera::FloorFromImagePixel(const Pose2D& p, double scale, double tilt_u,
                                       double tilt_v) const {
  const double cu = 0.5 * (options_.width - 1);
  const double cv = 0.5 * (options_.height - 1);
  const double k = options_.meters_per_pixel * scale;
  const double c = std::cos(p.theta), sn = std::sin(p.theta);
  // With centred pixels d = (u - cu, v - cv) and w = 1 + tilt . d:
  // floor = ([x, y] * w + k R(theta) d) / w.
  const double hc[9] = {k * c + p.x * tilt_u,
                        -k * sn + p.x * tilt_v,
                        p.x,
                        k * sn + p.y * tilt_u,
                        k * c + p.y * tilt_v,
                        p.y,
                        tilt_u,
                        tilt_v,
                        1.0};
  const double centre[9] = {1, 0, -cu, 0, 1, -cv, 0, 0, 1};
  Homography h{};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double v = 0;
      for (int q = 0; q < 3; ++q) v += hc[3 * i + q] * centre[3 * q + j];
      h[3 * i + j] = v;
    }
  }
  return h;
}

cv::Mat Camera::Capture(const Floor& floor, const Pose2D& pose, const FloorState& state,
                        const Lighting& lighting, uint64_t shot_seed) const {
  const CameraOptions& o = options_;
  CellRng rng(Mix64(shot_seed ^ 0xca3e7a));
  double scale = 1.0, tilt_u = 0.0, tilt_v = 0.0;
  if (o.sensor_effects) {
    const double lim = o.max_scale_change;
    scale = 1.0 + std::clamp(o.scale_jitter * rng.Normal(), -lim, lim);
    const double half = 0.5 * std::max(o.width, o.height);
    tilt_u = std::clamp(o.tilt_jitter * rng.Normal(), -lim, lim) / half;
    tilt_v = std::clamp(o.tilt_jitter * rng.Normal(), -lim, lim) / half;
  }
  if (!(lighting.gamma > 0) || !(lighting.directional_scale >= 0) ||
      !std::isfinite(lighting.azimuth_offset)) {
    throw std::invalid_argument(
        "Camera::Capture: lighting gamma must be > 0, directional_scale "
        ">= 0 and azimuth_offset finite");
  }
  FloorState lit = state;
  lit.directional = std::clamp(o.light_directional * lighting.directional_scale, 0.0, 1.0);
  lit.light_azimuth = o.light_azimuth + lighting.azimuth_offset;
  lit.light_elevation = o.light_elevation;
  cv::Mat img;
  floor.Render(FloorFromImagePixel(pose, scale, tilt_u, tilt_v), o.width, o.height, o.supersample,
               lit, &img);
  if (!o.sensor_effects) {
    cv::Mat out;
    img.convertTo(out, CV_8U, 255.0);
    return out;
  }
  const double blur = o.defocus_sigma * rng.Uniform(0.7, 1.3);
  if (blur > 0.05) cv::GaussianBlur(img, img, cv::Size(0, 0), blur, blur, cv::BORDER_REFLECT);
  // Motion blur: a box of random length (up to motion_blur pixels) along the driving direction.
  const double streak = o.motion_blur * rng.Uniform();
  if (streak > 0.1) {
    const int taps = 2 * static_cast<int>(std::ceil(0.5 * streak)) + 1;
    cv::Mat kernel(1, taps, CV_32F);
    const double half = 0.5 * streak, c = 0.5 * (taps - 1);
    for (int k = 0; k < taps; ++k) {  // the box's coverage of tap k's pixel
      const double lo = std::max(k - c - 0.5, -half), hi = std::min(k - c + 0.5, half);
      kernel.at<float>(0, k) = static_cast<float>(std::max(0.0, hi - lo) / streak);
    }
    cv::filter2D(img, img, -1, kernel, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  }
  const double gain = lighting.gain * (1.0 + o.exposure_jitter * rng.Normal());
  const double cu = 0.5 * (o.width - 1), cv_ = 0.5 * (o.height - 1);
  const double r2max = cu * cu + cv_ * cv_;
  cv::Mat noise(img.size(), CV_32F);
  cv::RNG cvrng(rng.Next());
  cvrng.fill(noise, cv::RNG::NORMAL, 0.0, 1.0);
  cv::Mat out(img.size(), CV_8U);
  const float var_read = static_cast<float>(o.noise_sigma * o.noise_sigma);
  const float shot = static_cast<float>(o.shot_noise);
  const float vig = static_cast<float>(o.vignetting / r2max);
  const float gu = static_cast<float>(lighting.gradient_u / o.width);
  const float gv = static_cast<float>(lighting.gradient_v / o.height);
  const float g = static_cast<float>(lighting.gamma);
  const bool gamma_one = lighting.gamma == 1.0;
  for (int v = 0; v < img.rows; ++v) {
    const float* in = img.ptr<float>(v);
    const float* n = noise.ptr<float>(v);
    uint8_t* dst = out.ptr<uint8_t>(v);
    const float dv = static_cast<float>(v - cv_);
    const float row_gain = static_cast<float>(gain) * (1.0f + gv * dv);
    for (int u = 0; u < img.cols; ++u) {
      const float du = static_cast<float>(u - cu);
      const float illum = row_gain * (1.0f - vig * (du * du + dv * dv)) +
                          row_gain * gu * du * (1.0f - vig * (du * du + dv * dv));
      const float val = (gamma_one ? in[u] : std::pow(std::max(in[u], 0.0f), g)) * illum;
      const float sd = std::sqrt(var_read + shot * std::max(0.0f, val));
      const float q = (val + sd * n[u]) * 255.0f + 0.5f;
      dst[u] = static_cast<uint8_t>(std::min(255.0f, std::max(0.0f, q)));
    }
  }
  return out;
}

}  // namespace synth
}  // namespace gtbow
