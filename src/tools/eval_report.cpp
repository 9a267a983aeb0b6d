// gtbow eval's reports: results.json (every number) and summary.md (ours next to the paper's
// figures), from the measured PresetResults.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>
#include <string>
#include <thread>

#include "eval_results.h"
#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/parallel.h"
#include "ground_texture_bow/core/pose.h"
#include "ground_texture_bow/core/progress.h"
#include "ground_texture_bow/core/simd.h"
#include "ground_texture_bow/eval/metrics.h"
#include "image_source.h"
#include "json_writer.h"
#include "paper_reference.h"
#include "timing.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace tools {

namespace {

void WriteStat(Json& j, const std::string& key, const TimingStats& s) {
  j.Key(key).Open('{');
  j.Key("mean_ms")
      .Num(s.mean)
      .Key("sd_ms")
      .Num(s.sd)
      .Key("median_ms")
      .Num(s.median)
      .Key("p95_ms")
      .Num(s.p95);
  j.Close('}');
}

// A precision-recall curve, thinned to at most 200 points (the first and last kept).
void WriteCurve(Json& j, const std::string& key, const PrecisionRecall& pr) {
  std::vector<double> e, p, r;
  const size_t n = pr.evidence.size(), step = std::max<size_t>(1, (n + 199) / 200);
  for (size_t i = 0; i < n; i += step) {
    e.push_back(pr.evidence[i]);
    p.push_back(pr.precision[i]);
    r.push_back(pr.recall[i]);
  }
  if (n > 0 && (n - 1) % step != 0) {
    e.push_back(pr.evidence.back());
    p.push_back(pr.precision.back());
    r.push_back(pr.recall.back());
  }
  j.Key(key).Open('{').Key("evidence").Nums(e).Key("precision").Nums(p).Key("recall").Nums(r);
  j.Close('}');
}

double PaperSeparationFor(const RetrievalConfig& c) {
  if (c.vocabulary.kind == VocabularyKind::kHkm) return kPaperSeparationDbow;
  return c.bow.soft_assignment == 1 ? kPaperSeparationFast : kPaperSeparationHigh;
}

}  // namespace

