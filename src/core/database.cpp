#include "ground_texture_bow/core/database.h"

#include <algorithm>
#include <cmath>
#include <mutex>
#include <stdexcept>

#include "ground_texture_bow/core/binary_io.h"

namespace gtbow {

namespace {

constexpr char kDatabaseMagic[8] = {'G', 'T', 'B', 'W', 'D', 'B', '\0', '\0'};
constexpr uint32_t kDatabaseVersion = 1;
constexpr float kTwoPi = static_cast<float>(2.0 * M_PI);

// Orientation stored in 8 bits: 256 steps per turn (1.4 degrees).
inline uint8_t QuantizeAngle(float a) {
  int q = static_cast<int>(std::lround(a / kTwoPi * 256.0f));
  return static_cast<uint8_t>(q & 255);
}

struct Posting {
  uint32_t image;
  float weight;     // d_w
  uint32_t kp_end;  // keypoints [previous kp_end, kp_end) of the row's keypoint array
};

struct PostedKeypoint {
  uint16_t keypoint;
  uint8_t angle;     // QuantizeAngle
  uint8_t reserved;
  float contribution;  // c_d
};

// Per-thread scratch for queries: a dense accumulator over images x bins.
struct Scratch {
  std::vector<float> acc;
  std::vector<uint32_t> touched;
  std::vector<uint8_t> seen;
};

Scratch& ThreadScratch() {
  thread_local Scratch s;
  return s;
}

}  // namespace

struct BowDatabase::Row {
  std::vector<Posting> postings;
  std::vector<PostedKeypoint> keypoints;
};

BowDatabase::BowDatabase(uint32_t num_rows, const BowOptions& options, uint64_t fingerprint)
    : num_rows_(num_rows), options_(options), fingerprint_(fingerprint), rows_(num_rows) {
  options_.Check();
  if (num_rows == 0) throw std::invalid_argument("BowDatabase: num_rows must be positive");
}

BowDatabase::~BowDatabase() = default;

uint32_t BowDatabase::Add(const BowVector& v) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  const uint32_t id = static_cast<uint32_t>(removed_.size());
  size_t k = 0;
  for (const BowEntry& e : v.entries) {
    if (e.row >= num_rows_) throw std::invalid_argument("BowDatabase::Add: row out of range");
    Row& row = rows_[e.row];
    while (k < v.keypoints.size() && v.keypoints[k].row < e.row) ++k;
    while (k < v.keypoints.size() && v.keypoints[k].row == e.row) {
      const KeypointEntry& ke = v.keypoints[k++];
      row.keypoints.push_back({ke.keypoint, QuantizeAngle(v.angles.at(ke.keypoint)), 0,
                               ke.contribution});
    }
    row.postings.push_back({id, e.weight, static_cast<uint32_t>(row.keypoints.size())});
  }
  removed_.push_back(0);
  ++live_;
  return id;
}

bool BowDatabase::Remove(uint32_t image) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  if (image >= removed_.size() || removed_[image]) return false;
  removed_[image] = 1;
  --live_;
  return true;
}

size_t BowDatabase::size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return live_;
}

uint32_t BowDatabase::next_id() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return static_cast<uint32_t>(removed_.size());
}

size_t BowDatabase::MemoryBytes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  size_t bytes = rows_.size() * sizeof(Row) + removed_.size();
  for (const Row& r : rows_) {
    bytes += r.postings.capacity() * sizeof(Posting) + r.keypoints.capacity() * sizeof(PostedKeypoint);
  }
  return bytes;
}

