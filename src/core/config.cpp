#include "ground_texture_bow/core/config.h"

#include <yaml-cpp/yaml.h>

#include <functional>
#include <map>
#include <vector>
#include <sstream>
#include <stdexcept>

#include "ground_texture_bow/core/file_util.h"

namespace gtbow {

void RetrievalConfig::Check() const {
  features.Check();
  vocabulary.Check();
  bow.Check();
  if (bow.compact_postings && features.num_features > 256) {
    throw std::invalid_argument("bow: compact_postings holds at most 256 keypoints per image; set "
                                "compact_postings: false for features.num_features " +
                                std::to_string(features.num_features));
  }
  if (vocabulary.kind == VocabularyKind::kHkm && bow.soft_assignment != 1) {
    throw std::invalid_argument("bow: soft_assignment must be 1 with an hkm vocabulary");
  }
  const bool binary = features.type == FeatureType::kOrb;
  if (binary && vocabulary.metric == Metric::kL2) {
    throw std::invalid_argument("vocabulary: metric l2 is for SIFT; use l2_bytes or hamming with ORB");
  }
  if (!binary && vocabulary.metric != Metric::kL2) {
    throw std::invalid_argument("vocabulary: SIFT descriptors need metric l2");
  }
  if (bow.size_binning == SizeBinning::kOctave && !binary) {
    throw std::invalid_argument("bow: size_binning octave needs ORB; use percentile with SIFT");
  }
}

namespace {

using Setter = std::function<void(const YAML::Node&)>;

template <typename T>
Setter Set(T* field) {
  return [field](const YAML::Node& n) { *field = n.as<T>(); };
}

template <typename E>
Setter SetEnum(E* field, E (*parse)(const std::string&)) {
  return [field, parse](const YAML::Node& n) { *field = parse(n.as<std::string>()); };
}

Setter SetUint64(uint64_t* field) {
  return [field](const YAML::Node& n) { *field = n.as<uint64_t>(); };
}

std::map<std::string, std::map<std::string, Setter>> Schema(RetrievalConfig* c) {
  FeatureOptions& f = c->features;
  VocabularyOptions& v = c->vocabulary;
  BowOptions& b = c->bow;
  return {
      {"features",
       {{"type", SetEnum(&f.type, &ParseFeatureType)},
        {"num_features", Set(&f.num_features)},
        {"orb_scale_factor", Set(&f.orb_scale_factor)},
        {"orb_num_levels", Set(&f.orb_num_levels)},
        {"orb_edge_threshold", Set(&f.orb_edge_threshold)},
        {"orb_first_level", Set(&f.orb_first_level)},
        {"orb_wta_k", Set(&f.orb_wta_k)},
        {"orb_fast_score", Set(&f.orb_fast_score)},
        {"orb_patch_size", Set(&f.orb_patch_size)},
        {"orb_fast_threshold", Set(&f.orb_fast_threshold)},
        {"contrast", SetEnum(&f.contrast, &ParseContrast)},
        {"contrast_target", Set(&f.contrast_target)},
        {"contrast_max_gain", Set(&f.contrast_max_gain)},
        {"clahe_clip", Set(&f.clahe_clip)},
        {"clahe_tiles", Set(&f.clahe_tiles)},
        {"orb_min_fast_threshold", Set(&f.orb_min_fast_threshold)},
        {"grid_cols", Set(&f.grid_cols)},
        {"grid_rows", Set(&f.grid_rows)},
        {"grid_oversample", Set(&f.grid_oversample)},
        {"grid_refill", Set(&f.grid_refill)},
        {"sift_octave_layers", Set(&f.sift_octave_layers)},
        {"sift_contrast_threshold", Set(&f.sift_contrast_threshold)},
        {"sift_edge_threshold", Set(&f.sift_edge_threshold)},
        {"sift_sigma", Set(&f.sift_sigma)}}},
      {"vocabulary",
       {{"kind", SetEnum(&v.kind, &ParseVocabularyKind)},
        {"metric", SetEnum(&v.metric, &ParseMetric)},
        {"num_words", Set(&v.num_words)},
        {"kmeans_iterations", Set(&v.kmeans_iterations)},
        {"kmeans_stop_fraction", Set(&v.kmeans_stop_fraction)},
        {"kmeans_min_iterations", Set(&v.kmeans_min_iterations)},
        {"num_trees", Set(&v.num_trees)},
        {"checks", Set(&v.checks)},
        {"train_checks", Set(&v.train_checks)},
        {"ann", SetEnum(&v.ann, &ParseAnnIndex)},
        {"nprobe", Set(&v.nprobe)},
        {"train_nprobe", Set(&v.train_nprobe)},
        {"hkm_branching", Set(&v.hkm_branching)},
        {"hkm_depth", Set(&v.hkm_depth)},
        {"seed", SetUint64(&v.seed)},
        {"threads", Set(&v.threads)}}},
      {"bow",
       {{"size_binning", SetEnum(&b.size_binning, &ParseSizeBinning)},
        {"num_size_bins", Set(&b.num_size_bins)},
        {"soft_assignment", Set(&b.soft_assignment)},
        {"sigma", Set(&b.sigma)},
        {"normalization", SetEnum(&b.normalization, &ParseNormalization)},
        {"orientation_verification", Set(&b.orientation_verification)},
        {"orientation_bins", Set(&b.orientation_bins)},
        {"scoring", SetEnum(&b.scoring, &ParseScoring)},
        {"compact_postings", Set(&b.compact_postings)}}},
  };
}

}  // namespace

RetrievalConfig ParseRetrievalConfig(const std::string& text, const std::string& source) {
  auto fail = [&](const YAML::Node* n, const std::string& what) {
    std::ostringstream s;
    s << source;
    if (n != nullptr && n->Mark().line >= 0) s << ":" << n->Mark().line + 1;
    s << ": " << what;
    throw std::runtime_error(s.str());
  };
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::ParserException& e) {
    throw std::runtime_error(source + ":" + std::to_string(e.mark.line + 1) + ": invalid YAML: " + e.msg);
  }
  RetrievalConfig c;
  if (root.IsNull()) return c;
  if (!root.IsMap()) fail(&root, "expected sections features, vocabulary and bow");
  auto schema = Schema(&c);
  for (const auto& section : root) {
    const std::string name = section.first.as<std::string>();
    const auto it = schema.find(name);
    if (it == schema.end()) {
      fail(&section.first, "unknown section '" + name + "' (valid: features, vocabulary, bow)");
    }
    if (!section.second.IsMap()) fail(&section.second, "section '" + name + "' must be a mapping");
    for (const auto& kv : section.second) {
      const std::string key = kv.first.as<std::string>();
      const auto field = it->second.find(key);
      if (field == it->second.end()) fail(&kv.first, "unknown key '" + name + "." + key + "'");
      try {
        field->second(kv.second);
      } catch (const YAML::Exception&) {
        fail(&kv.second, "bad value for '" + name + "." + key + "': '" +
                             (kv.second.IsScalar() ? kv.second.Scalar() : std::string("?")) + "'");
      } catch (const std::invalid_argument& e) {
        fail(&kv.second, name + "." + key + ": " + e.what());
      }
    }
  }
  try {
    c.Check();
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(source + ": " + e.what());
  }
  return c;
}

