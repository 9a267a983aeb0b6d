// HKM vocabularies: a DBoW2-style tree of k-means levels, its training and its file form.
#include "ground_texture_bow/core/progress.h"
#include "vocabulary_internal.h"

namespace gtbow {
namespace vocabulary_internal {

// ---------------------------------------------------------------------------------------------
// HKM: a DBoW2-style vocabulary tree (Nister & Stewenius 2006; Galvez-Lopez & Tardos 2012).

template <typename Space>
class HkmVocabulary : public Vocabulary {
 public:
  using E = typename Space::Element;
  struct Node {
    int32_t first_child = -1;  // index of the first child in nodes_, -1 for a leaf
    int32_t num_children = 0;
    int32_t word = -1;  // word id of a leaf
  };

  HkmVocabulary(Metric metric, std::vector<Node> nodes, cv::Mat centroids)
      : metric_(metric), nodes_(std::move(nodes)), centroids_(std::move(centroids)) {
    num_words_ = 0;
    for (const auto& n : nodes_) num_words_ += n.word >= 0 ? 1 : 0;
    fingerprint_ = Checksum64(centroids_.data, centroids_.total() * centroids_.elemSize()) ^
                   Checksum64(nodes_.data(), nodes_.size() * sizeof(Node));
  }

  VocabularyKind kind() const override { return VocabularyKind::kHkm; }
  Metric metric() const override { return metric_; }
  uint32_t size() const override { return num_words_; }
  int max_neighbours() const override { return 1; }

  void AssignExact(const cv::Mat& descriptors, std::vector<WordHit>* out) const override {
    Assign(descriptors, 1, out);  // the tree defines the words: descent is exact
  }

  void Assign(const cv::Mat& descriptors, int r, std::vector<WordHit>* out) const override {
    if (r != 1)
      throw std::invalid_argument("an HKM vocabulary assigns one word per descriptor (r = 1)");
    const cv::Mat q = ToSpace(descriptors, metric_);
    out->assign(static_cast<size_t>(q.rows), WordHit{});
    if (q.rows > 0 && q.cols != centroids_.cols) {
      throw std::invalid_argument("Assign: descriptor length does not match the vocabulary");
    }
    for (int i = 0; i < q.rows; ++i) {
      const E* x = q.ptr<E>(i);
      int32_t node = 0;
      float best = 0.0f;
      while (nodes_[node].first_child >= 0) {
        const Node& n = nodes_[node];
        best = std::numeric_limits<float>::max();
        const int c = Space::Nearest(x, centroids_.ptr<E>(n.first_child), centroids_.step[0],
                                     n.num_children, q.cols, &best);
        node = n.first_child + std::max(c, 0);
      }
      (*out)[i] = {static_cast<uint32_t>(nodes_[node].word), best};
    }
  }

 protected:
  void SaveWords(BinaryWriter* w) const override {
    w->PutVector(nodes_);
    w->Put<int32_t>(centroids_.rows);
    w->Put<int32_t>(centroids_.cols);
    w->PutArray(centroids_.ptr<E>(), centroids_.total());
  }

