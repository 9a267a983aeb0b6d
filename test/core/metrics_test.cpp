#include "ground_texture_bow/eval/metrics.h"

#include <gtest/gtest.h>

namespace gtbow {
namespace {

TEST(Metrics, AveragePrecisionHandCases) {
  // Relevant at ranks 1 and 3 of 2 relevant: (1/1 + 2/3) / 2.
  EXPECT_NEAR(AveragePrecision({true, false, true, false}, 2), (1.0 + 2.0 / 3) / 2, 1e-12);
  // A relevant image never retrieved counts against AP.
  EXPECT_NEAR(AveragePrecision({true, false}, 4), 1.0 / 4, 1e-12);
  // Only the first `cutoff` results count, and R is capped at the cutoff.
  EXPECT_NEAR(AveragePrecision({false, true, true}, 5, 2), (1.0 / 2) / 2, 1e-12);
  EXPECT_DOUBLE_EQ(AveragePrecision({true, true}, 2), 1.0);
  EXPECT_THROW(AveragePrecision({true}, 0), std::invalid_argument);
}

TEST(Metrics, HitAtN) {
  const std::vector<bool> r = {false, false, true};
  EXPECT_EQ(HitAtN(r, 1), 0.0);
  EXPECT_EQ(HitAtN(r, 2), 0.0);
  EXPECT_EQ(HitAtN(r, 3), 1.0);
  EXPECT_EQ(HitAtN(r, 100), 1.0);
}

TEST(Metrics, ScoreSeparation) {
  // 100 non-relevant scores 0.00 .. 0.99: rejecting 99% puts the threshold at 0.98.
  std::vector<double> irr;
  for (int i = 0; i < 100; ++i) irr.push_back(i / 100.0);
  const Separation s = ScoreSeparation({0.5, 0.985, 0.99, 2.0}, irr);
  EXPECT_NEAR(s.threshold, 0.98, 1e-12);
  EXPECT_NEAR(s.kept_relevant, 0.75, 1e-12);
}

TEST(Metrics, PrecisionRecallAndRecallAtFullPrecision) {
  // Right at 0.9 and 0.8, wrong at 0.7, right at 0.6; four answers could be right.
  const PrecisionRecall pr =
      PrecisionRecallCurve({{0.6, true}, {0.9, true}, {0.7, false}, {0.8, true}}, 4);
  ASSERT_EQ(pr.evidence.size(), 4u);
  EXPECT_EQ(pr.evidence, (std::vector<double>{0.9, 0.8, 0.7, 0.6}));
  EXPECT_EQ(pr.precision, (std::vector<double>{1.0, 1.0, 2.0 / 3.0, 0.75}));
  EXPECT_EQ(pr.recall, (std::vector<double>{0.25, 0.5, 0.5, 0.75}));
  EXPECT_DOUBLE_EQ(pr.recall_at_full_precision, 0.5);
  // Answers of equal evidence are accepted together: a wrong one among the strongest gives 0.
  EXPECT_DOUBLE_EQ(
      PrecisionRecallCurve({{0.9, true}, {0.9, false}, {0.5, true}}, 2).recall_at_full_precision,
      0.0);
  EXPECT_DOUBLE_EQ(PrecisionRecallCurve({{3, false}, {2, true}}, 1).recall_at_full_precision, 0.0);
  // All right: the recall of all of them.
  EXPECT_DOUBLE_EQ(PrecisionRecallCurve({{30, true}, {12, true}}, 5).recall_at_full_precision, 0.4);
  const PrecisionRecall none = PrecisionRecallCurve({}, 3);
  EXPECT_TRUE(none.evidence.empty());
  EXPECT_DOUBLE_EQ(none.recall_at_full_precision, 0.0);
}

}  // namespace
}  // namespace gtbow