std::string ToJson(const EvalArgs& a, const Dataset& ds, const std::vector<PresetResult>& results) {
  Json j;
  j.Open('{');
  j.Key("dataset").Open('{');
  j.Key("path").Str(fs::absolute(a.dataset).string());
  j.Key("name").Str(ds.info().name).Key("surface").Str(ds.info().surface);
  j.Key("image_width")
      .Int(ds.info().geometry.width)
      .Key("image_height")
      .Int(ds.info().geometry.height);
  j.Key("meters_per_pixel").Num(ds.info().geometry.meters_per_pixel);
  j.Close('}');
  j.Key("protocol").Open('{');
  j.Key("success_position_mm").Num(kSuccessMeters * 1000).Key("success_heading_deg").Num(1.5);
  j.Key("sequence").Int(a.sequence);
  j.Key("sequence_single_first").Bool(a.sequence > 1 && !a.sequence_always);
  j.Key("sequence_max_span_m").Num(a.sequence_max_span);
  j.Key("recall_n").Open('[');
  for (size_t n : kRecallN) j.Int(static_cast<long long>(n));
  j.Close(']');
  j.Close('}');
  j.Key("presets").Open('[');
  for (const auto& pr : results) {
    j.Open('{');
    j.Key("name").Str(pr.name).Key("file").Str(pr.file).Key("vocabulary").Str(pr.vocab_desc);
    j.Key("table_i_row").Str(pr.table_row);
    j.Key("configuration").Str(FormatRetrievalConfig(pr.config));
    // Query options a map does not record (FormatRetrievalConfig leaves them out).
    j.Key("query_num_features").Int(pr.config.features.query_num_features);
    j.Key("query_escalate").Bool(pr.config.features.query_escalate);
    j.Key("query_escalate_backoff").Int(pr.config.features.query_escalate_backoff);
    j.Key("verification").Str(FormatVerificationOptions(pr.config.verification));
    j.Key("localization_candidates").Int(pr.config.verification.candidates);
    j.Key("database_images").Int(static_cast<long long>(pr.db_images));
    if (!a.maintain.empty()) {
      const MaintenanceOptions& mo = pr.maintenance.options;
      j.Key("maintenance").Open('{');
      j.Key("refresh_below_inliers").Int(mo.refresh_below_inliers);
      j.Key("min_inliers").Int(mo.min_inliers).Key("place_fraction").Num(mo.place_fraction);
      j.Key("max_views_per_place")
          .Int(mo.max_views_per_place)
          .Key("max_theta_sigma")
          .Num(mo.max_theta_sigma);
      j.Key("sessions").Open('[');
      for (const MaintenanceSession& ms : pr.maintenance.sessions) {
        j.Open('{').Key("split").Str(ms.split).Key("day").Num(ms.day);
        j.Key("images").Int(static_cast<long long>(ms.images));
        j.Key("fixes").Int(static_cast<long long>(ms.fixes));
        j.Key("correct").Int(static_cast<long long>(ms.correct));
        j.Key("added").Int(static_cast<long long>(ms.added));
        j.Key("retired").Int(static_cast<long long>(ms.retired));
        j.Key("added_wrong").Int(static_cast<long long>(ms.added_wrong));
        j.Key("added_error_mm").Nums(ms.added_error_mm);
        j.Key("added_error_deg").Nums(ms.added_error_deg);
        j.Key("keyframes_after").Int(static_cast<long long>(ms.keyframes_after));
        j.Close('}');
      }
      j.Close(']').Close('}');
    }
    j.Key("splits").Open('[');
    for (const auto& s : pr.splits) {
      j.Open('{');
      j.Key("name").Str(s.name).Key("day").Num(s.day);
      j.Key("queries").Int(static_cast<long long>(s.queries));
      j.Key("queries_with_relevant").Int(static_cast<long long>(s.counted));
      j.Key("queries_without_relevant").Int(static_cast<long long>(s.no_relevant));
      j.Key("escalated_queries").Int(static_cast<long long>(s.escalated));
      j.Key("first_passes_skipped").Int(static_cast<long long>(s.first_passes_skipped));
      j.Key("map_at_1000").Num(s.map);
      j.Key("recall_at_n").Nums(s.recall);
      j.Key("separation").Open('{').Key("threshold").Num(s.separation.threshold);
      j.Key("kept_relevant").Num(s.separation.kept_relevant).Close('}');
      j.Key("separation_vs_disjoint")
          .Open('{')
          .Key("threshold")
          .Num(s.separation_disjoint.threshold);
      j.Key("kept_relevant").Num(s.separation_disjoint.kept_relevant).Close('}');
      j.Key("top10_scores_relevant").Nums(s.rel_scores);
      j.Key("top10_scores_irrelevant").Nums(s.irr_scores);
      j.Key("localization").Open('{');
      j.Key("success_rate").Num(s.queries ? static_cast<double>(s.localized) / s.queries : NAN);
      j.Key("correct").Int(static_cast<long long>(s.localized));
      j.Key("estimated").Int(static_cast<long long>(s.estimated));
      j.Key("position_error_mm").Nums(s.err_mm).Key("heading_error_deg").Nums(s.err_deg);
      j.Close('}');
      j.Key("backend").Open('{');
      j.Key("verified_poses").Int(static_cast<long long>(s.verified_poses));
      j.Key("wrong_verified_poses").Int(static_cast<long long>(s.wrong_verified_poses));
      j.Key("recall_at_100_precision_bow_top1").Num(s.pr_bow.recall_at_full_precision);
      j.Key("recall_at_100_precision_verified").Num(s.pr_verified.recall_at_full_precision);
      WriteCurve(j, "pr_bow_top1", s.pr_bow);
      WriteCurve(j, "pr_verified", s.pr_verified);
      j.Close('}');
      j.Close('}');
    }
    j.Close(']');
    j.Key("timing").Open('{');
    j.Key("queries").Int(static_cast<long long>(pr.timed));
    j.Key("presets_side_by_side").Bool(pr.timed_side_by_side);
    j.Key("in_order").Bool(pr.timed_in_order);
    j.Key("first_passes_skipped").Int(static_cast<long long>(pr.timed_first_passes_skipped));
    j.Key("kernels").Open('{').Key("hamming").Str(ActiveHammingKernelName());
    j.Key("l2_bytes").Str(ActiveByteDistanceKernelName()).Close('}');
    // The stages of PresetResult and of each KernelTiming.
    auto stages = [&j](const auto& t) {
      WriteStat(j, "feature_extraction", t.extract);
      WriteStat(j, "bow_transform", t.transform);
      WriteStat(j, "database_insertion", t.insert);
      WriteStat(j, "database_query", t.query);
      WriteStat(j, "pose_estimation", t.pose);
      WriteStat(j, "end_to_end", t.total);
    };
    stages(pr);
    j.Key("by_kernel").Open('[');
    for (const auto& k : pr.by_kernel) {
      j.Open('{').Key("requested").Str(k.requested).Key("hamming").Str(k.hamming);
      j.Key("l2_bytes").Str(k.l2_bytes);
      stages(k);
      j.Close('}');
    }
    j.Close(']');
    j.Close('}');
    j.Key("scaling").Open('[');
    for (const auto& sp : pr.scaling) {
      j.Open('{').Key("images").Int(static_cast<long long>(sp.images));
      WriteStat(j, "insertion", sp.insert);
      WriteStat(j, "query", sp.query);
      j.Close('}');
    }
    j.Close(']');
    j.Close('}');
  }
  j.Close(']');
  j.Close('}');
  return j.str();
}

