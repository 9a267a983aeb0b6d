// A procedural, unbounded ground-texture floor. Each surface is a deterministic function of a
// seed: any region renders on demand and nothing is stored. Structure exists at several scales
// (e.g. asphalt: aggregate stones of many sizes in a darker binder, plus fine speckle), and
// ageing (dirt, stains, scuffs, tyre marks, debris) accumulates progressively with the day.
// Surfaces with relief (asphalt, concrete) can be shaded by a light fixed to the camera.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace gtbow {
namespace synth {

// Low-contrast floors: kSmoothConcrete (power-trowelled or polished: faint cement-paste mottling,
// fine sand, rare pinholes, trowel swirls) and kEpoxy (a painted or epoxy coating: orange peel,
// roller marks, dust specks, hairline scratches). kPhoto: the floor is made of photographs
// (PhotoRegion), not procedural.
enum class Surface {
  kAsphalt,
  kConcrete,
  kCarpet,
  kLaminate,
  kFlat,
  kSmoothConcrete,
  kEpoxy,
  kPhoto
};

// Parses "asphalt", "concrete", "carpet", "laminate", "smooth_concrete", "epoxy" or "flat";
// throws std::invalid_argument listing the valid names otherwise. ("photo" is not parsed: a
// photo floor needs photographs.)
Surface ParseSurface(const std::string& name);
std::string SurfaceName(Surface surface);
// The names ParseSurface accepts, for help texts.
std::vector<std::string> SurfaceNames();

// A 3x3 row-major homography mapping image pixel centres (u, v, 1) to floor metres.
using Homography = std::array<double, 9>;

// A calibration disk drawn on top of the floor: white inside `radius`, with a black ring out
// to 2 * radius. Metres, floor frame.
struct FloorMarker {
  double x = 0.0;
  double y = 0.0;
  double radius = 0.001;
};

// How the floor looks at one visit.
struct FloorState {
  double day = 0.0;         // age of the floor since mapping, days (>= 0)
  uint64_t visit_seed = 0;  // randomness of this visit: transient debris
  double aging = 1.0;       // multiplier on the rate of ageing (0 disables wear)
  std::vector<FloorMarker> markers;
  // Relief shading. The floor has a height field (stones stand proud of the binder, pores and
  // pits sink into it, debris lies on top). A directional light shades it Lambertian-style:
  // slopes facing the light brighten, slopes facing away darken. The light is given in the
  // IMAGE frame (a light mounted on the camera turns with the robot), so the same stone looks
  // different when seen at another heading. `directional` is the share of directional light
  // (the rest is ambient); 0 renders plain reflectance.
  double directional = 0.0;      // [0, 1]
  double light_azimuth = 0.0;    // direction the light comes from, radians from image +u
  double light_elevation = 0.7;  // radians above the floor, (0, pi/2]
};

// A bounded region of a photo floor: a top-down photograph of a real floor laid on the floor
// frame with its image axes along the floor axes (a camera at theta = 0 sees it upright).
// Photo pixel (pu, pv) covers floor [x0 + pu s, x0 + (pu + 1) s] x [y0 + pv s, y0 + (pv + 1) s]
// with s = meters_per_pixel.
struct PhotoRegion {
  std::filesystem::path path;   // where it was read from
  std::string label;            // a short name (the file's stem), used in split names
  double meters_per_pixel = 0;  // ground size of a photo pixel, metres
  double x0 = 0, y0 = 0;        // floor position of the photo's top-left corner, metres
  cv::Mat reflectance;          // CV_32F grey values in [0, 1]
  double width() const { return reflectance.cols * meters_per_pixel; }   // metres
  double height() const { return reflectance.rows * meters_per_pixel; }  // metres
};

// Reads a photograph (PNG, JPEG, TIFF, BMP, ...: what OpenCV decodes; 8- or 16-bit, grey or
// colour, converted to grey) as a region at the origin. Throws std::invalid_argument naming the
// file when it is missing, not an image, or of a format that cannot be decoded.
PhotoRegion LoadPhotoRegion(const std::filesystem::path& path, double meters_per_pixel);

class Floor {
 public:
  Floor(Surface surface, uint64_t seed);
  // A photo floor: the regions (which must not overlap) with the ageing model of the procedural
  // floors on top (grime, stains, tyre marks, scuffs, debris). Views must lie inside one region;
  // a view that strays over its edge sees the edge pixels repeated.
  Floor(std::vector<PhotoRegion> regions, uint64_t seed);

  // Renders floor reflectance (about [0, 1]) into `out` (CV_32F, height x width): pixel (u, v)
  // sees the floor around floor_from_image * (u, v, 1), averaged over supersample x supersample
  // samples (anti-aliasing).
  void Render(const Homography& floor_from_image, int width, int height, int supersample,
              const FloorState& state, cv::Mat* out) const;

  Surface surface() const { return surface_; }
  uint64_t seed() const { return seed_; }
  const std::vector<PhotoRegion>& regions() const { return *regions_; }

 private:
  Surface surface_;
  uint64_t seed_;
  std::shared_ptr<const std::vector<PhotoRegion>> regions_;  // photo floors; empty otherwise
};

}  // namespace synth
}  // namespace gtbow
