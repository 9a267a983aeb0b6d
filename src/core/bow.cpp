#include "ground_texture_bow/core/bow.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "ground_texture_bow/core/enum_names.h"
#include "ground_texture_bow/core/parallel.h"

namespace gtbow {

namespace {
constexpr EnumName<SizeBinning> kSizeBinnings[] = {{"none", SizeBinning::kNone},
                                                   {"octave", SizeBinning::kOctave},
                                                   {"percentile", SizeBinning::kPercentile}};
constexpr EnumName<Scoring> kScorings[] = {{"dot", Scoring::kDot}, {"dbow_l1", Scoring::kDbowL1}};
constexpr EnumName<Normalization> kNormalizations[] = {{"global", Normalization::kGlobal},
                                                       {"per_bin", Normalization::kPerBin}};
}  // namespace

SizeBinning ParseSizeBinning(const std::string& name) {
  return ParseEnumName(name, "size binning", kSizeBinnings);
}
std::string SizeBinningName(SizeBinning b) { return EnumValueName(b, kSizeBinnings); }
Scoring ParseScoring(const std::string& name) { return ParseEnumName(name, "scoring", kScorings); }
std::string ScoringName(Scoring s) { return EnumValueName(s, kScorings); }
Normalization ParseNormalization(const std::string& name) {
  return ParseEnumName(name, "normalization", kNormalizations);
}
std::string NormalizationName(Normalization n) { return EnumValueName(n, kNormalizations); }

void BowOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("bow: ") + what);
  };
  need(num_size_bins >= 1 && num_size_bins <= 64, "num_size_bins must be in 1..64");
  need(soft_assignment >= 1 && soft_assignment <= 16, "soft_assignment must be in 1..16");
  need(sigma > 0 && std::isfinite(sigma), "sigma must be positive");
  need(orientation_bins >= 1 && orientation_bins <= 64, "orientation_bins must be in 1..64");
  // Orientation votes are products q_w d_w c_q c_d: they are defined for the dot product only.
  need(!(orientation_verification && scoring == Scoring::kDbowL1),
       "orientation_verification needs scoring: dot (votes are products of weights)");
}

std::vector<float> SizePercentileThresholds(std::vector<float> sizes, int bins) {
  if (bins < 1) throw std::invalid_argument("SizePercentileThresholds: bins must be >= 1");
  std::vector<float> t;
  if (sizes.empty() || bins == 1) return t;
  std::sort(sizes.begin(), sizes.end());
  for (int b = 1; b < bins; ++b) {
    t.push_back(sizes[std::min(sizes.size() - 1, sizes.size() * b / bins)]);
  }
  return t;
}

BowEncoder::BowEncoder(const Vocabulary& vocabulary, const BowOptions& options)
    : vocabulary_(vocabulary), options_(options) {
  options_.Check();
  if (options_.soft_assignment > vocabulary_.max_neighbours()) {
    throw std::invalid_argument(
        "bow: soft_assignment r = " + std::to_string(options_.soft_assignment) +
        " exceeds what a " + VocabularyKindName(vocabulary_.kind()) + " vocabulary supports (" +
        std::to_string(vocabulary_.max_neighbours()) + ")");
  }
  if (options_.size_binning == SizeBinning::kPercentile &&
      vocabulary_.size_thresholds().size() + 1 != static_cast<size_t>(options_.num_size_bins)) {
    throw std::invalid_argument(
        "bow: percentile size binning with S = " + std::to_string(options_.num_size_bins) +
        " needs a vocabulary trained with S - 1 size thresholds; it has " +
        std::to_string(vocabulary_.size_thresholds().size()));
  }
}

uint32_t BowEncoder::num_rows() const {
  return static_cast<uint32_t>(options_.SizeBins()) * vocabulary_.size();
}

int BowEncoder::SizeBin(const Keypoint& k) const {
  switch (options_.size_binning) {
    case SizeBinning::kNone:
      return 0;
    case SizeBinning::kOctave:
      return std::clamp(k.octave, 0, options_.num_size_bins - 1);
    case SizeBinning::kPercentile: {
      const auto& t = vocabulary_.size_thresholds();
      return static_cast<int>(std::upper_bound(t.begin(), t.end(), k.size) - t.begin());
    }
  }
  return 0;
}

