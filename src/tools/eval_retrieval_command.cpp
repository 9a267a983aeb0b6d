// gtbow eval-retrieval: mAP@1000, Recall@N and score separation of one retrieval
// configuration on a dataset (shared/DATASET_FORMAT.md, evaluation protocol).
#include <algorithm>
#include <atomic>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <thread>

#include "commands.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/metrics.h"
#include "ground_texture_bow/core/progress.h"
#include "image_source.h"

namespace gtbow {
namespace tools {

namespace {

struct EvalArgs {
  std::string vocab;
  std::string preset;
  std::string dataset;
  std::vector<std::string> query_splits;
  size_t max_queries = 0;
  int threads = 0;
  std::string markdown;
  bool quiet = false;
};

void RunEval(const EvalArgs& a) {
  const RetrievalConfig c = a.preset.empty() ? RetrievalConfig{} : LoadRetrievalConfig(a.preset);
  const auto vocab = Vocabulary::Load(a.vocab);
  vocab->set_search(c.vocabulary.ann, c.vocabulary.nprobe);
  const BowEncoder enc(*vocab, c.bow);
  const Dataset ds = Dataset::Load(a.dataset);
  const ImageGeometry geo = ds.info().geometry;
  ImageSource db_src = ImageSource::FromDataset(a.dataset, "database");
  const auto db_vecs = EncodeAll(enc, ExtractAll(db_src, c.features, a.threads, !a.quiet), a.threads, !a.quiet);
  BowDatabase db(enc.num_rows(), c.bow, vocab->fingerprint());
  std::vector<Pose2D> db_pose;
  for (size_t i = 0; i < db_vecs.size(); ++i) {
    db.Add(db_vecs[i]);
    db_pose.push_back(ds.PoseOf(db_src.name(i)));
  }
  std::vector<std::string> splits = a.query_splits;
  if (splits.empty()) {
    for (const auto& s : ds.SplitNames()) {
      if (s.rfind("query", 0) == 0) splits.push_back(s);
    }
  }
  std::string md = "| split | queries | mAP@1000 | R@1 | R@5 | R@10 | R@100 | separation (kept at 99% rejection) |\n"
                   "| --- | --- | --- | --- | --- | --- | --- | --- |\n";
  for (const auto& split : splits) {
    ImageSource q_src = ImageSource::FromDataset(a.dataset, split);
    q_src.Subsample(a.max_queries);
    const auto q_vecs = EncodeAll(enc, ExtractAll(q_src, c.features, a.threads, !a.quiet), a.threads, !a.quiet);
    double ap = 0, r1 = 0, r5 = 0, r10 = 0, r100 = 0;
    size_t counted = 0, no_relevant = 0;
    std::vector<double> rel_scores, irr_scores;
    for (size_t qi = 0; qi < q_vecs.size(); ++qi) {
      const Pose2D qp = ds.PoseOf(q_src.name(qi));
      size_t num_rel = 0;
      for (const auto& dp : db_pose) num_rel += IsRelevant(qp, dp, geo) ? 1 : 0;
      if (num_rel == 0) {
        ++no_relevant;
        continue;
      }
      const auto res = db.Query(q_vecs[qi], 1000, false);
      std::vector<bool> rel;
      for (size_t k = 0; k < res.size(); ++k) {
        const bool r = IsRelevant(qp, db_pose[res[k].image], geo);
        rel.push_back(r);
        if (k < 10) (r ? rel_scores : irr_scores).push_back(res[k].score);
      }
      ap += AveragePrecision(rel, num_rel);
      r1 += HitAtN(rel, 1);
      r5 += HitAtN(rel, 5);
      r10 += HitAtN(rel, 10);
      r100 += HitAtN(rel, 100);
      ++counted;
    }
    const Separation sep = ScoreSeparation(rel_scores, irr_scores);
    const double n = std::max<size_t>(1, counted);
    char buf[512];
    std::snprintf(buf, sizeof(buf), "| %s | %zu | %.3f | %.3f | %.3f | %.3f | %.3f | %.1f%% |\n", split.c_str(),
                  counted, ap / n, r1 / n, r5 / n, r10 / n, r100 / n, 100 * sep.kept_relevant);
    md += buf;
    if (no_relevant > 0) {
      std::fprintf(stderr, "%s: %zu queries without relevant database images left out\n", split.c_str(), no_relevant);
    }
  }
  std::printf("Retrieval on %s: %zu database images; vocabulary %s/%s, %u words; preset %s\n\n%s",
              a.dataset.c_str(), db.size(), VocabularyKindName(vocab->kind()).c_str(),
              MetricName(vocab->metric()).c_str(), vocab->size(),
              a.preset.empty() ? "defaults (high accuracy)" : a.preset.c_str(), md.c_str());
  if (!a.markdown.empty()) std::ofstream(a.markdown, std::ios::app) << md << "\n";
}

}  // namespace

void RegisterEvalRetrieval(CLI::App& app) {
  auto a = std::make_shared<EvalArgs>();
  CLI::App* cmd = app.add_subcommand("eval-retrieval", "mAP@1000, Recall@N and score separation on a dataset");
  cmd->add_option("--vocab", a->vocab, "Vocabulary file")->required();
  cmd->add_option("--preset", a->preset, "Retrieval configuration YAML; default: high accuracy");
  cmd->add_option("--dataset", a->dataset, "Dataset with a database split and query splits")->required();
  cmd->add_option("--query-splits", a->query_splits, "Query splits (default: every query* split)")->delimiter(',');
  cmd->add_option("--max-queries", a->max_queries, "At most this many queries per split");
  cmd->add_option("-j,--threads", a->threads, "Threads, 0 = all cores");
  cmd->add_option("--markdown", a->markdown, "Append the table to this Markdown file");
  cmd->add_flag("-q,--quiet", a->quiet, "No progress bars");
  cmd->callback([a]() { RunEval(*a); });
}

}  // namespace tools
}  // namespace gtbow
