// Retrieval metrics of the evaluation protocol (docs/DATASET_FORMAT.md, following the
// paper's §IV): AP@1000, Recall@N and score separation.
#pragma once

#include <cstddef>
#include <vector>

namespace gtbow {

// AP over the first `cutoff` results: (1 / min(R, cutoff)) * sum_k P(k) rel(k), with R the
// number of relevant database images. `relevant[k]` tells whether result k is relevant.
// Precondition: num_relevant > 0 (queries with R = 0 are left out of every metric).
double AveragePrecision(const std::vector<bool>& relevant, size_t num_relevant,
                        size_t cutoff = 1000);

// 1 when a relevant result is among the first n, else 0.
double HitAtN(const std::vector<bool>& relevant, size_t n);

// Score separation: the lowest threshold rejecting at least 99% of the non-relevant scores,
// and the fraction of relevant scores above it. Inputs: top-10 scores of every query, labelled.
struct Separation {
  double threshold = 0.0;
  double kept_relevant = 0.0;  // fraction in [0, 1]
};
Separation ScoreSeparation(const std::vector<double>& relevant_scores,
                           std::vector<double> irrelevant_scores, double reject = 0.99);

// What a SLAM backend reads: answers (a top-1 result, a verified loop closure) accepted in
// order of their evidence (a BoW score, an inlier count), each right or wrong.
struct RankedAnswer {
  double evidence = 0.0;
  bool correct = false;
};
// The precision-recall curve of accepting every answer with evidence >= t, for every t (answers
// of equal evidence are accepted together), and the recall at 100% precision: the largest
// recall of a threshold that accepts no wrong answer (0 when the strongest answer is wrong).
// `positives` is the recall's denominator (the queries that have a right answer to find).
struct PrecisionRecall {
  std::vector<double> evidence, precision, recall;  // one point per distinct evidence value
  double recall_at_full_precision = 0.0;
};
PrecisionRecall PrecisionRecallCurve(std::vector<RankedAnswer> answers, size_t positives);

}  // namespace gtbow
