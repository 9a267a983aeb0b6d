// The retrieval configuration (features, vocabulary, BoW and index options) and its YAML form,
// used by the presets in config/ (high_accuracy.yaml, fast.yaml, ...) and by the ROS layer
// (~preset).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "ground_texture_bow/core/bow.h"
#include "ground_texture_bow/core/features.h"
#include "ground_texture_bow/core/pose.h"
#include "ground_texture_bow/core/vocabulary.h"

namespace gtbow {

struct RetrievalConfig {
  FeatureOptions features;
  VocabularyOptions vocabulary;
  BowOptions bow;
  // How retrieved candidates are verified (section `verification`): K, RANSAC and the checks a
  // pose must pass. These shape the poses, not the map, so a map file does not record them.
  LocalizationOptions verification;

  // Checks every part and their combination (e.g. r <= 1 for an HKM vocabulary).
  void Check() const;
};

// Parses the YAML form: sections `features`, `vocabulary`, `bow` and `verification` whose keys are
// the option names. Missing keys keep their defaults; unknown sections or keys and bad values throw
// std::runtime_error naming `source`, the line and the key.
RetrievalConfig ParseRetrievalConfig(const std::string& yaml, const std::string& source);
RetrievalConfig LoadRetrievalConfig(const std::filesystem::path& path);
// The YAML form of a configuration: every key that shapes the answers (so it documents the
// defaults; a map file records it and refuses to load under other options).
std::string FormatRetrievalConfig(const RetrievalConfig& config);
// Those keys, as "section.key", in the order written (one table in config.cpp drives the
// parser, FormatRetrievalConfig and RetrievalConfigDifference).
std::vector<std::string> RetrievalConfigKeys();
// The `verification` section (every key; a map file does not record them).
std::string FormatVerificationOptions(const LocalizationOptions& verification);
// The `features` section alone (what Vocabulary::extractor() records).
std::string FormatFeatureOptions(const FeatureOptions& features);
// Throws std::invalid_argument naming `vocabulary_name` and the differing keys when the
// vocabulary was trained with another extractor than `features` (a vocabulary from before
// format 3, which did not record it, passes only with the paper's plain extractor).
void CheckVocabularyExtractor(const Vocabulary& vocabulary, const std::string& vocabulary_name,
                              const FeatureOptions& features);
// The keys whose values differ, as "section.key: A (a_name), B (b_name)" joined by "; ";
// empty when the configurations are the same.
std::string RetrievalConfigDifference(const RetrievalConfig& a, const std::string& a_name,
                                      const RetrievalConfig& b, const std::string& b_name);

}  // namespace gtbow