RetrievalConfig LoadRetrievalConfig(const std::filesystem::path& path) {
  return ParseRetrievalConfig(ReadFile(path), path.string());
}

std::string FormatRetrievalConfig(const RetrievalConfig& c) {
  std::ostringstream s;
  const FeatureOptions& f = c.features;
  const VocabularyOptions& v = c.vocabulary;
  const BowOptions& b = c.bow;
  s << "features:\n"
    << "  type: " << FeatureTypeName(f.type) << "\n"
    << "  num_features: " << f.num_features << "\n"
    << "  orb_scale_factor: " << f.orb_scale_factor << "\n"
    << "  orb_num_levels: " << f.orb_num_levels << "\n"
    << "  orb_edge_threshold: " << f.orb_edge_threshold << "\n"
    << "  orb_first_level: " << f.orb_first_level << "\n"
    << "  orb_wta_k: " << f.orb_wta_k << "\n"
    << "  orb_fast_score: " << (f.orb_fast_score ? "true" : "false") << "\n"
    << "  orb_patch_size: " << f.orb_patch_size << "\n"
    << "  orb_fast_threshold: " << f.orb_fast_threshold << "\n"
    << "  contrast: " << ContrastName(f.contrast) << "\n"
    << "  contrast_target: " << f.contrast_target << "\n"
    << "  contrast_max_gain: " << f.contrast_max_gain << "\n"
    << "  clahe_clip: " << f.clahe_clip << "\n"
    << "  clahe_tiles: " << f.clahe_tiles << "\n"
    << "  orb_min_fast_threshold: " << f.orb_min_fast_threshold << "\n"
    << "  grid_cols: " << f.grid_cols << "\n"
    << "  grid_rows: " << f.grid_rows << "\n"
    << "  grid_oversample: " << f.grid_oversample << "\n"
    << "  grid_refill: " << (f.grid_refill ? "true" : "false") << "\n"
    << "  sift_octave_layers: " << f.sift_octave_layers << "\n"
    << "  sift_contrast_threshold: " << f.sift_contrast_threshold << "\n"
    << "  sift_edge_threshold: " << f.sift_edge_threshold << "\n"
    << "  sift_sigma: " << f.sift_sigma << "\n"
    << "vocabulary:\n"
    << "  kind: " << VocabularyKindName(v.kind) << "\n"
    << "  metric: " << MetricName(v.metric) << "\n"
    << "  num_words: " << v.num_words << "\n"
    << "  kmeans_iterations: " << v.kmeans_iterations << "\n"
    << "  kmeans_stop_fraction: " << v.kmeans_stop_fraction << "\n"
    << "  kmeans_min_iterations: " << v.kmeans_min_iterations << "\n"
    << "  num_trees: " << v.num_trees << "\n"
    << "  checks: " << v.checks << "\n"
    << "  train_checks: " << v.train_checks << "\n"
    << "  ann: " << AnnIndexName(v.ann) << "\n"
    << "  nprobe: " << v.nprobe << "\n"
    << "  train_nprobe: " << v.train_nprobe << "\n"
    << "  hkm_branching: " << v.hkm_branching << "\n"
    << "  hkm_depth: " << v.hkm_depth << "\n"
    << "  seed: " << v.seed << "\n"
    << "bow:\n"
    << "  size_binning: " << SizeBinningName(b.size_binning) << "\n"
    << "  num_size_bins: " << b.num_size_bins << "\n"
    << "  soft_assignment: " << b.soft_assignment << "\n"
    << "  sigma: " << b.sigma << "\n"
    << "  normalization: " << NormalizationName(b.normalization) << "\n"
    << "  orientation_verification: " << (b.orientation_verification ? "true" : "false") << "\n"
    << "  orientation_bins: " << b.orientation_bins << "\n"
    << "  scoring: " << ScoringName(b.scoring) << "\n"
    << "  compact_postings: " << (b.compact_postings ? "true" : "false") << "\n";
  return s.str();
}

