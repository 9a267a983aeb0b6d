// Sequence queries: the last few images of a robot, related by its odometry, queried as one
// larger view of the floor. On a floor that changed since it was mapped, one image may hold too
// little of the detail that lasted; the images just before it see the floor next to it, and
// odometry over a few centimetres is accurate to a fraction of a millimetre.
#pragma once

#include <deque>
#include <functional>
#include <optional>
#include <vector>

#include "ground_texture_bow/core/features.h"
#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/core/localizer.h"

namespace gtbow {

// The features of `views` in the pixel frame of views[0] (the newest image, the one to be
// localized; its keypoints first and unchanged). poses[i] is view i's pose in any common frame
// (odometry: metres, radians, the convention of geometry.h); only poses relative to poses[0]
// count. An older view's keypoint is left out when a keypoint already taken lies within
// SameKeypointRadius of it (the same place of the floor seen again: it would give one point of
// the floor several inliers); the others, outside the newest image or where it detected nothing,
// are added, their angles turned into views[0]'s frame. Every view has `geometry`'s size and
// scale; descriptors are copied. Throws std::invalid_argument naming the view when the counts of
// views and poses differ, or a view's descriptors do not match its keypoints or views[0]'s type
// and width.
ImageFeatures CombineViews(const std::vector<const ImageFeatures*>& views,
                           const std::vector<Pose2D>& poses, const ImageGeometry& geometry);

// The radius within which CombineViews takes two keypoints for one, in pixels of views[0], for
// a keypoint of `size` pixels: a tenth of its size, at least 2 pixels.
double SameKeypointRadius(float size);

struct SequenceOptions {
  int length = 1;          // images per query, the newest included; 1 = single images
  double max_span = 0.25;  // metres of odometry from the oldest image kept to the newest
  // The newest image alone first, the combined view only when it gives no fix: a combined view
  // spreads over more keyframes than the newest image's own, which costs a floor whose words are
  // weak (a held-out wood grain lost most of its day-0 fixes to it).
  bool single_first = true;
  void Check() const;  // throws std::invalid_argument naming the bad field
};

// How many of a robot's last images, newest first with their odometry, one sequence query
// combines (what QuerySequence keeps and gtbow eval combines): the newest, then each older one
// in turn while its odometry is known and within options.max_span metres of the newest's, at
// most options.length. 1 when the newest has no odometry; 0 for no image.
size_t ImagesInSpan(const std::vector<std::optional<Pose2D>>& newest_first,
                    const SequenceOptions& options);

// A sequence query's fix (what the node and gtbow eval both do): with `single_first`, the
// newest image's own fix when it has one, else the combined view's; without, the combined
// view's. `single` and `combined` localize one and the other; `combined` runs only when needed.
// *used_combined (if given) says whether the fix, or the failure, is the combined view's.
Localization SequenceFix(const SequenceOptions& options,
                         const std::function<Localization()>& single,
                         const std::function<Localization()>& combined, bool* used_combined);

// The robot's last few images and their odometry, for sequence queries (Localizer::Combine):
// what the node keeps between images in localization mode. Not thread-safe.
class QuerySequence {
 public:
  explicit QuerySequence(const SequenceOptions& options);
  // The newest image with its odometry pose. Without one (no odometry at its time) the
  // sequence starts again with it alone. Images further than max_span from it are dropped.
  void Push(ProcessedImage image, const std::optional<Pose2D>& odometry);
  void Clear() { entries_.clear(); }
  size_t size() const { return entries_.size(); }
  // Newest first, what Localizer::Combine takes.
  std::vector<const ProcessedImage*> images() const;
  std::vector<Pose2D> poses() const;
  const SequenceOptions& options() const { return options_; }

 private:
  struct Entry {
    ProcessedImage image;
    std::optional<Pose2D> odometry;
  };
  SequenceOptions options_;
  std::deque<Entry> entries_;  // newest first
};

}  // namespace gtbow