std::vector<QueryResult> BowDatabase::Query(const BowVector& q, size_t top_n,
                                            bool with_matches) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const bool ov = options_.orientation_verification;
  const int bins = ov ? options_.orientation_bins : 1;
  const bool l1 = options_.scoring == Scoring::kDbowL1;
  const size_t n_images = removed_.size();
  Scratch& s = ThreadScratch();
  if (s.acc.size() < n_images * bins) s.acc.resize(n_images * bins, 0.0f);
  if (s.seen.size() < n_images) s.seen.resize(n_images, 0);
  s.touched.clear();
  // Orientation bin of a difference: 256 angle steps map onto `bins` bins.
  int bin_of[256];
  for (int d = 0; d < 256; ++d) bin_of[d] = d * bins / 256;
  // Query keypoint angles, quantised like the database's.
  std::vector<uint8_t> qa(q.angles.size());
  for (size_t i = 0; i < qa.size(); ++i) qa[i] = QuantizeAngle(q.angles[i]);

  size_t k = 0;
  for (const BowEntry& e : q.entries) {
    if (e.row >= num_rows_) continue;
    const size_t kb = (k = std::lower_bound(q.keypoints.begin() + k, q.keypoints.end(), e.row,
                                            [](const KeypointEntry& x, uint32_t r) { return x.row < r; }) -
                           q.keypoints.begin());
    size_t ke = kb;
    while (ke < q.keypoints.size() && q.keypoints[ke].row == e.row) ++ke;
    const Row& row = rows_[e.row];
    uint32_t kp_begin = 0;
    for (const Posting& p : row.postings) {
      const uint32_t kp_end = p.kp_end;
      if (!removed_[p.image]) {
        if (!s.seen[p.image]) {
          s.seen[p.image] = 1;
          s.touched.push_back(p.image);
        }
        float* acc = &s.acc[static_cast<size_t>(p.image) * bins];
        if (l1) {
          acc[0] += std::min(e.weight, p.weight);
        } else if (!ov) {
          acc[0] += e.weight * p.weight;
        } else {
          const float w = e.weight * p.weight;
          for (size_t i = kb; i < ke; ++i) {
            const float wq = w * q.keypoints[i].contribution;
            const uint8_t aq = qa[q.keypoints[i].keypoint];
            for (uint32_t j = kp_begin; j < kp_end; ++j) {
              const PostedKeypoint& dk = row.keypoints[j];
              acc[bin_of[static_cast<uint8_t>(dk.angle - aq)]] += wq * dk.contribution;
            }
          }
        }
      }
      kp_begin = kp_end;
    }
  }
  // Scores: the best bin of each touched image.
  std::vector<QueryResult> results;
  results.reserve(s.touched.size());
  for (uint32_t img : s.touched) {
    float* acc = &s.acc[static_cast<size_t>(img) * bins];
    int best = 0;
    for (int b = 1; b < bins; ++b) best = acc[b] > acc[best] ? b : best;
    QueryResult r;
    r.image = img;
    r.score = acc[best];
    r.orientation_bin = ov ? best : -1;
    results.push_back(std::move(r));
    std::fill(acc, acc + bins, 0.0f);
    s.seen[img] = 0;
  }
  const size_t n = std::min(top_n, results.size());
  std::partial_sort(results.begin(), results.begin() + n, results.end(),
                    [](const QueryResult& a, const QueryResult& b) {
                      return a.score != b.score ? a.score > b.score : a.image < b.image;
                    });
  results.resize(n);
  if (!with_matches || n == 0) return results;

  // Second pass, restricted to the results: the keypoint pairs of each winning bin.
  std::vector<int32_t> slot(n_images, -1);
  for (size_t i = 0; i < n; ++i) slot[results[i].image] = static_cast<int32_t>(i);
  k = 0;
  for (const BowEntry& e : q.entries) {
    if (e.row >= num_rows_) continue;
    while (k < q.keypoints.size() && q.keypoints[k].row < e.row) ++k;
    size_t ke = k;
    while (ke < q.keypoints.size() && q.keypoints[ke].row == e.row) ++ke;
    const Row& row = rows_[e.row];
    uint32_t kp_begin = 0;
    for (const Posting& p : row.postings) {
      const int32_t sl = slot[p.image];
      if (sl >= 0) {
        QueryResult& r = results[sl];
        const float w = e.weight * p.weight;
        for (size_t i = k; i < ke; ++i) {
          const uint8_t aq = qa[q.keypoints[i].keypoint];
          for (uint32_t j = kp_begin; j < p.kp_end; ++j) {
            const PostedKeypoint& dk = row.keypoints[j];
            if (ov && bin_of[static_cast<uint8_t>(dk.angle - aq)] != r.orientation_bin) continue;
            r.matches.push_back({q.keypoints[i].keypoint, dk.keypoint,
                                 w * q.keypoints[i].contribution * dk.contribution});
          }
        }
      }
      kp_begin = p.kp_end;
    }
  }
  return results;
}

