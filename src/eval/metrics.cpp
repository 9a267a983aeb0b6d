#include "ground_texture_bow/eval/metrics.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace gtbow {

double AveragePrecision(const std::vector<bool>& relevant, size_t num_relevant, size_t cutoff) {
  if (num_relevant == 0) throw std::invalid_argument("AveragePrecision: no relevant images");
  const size_t n = std::min(relevant.size(), cutoff);
  double hits = 0.0, sum = 0.0;
  for (size_t k = 0; k < n; ++k) {
    if (relevant[k]) {
      hits += 1.0;
      sum += hits / static_cast<double>(k + 1);
    }
  }
  return sum / static_cast<double>(std::min(num_relevant, cutoff));
}

double HitAtN(const std::vector<bool>& relevant, size_t n) {
  const size_t m = std::min(n, relevant.size());
  for (size_t k = 0; k < m; ++k) {
    if (relevant[k]) return 1.0;
  }
  return 0.0;
}

Separation ScoreSeparation(const std::vector<double>& relevant_scores,
                           std::vector<double> irrelevant, double reject) {
  Separation s;
  if (irrelevant.empty()) {
    s.threshold = -INFINITY;
    s.kept_relevant = relevant_scores.empty() ? 0.0 : 1.0;
    return s;
  }
  std::sort(irrelevant.begin(), irrelevant.end());
  // The lowest t with #{irrelevant <= t} >= reject * N: scores strictly above t are kept.
  const size_t need = static_cast<size_t>(std::ceil(reject * irrelevant.size()));
  s.threshold = irrelevant[std::max<size_t>(1, need) - 1];
  size_t kept = 0;
  for (double x : relevant_scores) kept += x > s.threshold ? 1 : 0;
  s.kept_relevant =
      relevant_scores.empty() ? 0.0 : static_cast<double>(kept) / relevant_scores.size();
  return s;
}

PrecisionRecall PrecisionRecallCurve(std::vector<RankedAnswer> answers, size_t positives) {
  PrecisionRecall pr;
  std::sort(answers.begin(), answers.end(),
            [](const RankedAnswer& a, const RankedAnswer& b) { return a.evidence > b.evidence; });
  const double denominator = static_cast<double>(std::max<size_t>(1, positives));
  size_t right = 0, wrong = 0;
  for (size_t i = 0; i < answers.size();) {
    size_t j = i;
    for (; j < answers.size() && answers[j].evidence == answers[i].evidence; ++j) {
      (answers[j].correct ? right : wrong) += 1;
    }
    pr.evidence.push_back(answers[i].evidence);
    pr.precision.push_back(static_cast<double>(right) / static_cast<double>(right + wrong));
    pr.recall.push_back(static_cast<double>(right) / denominator);
    if (wrong == 0) pr.recall_at_full_precision = pr.recall.back();
    i = j;
  }
  return pr;
}

}  // namespace gtbow
