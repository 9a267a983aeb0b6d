// The paper's published figures (Wilhelm & Napp, ICRA 2025; shared/paper), printed next to ours.
#pragma once

#include "ground_texture_bow/core/config.h"

namespace gtbow {
namespace tools {

// Table II (i7-13700, 32,251-image asphalt database), in ms: mean, sd.
struct PaperTiming {
  const char* name;
  double extract[2], transform[2], insert[2], query[2];
};
constexpr PaperTiming kPaperDbow = {"DBoW", {19.1, 2.5}, {6.7, 0.0}, {0.0, 0.0}, {50, 5.5}};
constexpr PaperTiming kPaperHigh = {
    "Ours (High Acc.)", {18.9, 2.5}, {24, 0.3}, {1.4, 0.5}, {149.6, 14.9}};
constexpr PaperTiming kPaperFast = {
    "Ours (Fast)", {18.9, 2.5}, {23.1, 0.3}, {0.6, 0.4}, {31.9, 3.7}};

// The paper's timed version nearest to a configuration: DBoW for an HKM vocabulary, else the
// fast (r = 1) or high-accuracy version.
inline const PaperTiming& PaperTimingFor(const RetrievalConfig& c) {
  if (c.vocabulary.kind == VocabularyKind::kHkm) return kPaperDbow;
  return c.bow.soft_assignment == 1 ? kPaperFast : kPaperHigh;
}

// Table I: mAP on the HD Ground asphalt test set.
struct PaperAblationRow {
  const char* name;
  double map;
};
constexpr PaperAblationRow kPaperAblation[] = {
    {"DBoW", 0.026},       {"DBoW + SB", 0.091},
    {"DBoW + AKM", 0.073}, {"DBoW + AKM + SA (r=3)", 0.191},
    {"DBoW + OV", 0.083},  {"Ours Fast", 0.258},
    {"Ours", 0.559}};

// Score separation (§IV-E): true loop closures kept at the threshold rejecting 99% of false ones.
constexpr double kPaperSeparationDbow = 0.325;
constexpr double kPaperSeparationFast = 0.7101;
constexpr double kPaperSeparationHigh = 0.9121;

}  // namespace tools
}  // namespace gtbow