std::string ToMarkdown(const EvalArgs& a, const std::vector<PresetResult>& results) {
  std::ostringstream md;
  char b[512];
  md << "# gtbow eval: " << a.dataset << "\n\n";
  md << "Protocol: docs/DATASET_FORMAT.md. Localization verifies the top K candidates "
        "(each preset's verification.candidates); success is a position error of at most 4.8 mm "
        "and a heading error of at "
        "most 1.5 degrees (no estimate counts as a failure). \"sep. vs disjoint\" is a "
        "diagnostic: the separation when only false results that do not overlap the query at all "
        "count as false (near misses with 1-24% overlap share real texture).\n\n";
  if (!results.empty() && !results[0].table_row.empty()) {
    md << "## Ablation (the paper's Table I)\n\nmAP@1000 per query split; the paper's column is "
          "its HD Ground asphalt test set.\n\n| row | preset | paper mAP |";
    for (const auto& s : results[0].splits) md << " " << s.name << " |";
    md << "\n| --- | --- | --- |";
    for (size_t k = 0; k < results[0].splits.size(); ++k) md << " --- |";
    md << "\n";
    for (const auto& pr : results) {
      double paper = NAN;
      for (const auto& r : kPaperAblation) {
        if (pr.table_row == r.name) paper = r.map;
      }
      std::snprintf(b, sizeof(b), "| %s | %s | %.3f |", pr.table_row.c_str(), pr.name.c_str(),
                    paper);
      md << b;
      for (const auto& s : pr.splits) {
        std::snprintf(b, sizeof(b), " %.3f |", s.map);
        md << b;
      }
      md << "\n";
    }
    md << "\n";
  }
  for (const auto& pr : results) {
    md << "## " << pr.name << "\n\n";
    md << "Database: " << pr.db_images << " images. Vocabulary: " << pr.vocab_desc << ".\n\n";
    md << "| split | day | queries | mAP@1000 | R@1 | R@5 | R@10 | R@100 | separation (paper "
       << std::fixed << std::setprecision(1) << 100 * PaperSeparationFor(pr.config)
       << "%) | sep. vs disjoint | localized | median error |\n";
    md << "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for (const auto& s : pr.splits) {
      std::vector<double> e = s.err_mm;
      std::sort(e.begin(), e.end());
      std::snprintf(
          b, sizeof(b),
          "| %s | %s | %zu | %.3f | %.3f | %.3f | %.3f | %.3f | %.1f%% | %.1f%% | %.1f%% | %s |\n",
          s.name.c_str(),
          std::isfinite(s.day) ? std::to_string(static_cast<int>(s.day)).c_str() : "-", s.counted,
          s.map, s.recall[0], s.recall[2], s.recall[3], s.recall[6],
          100 * s.separation.kept_relevant, 100 * s.separation_disjoint.kept_relevant,
          s.queries ? 100.0 * s.localized / s.queries : 0.0,
          e.empty() ? "-" : (std::to_string(e[e.size() / 2]).substr(0, 5) + " mm").c_str());
      md << b;
    }
    md << "\nWhat a SLAM backend reads: recall at 100% precision over the queries with a relevant "
          "image, accepting the top-1 result by its BoW score, or the published loop closure (the "
          "first verified candidate) by its inliers; and every pose the top "
       << pr.config.verification.candidates
       << " candidates verified, with the wrong ones (beyond 4.8 mm or 1.5 deg):\n\n"
       << "| split | R@100P top-1 (BoW score) | R@100P verified (inliers) | verified poses | "
          "wrong |\n| --- | --- | --- | --- | --- |\n";
    for (const auto& s : pr.splits) {
      std::snprintf(b, sizeof(b), "| %s | %.3f | %.3f | %zu | %zu |\n", s.name.c_str(),
                    s.pr_bow.recall_at_full_precision, s.pr_verified.recall_at_full_precision,
                    s.verified_poses, s.wrong_verified_poses);
      md << b;
    }
    const PaperTiming& p = PaperTimingFor(pr.config);
    md << "\nTiming over " << pr.timed
       << (pr.timed_in_order ? " queries in order" : " random queries")
       << " against the full database, one thread"
       << (pr.timed_side_by_side ? ", the presets side by side (the order rotating)" : "")
       << " (ms; kernels: " << ActiveSimdKernels() << "; paper: " << p.name
       << ", i7-13700, 32,251 images):\n\n";
    md << "| stage | paper mean ± sd | here mean ± sd | here median | here p95 |\n| --- | --- | "
          "--- | --- | --- |\n";
    auto row = [&](const char* name, const double* paper, const TimingStats& s) {
      if (paper != nullptr) {
        std::snprintf(b, sizeof(b), "| %s | %.1f ± %.1f | %.3f ± %.3f | %.3f | %.3f |\n", name,
                      paper[0], paper[1], s.mean, s.sd, s.median, s.p95);
      } else {
        std::snprintf(b, sizeof(b), "| %s | - | %.3f ± %.3f | %.3f | %.3f |\n", name, s.mean, s.sd,
                      s.median, s.p95);
      }
      md << b;
    };
    row("feature extraction", p.extract, pr.extract);
    row("BoW transform", p.transform, pr.transform);
    row("database insertion", p.insert, pr.insert);
    row("database query", p.query, pr.query);
    row("pose estimation", nullptr, pr.pose);
    row("end to end (extraction, transform, query, pose)", nullptr, pr.total);
    std::snprintf(b, sizeof(b),
                  "\nEnd-to-end localization rate: %.1f Hz (median), paper: over 5 Hz.\n\n",
                  pr.total.median > 0 ? 1000.0 / pr.total.median : 0.0);
    md << b;
    md << "Scaling (the paper's Fig. 3): insertion over the last 1,000 insertions, query over "
       << kScalingQueries
       << " queries, ms.\n\n| database images | insertion mean | insertion p95 | query median | "
          "query p95 |\n"
       << "| --- | --- | --- | --- | --- |\n";
    for (const auto& sp : pr.scaling) {
      std::snprintf(b, sizeof(b), "| %zu | %.3f | %.3f | %.3f | %.3f |\n", sp.images,
                    sp.insert.mean, sp.insert.p95, sp.query.median, sp.query.p95);
      md << b;
    }
    md << "\n";
  }
  return md.str();
}

}  // namespace tools
}  // namespace gtbow