 private:
  Metric metric_;
  std::vector<Node> nodes_;  // node 0 is the root; children are contiguous
  cv::Mat centroids_;        // one row per node (the root's row is unused)
  uint32_t num_words_;
};

// k-means++ seeding then Lloyd iterations on the rows `members` of `data`; returns the k
// centroids and each member's cluster.
template <typename Space>
void KMeansPP(const cv::Mat& data, const std::vector<int>& members, int k, std::mt19937_64& rng,
              cv::Mat* centers, std::vector<int>* assign) {
  using E = typename Space::Element;
  const int d = data.cols;
  const int n = static_cast<int>(members.size());
  SeedPlusPlus<Space>(data, members, k, rng, centers);
  assign->assign(n, 0);
  cv::Mat sub(n, d, data.type());
  for (int i = 0; i < n; ++i) data.row(members[i]).copyTo(sub.row(i));
  for (int it = 0; it < 10; ++it) {
    bool changed = false;
    for (int i = 0; i < n; ++i) {
      float best = std::numeric_limits<float>::max();
      const int arg = std::max(
          Space::Nearest(sub.ptr<E>(i), centers->ptr<E>(), centers->step[0], k, d, &best), 0);
      if ((*assign)[i] != arg || it == 0) changed = changed || (*assign)[i] != arg;
      (*assign)[i] = arg;
    }
    std::vector<uint32_t> label(assign->begin(), assign->end());
    UpdateCentroids(sub, label, centers, rng, 1);
    if (!changed && it > 0) break;
  }
}

template <typename Space>
std::unique_ptr<Vocabulary> TrainHkmIn(const VocabularyOptions& o, const cv::Mat& data,
                                       bool progress) {
  using Node = typename HkmVocabulary<Space>::Node;
  const int k = o.hkm_branching;
  std::mt19937_64 rng(o.seed);
  std::vector<Node> nodes(1);
  std::vector<cv::Mat> rows(1, cv::Mat::zeros(1, data.cols, data.type()));
  // Breadth-first: (node, depth, members).
  struct Task {
    int node;
    int depth;
    std::vector<int> members;
  };
  std::vector<Task> queue;
  std::vector<int> all(data.rows);
  std::iota(all.begin(), all.end(), 0);
  queue.push_back({0, 0, std::move(all)});
  int32_t words = 0;
  ProgressBar bar("hkm levels", static_cast<size_t>(o.hkm_depth), progress);
  int last_depth = 0;
  for (size_t qi = 0; qi < queue.size(); ++qi) {
    Task task = std::move(queue[qi]);
    if (task.depth > last_depth) {
      bar.Add(task.depth - last_depth);
      last_depth = task.depth;
    }
    const int n = static_cast<int>(task.members.size());
    cv::Mat centers;
    std::vector<int> assign;
    int kk;
    if (n <= k) {
      // Too few descriptors to split: each becomes its own child (DBoW2 does the same).
      kk = n;
      centers.create(n, data.cols, data.type());
      for (int i = 0; i < n; ++i) data.row(task.members[i]).copyTo(centers.row(i));
      assign.resize(n);
      std::iota(assign.begin(), assign.end(), 0);
    } else {
      kk = k;
      KMeansPP<Space>(data, task.members, k, rng, &centers, &assign);
    }
    const int first = static_cast<int>(nodes.size());
    nodes[task.node].first_child = first;
    nodes[task.node].num_children = kk;
    std::vector<std::vector<int>> child_members(kk);
    for (int i = 0; i < n; ++i) child_members[assign[i]].push_back(task.members[i]);
    for (int c = 0; c < kk; ++c) {
      nodes.push_back(Node{});
      rows.push_back(centers.row(c).clone());
    }
    for (int c = 0; c < kk; ++c) {
      const int id = first + c;
      const bool leaf = task.depth + 1 >= o.hkm_depth || child_members[c].size() <= 1;
      if (leaf) {
        nodes[id].word = words++;
      } else {
        queue.push_back({id, task.depth + 1, std::move(child_members[c])});
      }
    }
    task.members.clear();
    task.members.shrink_to_fit();
  }
  bar.Finish();
  cv::Mat centroids;
  cv::vconcat(rows, centroids);
  return std::make_unique<HkmVocabulary<Space>>(o.metric, std::move(nodes), std::move(centroids));
}

std::unique_ptr<Vocabulary> TrainHkm(const VocabularyOptions& o, const cv::Mat& data,
                                     bool progress) {
  return o.metric == Metric::kHamming ? TrainHkmIn<BinarySpace>(o, data, progress)
                                      : TrainHkmIn<FloatSpace>(o, data, progress);
}

template <typename Space>
std::unique_ptr<Vocabulary> ReadHkmIn(BinaryReader* r, Metric metric) {
  using V = HkmVocabulary<Space>;
  auto nodes = r->GetVector<typename V::Node>(kMaxWords * 2);
  const int32_t rows = r->Get<int32_t>(), cols = r->Get<int32_t>();
  auto v = r->GetVector<typename Space::Element>(kMaxWords * 256);
  if (rows < 1 || cols < 1 || v.size() != static_cast<size_t>(rows) * cols ||
      nodes.size() != static_cast<size_t>(rows)) {
    r->Fail("invalid HKM tree");
  }
  // Children come after their parent (so a descent ends), every leaf has a word, the words
  // are 0..W-1 once each (they index the idf table), inner nodes have none.
  std::vector<uint8_t> seen(nodes.size(), 0);
  size_t leaves = 0;
  for (size_t i = 0; i < nodes.size(); ++i) {
    const auto& n = nodes[i];
    if (n.first_child >= 0) {
      if (n.num_children < 1 || static_cast<size_t>(n.first_child) <= i ||
          static_cast<int64_t>(n.first_child) + n.num_children > rows || n.word >= 0) {
        r->Fail("invalid HKM tree node " + std::to_string(i));
      }
      continue;
    }
    if (n.word < 0 || static_cast<size_t>(n.word) >= nodes.size() || seen[n.word]++) {
      r->Fail("HKM leaf " + std::to_string(i) + " has an invalid or repeated word id");
    }
    ++leaves;
  }
  for (size_t w = 0; w < leaves; ++w) {
    if (!seen[w]) r->Fail("HKM word ids are not 0.." + std::to_string(leaves - 1));
  }
  cv::Mat c(rows, cols, metric == Metric::kHamming ? CV_8U : CV_32F, v.data());
  return std::make_unique<V>(metric, std::move(nodes), c.clone());
}

std::unique_ptr<Vocabulary> ReadHkm(BinaryReader* r, Metric metric) {
  return metric == Metric::kHamming ? ReadHkmIn<BinarySpace>(r, metric)
                                    : ReadHkmIn<FloatSpace>(r, metric);
}

}  // namespace vocabulary_internal
}  // namespace gtbow
