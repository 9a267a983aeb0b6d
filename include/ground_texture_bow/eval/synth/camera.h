// An orthographic, downward-facing camera at constant height over a procedural Floor, with the
// imperfections of a real one: sensor noise, slight defocus, vignetting, exposure changes, and
// small height and tilt jitter that changes the scale by up to about +-2%, motion blur along
// the driving direction, and a light mounted on the camera that shades the floor's relief.
#pragma once

#include <cstdint>

#include <opencv2/core.hpp>

#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/eval/synth/floor.h"

namespace gtbow {
namespace synth {

struct CameraOptions {
  int width = 640;                    // image width, pixels
  int height = 480;                   // image height, pixels
  double meters_per_pixel = 0.00025;  // ground sampling distance, metres per pixel
  int supersample = 2;                // anti-aliasing: samples per pixel along each axis (1-4)
  bool sensor_effects = true;         // false renders the ideal image (no noise, blur, jitter)
  double noise_sigma = 0.01;          // read noise, fraction of full scale
  double shot_noise = 0.0004;         // photon noise variance per unit brightness
  double defocus_sigma = 0.55;        // mean Gaussian defocus, pixels
  double vignetting = 0.18;           // brightness lost at the image corners, fraction
  double exposure_jitter = 0.06;      // standard deviation of the per-image gain
  double scale_jitter = 0.007;        // standard deviation of the height-jitter scale change
  double tilt_jitter = 0.004;         // standard deviation of the tilt scale change at the edge
  double max_scale_change = 0.02;     // clamp on every scale change, fraction
  double motion_blur = 1.5;           // longest motion blur along the image u axis, pixels
  // The light mounted on the camera: it turns with the robot, so relief is shaded differently
  // when a place is seen at another heading (FloorState).
  double light_directional = 0.5;  // share of directional light, rest ambient [0, 1]
  double light_azimuth = 0.0;      // where the light comes from, radians from image +u
  double light_elevation = 0.7;    // radians above the floor (0, pi/2]

  // Throws std::invalid_argument naming the first bad field.
  void Check() const;
  ImageGeometry Geometry() const { return {width, height, meters_per_pixel}; }
};

// Illumination of one visit (a recording session).
struct Lighting {
  double gain = 1.0;               // overall brightness factor
  double gradient_u = 0.0;         // brightness change across the image width, fraction
  double gradient_v = 0.0;         // brightness change across the image height, fraction
  double gamma = 1.0;              // tone curve of this session's exposure settings (> 0)
  double directional_scale = 1.0;  // directional light relative to CameraOptions (ambient
                                   // light leaking in changes the mix), >= 0
  double azimuth_offset = 0.0;     // light azimuth relative to CameraOptions, radians
};

class Camera {
 public:
  explicit Camera(const CameraOptions& options);

  // Renders the 8-bit grayscale image of `floor` seen with pose `floor_from_image`.
  // `shot_seed` drives this image's sensor randomness (noise, jitter, exposure).
  cv::Mat Capture(const Floor& floor, const Pose2D& floor_from_image, const FloorState& state,
                  const Lighting& lighting, uint64_t shot_seed) const;

  // The homography from image pixels (u, v) to floor metres for a pose, with a scale factor
  // `scale` and perspective tilt terms (per centred pixel) applied. With scale 1 and no tilt it
  // is exactly FloorFromImage of geometry.h.
  Homography FloorFromImagePixel(const Pose2D& pose, double scale, double tilt_u,
                                 double tilt_v) const;

  const CameraOptions& options() const { return options_; }

 private:
  CameraOptions options_;
};

}  // namespace synth
}  // namespace gtbow