void BowDatabase::Save(const std::filesystem::path& path) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  BinaryWriter w;
  w.Put<uint32_t>(num_rows_);
  w.Put<uint64_t>(fingerprint_);
  w.Put<uint8_t>(static_cast<uint8_t>(options_.size_binning));
  w.Put<int32_t>(options_.num_size_bins);
  w.Put<int32_t>(options_.soft_assignment);
  w.Put<double>(options_.sigma);
  w.Put<uint8_t>(options_.orientation_verification ? 1 : 0);
  w.Put<int32_t>(options_.orientation_bins);
  w.Put<uint8_t>(static_cast<uint8_t>(options_.scoring));
  w.PutVector(removed_);
  uint32_t nonempty = 0;
  for (const Row& r : rows_) nonempty += r.postings.empty() ? 0 : 1;
  w.Put<uint32_t>(nonempty);
  for (uint32_t i = 0; i < num_rows_; ++i) {
    const Row& r = rows_[i];
    if (r.postings.empty()) continue;
    w.Put<uint32_t>(i);
    w.PutVector(r.postings);
    w.PutVector(r.keypoints);
  }
  WriteFramedFile(path, kDatabaseMagic, kDatabaseVersion, w.buffer());
}

void BowDatabase::Load(const std::filesystem::path& path) {
  const std::string payload = ReadFramedFile(path, kDatabaseMagic, kDatabaseVersion, "database");
  BinaryReader r(payload.data(), payload.size(), path.string());
  const uint32_t rows = r.Get<uint32_t>();
  const uint64_t fp = r.Get<uint64_t>();
  if (fp != fingerprint_) r.Fail("database was built with a different vocabulary");
  if (rows != num_rows_) {
    r.Fail("database has " + std::to_string(rows) + " rows, this vocabulary and size binning give " +
           std::to_string(num_rows_));
  }
  BowOptions o;
  o.size_binning = static_cast<SizeBinning>(r.Get<uint8_t>());
  o.num_size_bins = r.Get<int32_t>();
  o.soft_assignment = r.Get<int32_t>();
  o.sigma = r.Get<double>();
  o.orientation_verification = r.Get<uint8_t>() != 0;
  o.orientation_bins = r.Get<int32_t>();
  o.scoring = static_cast<Scoring>(r.Get<uint8_t>());
  if (o.size_binning != options_.size_binning || o.num_size_bins != options_.num_size_bins ||
      o.soft_assignment != options_.soft_assignment || o.sigma != options_.sigma ||
      o.orientation_verification != options_.orientation_verification ||
      o.orientation_bins != options_.orientation_bins || o.scoring != options_.scoring) {
    r.Fail("database was built with different BoW options");
  }
  auto removed = r.GetVector<uint8_t>(1u << 31);
  std::vector<Row> new_rows(num_rows_);
  const uint32_t nonempty = r.Get<uint32_t>();
  if (nonempty > num_rows_) r.Fail("row count out of range");
  uint32_t prev = 0;
  for (uint32_t n = 0; n < nonempty; ++n) {
    const uint32_t i = r.Get<uint32_t>();
    if (i >= num_rows_ || (n > 0 && i <= prev)) r.Fail("row index out of order");
    prev = i;
    Row& row = new_rows[i];
    row.postings = r.GetVector<Posting>(removed.size());
    row.keypoints = r.GetVector<PostedKeypoint>(removed.size() * 65536ull);
    uint32_t last = 0;
    for (const Posting& p : row.postings) {
      if (p.image >= removed.size() || p.kp_end < last || p.kp_end > row.keypoints.size()) {
        r.Fail("invalid posting in row " + std::to_string(i));
      }
      last = p.kp_end;
    }
  }
  if (r.remaining() != 0) r.Fail("unexpected trailing data");
  size_t live = 0;
  for (uint8_t x : removed) live += x ? 0 : 1;
  std::unique_lock<std::shared_mutex> lock(mutex_);
  rows_.swap(new_rows);
  removed_.swap(removed);
  live_ = live;
}

}  // namespace gtbow
