// Temporal consistency of loop closures (issue 15, part 4).
#include "ground_texture_bow/core/temporal_consistency.h"

#include <gtest/gtest.h>

namespace gtbow {
namespace {

// A closure of an image at odometry pose `own` to keyframe `id` at `map_from_match`, placing the
// image at `implied` in the map.
ClosureObservation Closure(uint32_t id, const Pose2D& map_from_match, const Pose2D& implied,
                           const std::optional<Pose2D>& own) {
  return {id, map_from_match, Compose(Inverse(map_from_match), implied), own};
}

TEST(TemporalConsistency, PublishesOnceNImagesInARowAgree) {
  TemporalConsistencyOptions o;
  o.required = 3;
  TemporalConsistency t(o);
  // The robot drives along x; odometry has drifted by (+20 mm, -5 mm, 0.01 rad), which every
  // true closure corrects in the same way.
  const Pose2D drift{0.02, -0.005, 0.01};
  std::vector<bool> published;
  for (int i = 0; i < 5; ++i) {
    const Pose2D own{0.01 * i, 0.0, 0.0};
    const Pose2D truth = Compose(drift, own);
    const Pose2D kf{0.01 * i + 0.003, 0.001, 0.02};
    published.push_back(t.Next(Closure(7 + i, kf, truth, own)));
  }
  EXPECT_EQ(published, (std::vector<bool>{false, false, true, true, true}));
  EXPECT_EQ(t.run(), 5);
  // A closure that puts the image 320 mm away (a repeated patch of floor) breaks the run...
  const Pose2D own{0.05, 0.0, 0.0};
  EXPECT_FALSE(t.Next(Closure(90, {0.37, 0.0, 0.0}, {0.37, 0.0, 0.0}, own)));
  EXPECT_EQ(t.run(), 1);
  // ... and so does an image without a closure.
  EXPECT_FALSE(t.Next(std::nullopt));
  EXPECT_EQ(t.run(), 0);
}

TEST(TemporalConsistency, TheRunFollowsThePassItIsOn) {
  TemporalConsistencyOptions o;
  o.required = 3;
  TemporalConsistency t(o);
  // Two earlier passes over the place, their keyframes' odometry drifted apart by 8 cm: each
  // image verifies against one keyframe of each. The better candidate alternates between the
  // passes; the run must follow one.
  const Pose2D pass_a{0.0, 0.0, 0.0}, pass_b{0.08, 0.0, 0.0};  // drift of each pass
  int published = 0;
  for (int i = 0; i < 6; ++i) {
    const Pose2D own{0.01 * i, 0.0, 0.0};  // the robot now, by its odometry (no drift)
    auto seen_from = [&](const Pose2D& drift, uint32_t id) {
      const Pose2D keyframe_true{0.01 * i + 0.002, 0.001, 0.0};
      return Closure(id, Compose(drift, keyframe_true), Compose(drift, own), own);
    };
    std::vector<ClosureObservation> c = {seen_from(pass_a, 10 + i), seen_from(pass_b, 200 + i)};
    if (i % 2 == 1) std::swap(c[0], c[1]);  // the other pass has more inliers this time
    const size_t pick = t.Pick(c);
    if (i > 0) EXPECT_EQ(c[pick].match_id, 10u + i) << i;  // stays on pass a
    published += t.Next(c[pick]) ? 1 : 0;
  }
  EXPECT_EQ(published, 4);  // images 2..5
  EXPECT_EQ(t.Pick({}), 0u);
}

TEST(TemporalConsistency, NOfOnePublishesEveryClosureAndFallbacksCompareWhatIsKnown) {
  TemporalConsistency every(TemporalConsistencyOptions{});
  EXPECT_TRUE(every.Next(Closure(1, {0, 0, 0}, {0, 0, 0}, std::nullopt)));
  EXPECT_TRUE(every.Next(Closure(500, {5, 5, 0}, {5, 5, 0}, std::nullopt)));

  TemporalConsistencyOptions o;
  TemporalConsistency t(o);
  // Without own poses: implied poses within max_motion (0.1 m) agree.
  EXPECT_TRUE(t.Agree(Closure(1, {0, 0, 0}, {0.0, 0, 0}, std::nullopt),
                      Closure(2, {0.05, 0, 0}, {0.05, 0, 0}, std::nullopt)));
  EXPECT_FALSE(t.Agree(Closure(1, {0, 0, 0}, {0.0, 0, 0}, std::nullopt),
                       Closure(2, {0.3, 0, 0}, {0.3, 0, 0}, std::nullopt)));
  // Without keyframe poses either: matched ids within max_id_gap.
  ClosureObservation a{10, std::nullopt, {}, std::nullopt}, b = a, c = a;
  b.match_id = 14;
  c.match_id = 200;
  EXPECT_TRUE(t.Agree(a, b));
  EXPECT_FALSE(t.Agree(a, c));
  o.required = 0;
  EXPECT_THROW(TemporalConsistency{o}, std::invalid_argument);
}

}  // namespace
}  // namespace gtbow