BowVector BowEncoder::Encode(const ImageFeatures& f) const {
  BowVector out;
  out.source = f.keypoints;
  out.source_descriptors = f.descriptors;
  out.angles.reserve(f.size());
  for (const auto& k : f.keypoints) out.angles.push_back(k.angle);
  if (f.size() == 0) return out;
  if (f.size() > 65535) throw std::invalid_argument("BowEncoder: more than 65535 keypoints");
  const int r = options_.soft_assignment;
  std::vector<WordHit> hits;
  const int parts = std::min<int>(threads_, static_cast<int>(f.size() / kMinDescriptorsPerThread));
  if (parts <= 1) {
    vocabulary_.Assign(f.descriptors, r, &hits);
  } else {
    // Descriptor assignment split over threads: each assigns a contiguous range of rows.
    std::vector<std::vector<WordHit>> part(parts);
    RunTasks(parts, [&](int t) {
      const int b = static_cast<int>(f.size() * t / parts),
                e = static_cast<int>(f.size() * (t + 1) / parts);
      vocabulary_.Assign(f.descriptors.rowRange(b, e), r, &part[t]);
    });
    hits.reserve(f.size() * r);
    for (const auto& p : part) hits.insert(hits.end(), p.begin(), p.end());
  }
  const uint32_t v = vocabulary_.size();
  const double inv_two_sigma2 = 1.0 / (2.0 * options_.sigma * options_.sigma);
  std::vector<KeypointEntry>& kps = out.keypoints;
  kps.reserve(f.size() * r);
  for (size_t i = 0; i < f.size(); ++i) {
    const uint32_t base = static_cast<uint32_t>(SizeBin(f.keypoints[i])) * v;
    // Soft assignment (§II-D): exp(-d^2 / 2 sigma^2), L1-normalised over the r words.
    double w[16];
    double sum = 0.0;
    for (int j = 0; j < r; ++j) {
      const double d = hits[i * r + j].distance;
      w[j] = r == 1 ? 1.0 : std::exp(-d * d * inv_two_sigma2);
      sum += w[j];
    }
    for (int j = 0; j < r; ++j) {
      const double a = sum > 0 ? w[j] / sum : 1.0 / r;
      kps.push_back(
          {base + hits[i * r + j].word, static_cast<uint16_t>(i), 0.0f, static_cast<float>(a)});
    }
  }
  return FromAssignments(std::move(out), f.size());
}

BowVector BowEncoder::FromAssignments(BowVector out, size_t num_keypoints) const {
  std::vector<KeypointEntry>& kps = out.keypoints;
  const uint32_t v = vocabulary_.size();
  out.entries.clear();
  if (num_keypoints == 0) return out;
  std::sort(kps.begin(), kps.end(), [](const KeypointEntry& a, const KeypointEntry& b) {
    return a.row != b.row ? a.row < b.row : a.keypoint < b.keypoint;
  });
  // tf per row, tf-idf weights, and each keypoint's share of its row (§II-E).
  const auto& idf = vocabulary_.idf();
  std::vector<KeypointEntry> kept;
  kept.reserve(kps.size());
  double norm = 0.0;
  for (size_t b = 0; b < kps.size();) {
    size_t e = b;
    double tf = 0.0;
    while (e < kps.size() && kps[e].row == kps[b].row) tf += kps[e++].assignment;
    const float idf_w = idf.empty() ? 1.0f : idf[kps[b].row % v];
    const double weight = tf / static_cast<double>(num_keypoints) * idf_w;
    if (weight > 0.0) {
      out.entries.push_back({kps[b].row, static_cast<float>(weight)});
      norm += options_.scoring == Scoring::kDot ? weight * weight : weight;
      for (size_t k = b; k < e; ++k) {
        KeypointEntry ke = kps[k];
        ke.contribution = static_cast<float>(ke.assignment / tf);
        kept.push_back(ke);
      }
    }
    b = e;
  }
  kps.swap(kept);
  const bool l2 = options_.scoring == Scoring::kDot;
  if (options_.normalization == Normalization::kPerBin && options_.SizeBins() > 1) {
    // Each size bin's part normalised on its own (entries are sorted by row, so a bin's
    // entries are contiguous), then the whole vector again below.
    norm = 0.0;
    for (size_t b = 0; b < out.entries.size();) {
      const uint32_t bin = out.entries[b].row / v;
      size_t e = b;
      double bin_norm = 0.0;
      for (; e < out.entries.size() && out.entries[e].row / v == bin; ++e) {
        const double w = out.entries[e].weight;
        bin_norm += l2 ? w * w : w;
      }
      const double scale = bin_norm > 0.0 ? (l2 ? 1.0 / std::sqrt(bin_norm) : 1.0 / bin_norm) : 0.0;
      for (size_t k = b; k < e; ++k) {
        out.entries[k].weight = static_cast<float>(out.entries[k].weight * scale);
        const double w = out.entries[k].weight;
        norm += l2 ? w * w : w;
      }
      b = e;
    }
  }
  if (norm > 0.0) {
    const double scale = l2 ? 1.0 / std::sqrt(norm) : 1.0 / norm;
    for (auto& e : out.entries) e.weight = static_cast<float>(e.weight * scale);
  }
  return out;
}

}  // namespace gtbow
