// Planar geometry of a downward camera over the floor: poses, footprints and overlap.
// Frames follow docs/DATASET_FORMAT.md: the floor frame is the image frame of a camera with
// theta = 0, scaled to metres; u points right and v down in the image.
#pragma once

#include <array>
#include <vector>

namespace gtbow {

// A 2-D point or vector; metres in the floor frame or pixels in an image, as the name says.
struct Vec2 {
  double x = 0.0;
  double y = 0.0;
};

// Pose of an image on the floor: the floor position (metres) of the image centre pixel
// ((W-1)/2, (H-1)/2) and the rotation theta (radians, CCW) from image axes to floor axes.
struct Pose2D {
  double x = 0.0;
  double y = 0.0;
  double theta = 0.0;
};

// Intrinsics shared by every image of a dataset: size in pixels and ground sampling distance.
struct ImageGeometry {
  int width = 640;                    // pixels
  int height = 480;                   // pixels
  double meters_per_pixel = 0.00025;  // metres per pixel, > 0
};

// Maps pixel (u, v) of an image with pose `floor_from_image` to floor metres.
Vec2 FloorFromImage(const Pose2D& floor_from_image, const ImageGeometry& geometry, Vec2 pixel);

// Inverse of FloorFromImage: the pixel (u, v) at which floor point `floor` appears.
Vec2 ImageFromFloor(const Pose2D& floor_from_image, const ImageGeometry& geometry, Vec2 floor);

// The four floor-frame corners (metres) of an image's footprint, counter-clockwise.
std::array<Vec2, 4> Footprint(const Pose2D& pose, const ImageGeometry& geometry);

// Signed area (positive when counter-clockwise) of a simple polygon.
double PolygonArea(const std::vector<Vec2>& polygon);

// Intersection of two convex polygons given counter-clockwise (Sutherland-Hodgman clipping).
std::vector<Vec2> ConvexIntersection(const std::vector<Vec2>& subject,
                                     const std::vector<Vec2>& clip);

// area(fp(query) ∩ fp(database)) / area(fp(query)), in [0, 1] (DATASET_FORMAT.md, Overlap).
double Overlap(const Pose2D& query, const Pose2D& database, const ImageGeometry& geometry);

// The evaluation protocol's relevance threshold on Overlap.
constexpr double kRelevantOverlap = 0.25;

// True when `database` is relevant to `query`: Overlap >= kRelevantOverlap.
bool IsRelevant(const Pose2D& query, const Pose2D& database, const ImageGeometry& geometry);

// Wraps an angle to (-pi, pi].
double WrapAngle(double angle);

// a * b: pose b, given in a's frame, in the frame a is given in (angles add, unwrapped).
Pose2D Compose(const Pose2D& a, const Pose2D& b);
// The inverse pose: Compose(p, Inverse(p)) is the identity.
Pose2D Inverse(const Pose2D& p);

}  // namespace gtbow