std::string RetrievalConfigDifference(const RetrievalConfig& a, const std::string& a_name,
                                      const RetrievalConfig& b, const std::string& b_name) {
  auto lines = [](const std::string& text) {
    std::vector<std::string> out;
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);) out.push_back(line);
    return out;
  };
  const auto la = lines(FormatRetrievalConfig(a)), lb = lines(FormatRetrievalConfig(b));
  std::string section, diff;
  for (size_t i = 0; i < la.size() && i < lb.size(); ++i) {
    if (!la[i].empty() && la[i][0] != ' ') {
      section = la[i].substr(0, la[i].size() - 1);  // "features:" -> "features"
      continue;
    }
    if (la[i] == lb[i]) continue;
    const size_t colon = la[i].find(':');
    const std::string key = la[i].substr(2, colon - 2);
    const std::string va = la[i].substr(colon + 2), vb = lb[i].substr(lb[i].find(':') + 2);
    diff += (diff.empty() ? "" : "; ") + section + "." + key + ": " + va + " (" + a_name + "), " + vb +
            " (" + b_name + ")";
  }
  return diff;
}

std::string FormatFeatureOptions(const FeatureOptions& features) {
  RetrievalConfig c;
  c.features = features;
  const std::string all = FormatRetrievalConfig(c);
  return all.substr(0, all.find("vocabulary:\n"));
}

void CheckVocabularyExtractor(const Vocabulary& vocabulary, const std::string& vocabulary_name,
                              const FeatureOptions& features) {
  if (vocabulary.extractor().empty()) {
    if (IsPlainExtractor(features)) return;
    throw std::invalid_argument(vocabulary_name +
                                ": the vocabulary does not record its feature extractor (written "
                                "before format 3) and the preset adapts features to the floor; "
                                "train it again with gtbow train-vocab");
  }
  if (vocabulary.extractor() == FormatFeatureOptions(features)) return;
  RetrievalConfig trained;
  try {
    trained = ParseRetrievalConfig(vocabulary.extractor(), vocabulary_name + " (its extractor)");
  } catch (const std::exception& e) {
    throw std::invalid_argument(std::string(e.what()));
  }
  RetrievalConfig wanted;
  wanted.features = features;
  const std::string diff = RetrievalConfigDifference(trained, "the vocabulary", wanted, "the preset");
  if (!diff.empty()) {
    throw std::invalid_argument(vocabulary_name +
                                ": the vocabulary was trained with another feature extractor than "
                                "the preset's (" + diff + "); train it with the preset");
  }
}

}  // namespace gtbow
