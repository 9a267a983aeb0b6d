#include "ground_texture_bow/core/database.h"

#include <algorithm>
#include <cmath>
#include <mutex>
#include <stdexcept>

#include "ground_texture_bow/core/binary_io.h"

namespace gtbow {

namespace {

constexpr char kDatabaseMagic[8] = {'G', 'T', 'B', 'W', 'D', 'B', '\0', '\0'};
constexpr uint32_t kDatabaseVersion = 2;  // 2: packed 8-byte entries
constexpr float kTwoPi = static_cast<float>(2.0 * M_PI);
// Weights d_w * c_d lie in [0, 1] (normalised vectors, shares summing to 1): 16-bit steps.
constexpr float kWeightScale = 65535.0f;
constexpr float kWeightStep = 1.0f / kWeightScale;

// Orientation stored in 8 bits: 256 steps per turn (1.4 degrees).
inline uint8_t QuantizeAngle(float a) {
  int q = static_cast<int>(std::lround(a / kTwoPi * 256.0f));
  return static_cast<uint8_t>(q & 255);
}

inline uint16_t QuantizeWeight(float w) {
  const long q = std::lround(std::clamp(w, 0.0f, 1.0f) * kWeightScale);
  return static_cast<uint16_t>(std::max(1L, q));  // a present keypoint never weighs nothing
}

struct Entry {
  uint32_t image_angle;  // image id << 8 | orientation
  uint16_t keypoint;
  uint16_t weight;       // d_w * c_d, QuantizeWeight
  uint32_t image() const { return image_angle >> 8; }
  uint8_t angle() const { return static_cast<uint8_t>(image_angle & 255); }
};
static_assert(sizeof(Entry) == 8, "entries are 8 bytes");

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
  std::vector<Entry> entries;  // grouped by image (a posting), in insertion order
};

BowDatabase::BowDatabase(uint32_t num_rows, const BowOptions& options, uint64_t fingerprint)
    : num_rows_(num_rows), options_(options), fingerprint_(fingerprint), rows_(num_rows) {
  options_.Check();
  if (num_rows == 0) throw std::invalid_argument("BowDatabase: num_rows must be positive");
}

BowDatabase::~BowDatabase() = default;

uint32_t BowDatabase::Add(const BowVector& v) {
  for (const BowEntry& e : v.entries) {
    if (e.row >= num_rows_) throw std::invalid_argument("BowDatabase::Add: row out of range");
  }
  for (const KeypointEntry& ke : v.keypoints) {
    if (ke.keypoint >= v.angles.size()) {
      throw std::invalid_argument("BowDatabase::Add: keypoint without an orientation");
    }
  }
  std::unique_lock<std::shared_mutex> lock(mutex_);
  if (removed_.size() >= kMaxImages) {
    throw std::length_error("BowDatabase::Add: the index holds at most " +
                            std::to_string(kMaxImages) + " image ids");
  }
  const uint32_t id = static_cast<uint32_t>(removed_.size());
  size_t k = 0;
  for (const BowEntry& e : v.entries) {
    Row& row = rows_[e.row];
    while (k < v.keypoints.size() && v.keypoints[k].row < e.row) ++k;
    while (k < v.keypoints.size() && v.keypoints[k].row == e.row) {
      const KeypointEntry& ke = v.keypoints[k++];
      row.entries.push_back({id << 8 | QuantizeAngle(v.angles[ke.keypoint]), ke.keypoint,
                             QuantizeWeight(e.weight * ke.contribution)});
    }
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
  size_t bytes = rows_.size() * sizeof(Row) + removed_.capacity();
  for (const Row& r : rows_) bytes += r.entries.capacity() * sizeof(Entry);
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
  uint8_t bin_of[256];
  for (int d = 0; d < 256; ++d) bin_of[d] = static_cast<uint8_t>(d * bins / 256);
  // Query keypoint angles, quantised like the database's.
  std::vector<uint8_t> qa(q.angles.size());
  for (size_t i = 0; i < qa.size(); ++i) qa[i] = QuantizeAngle(q.angles[i]);
  // Per query keypoint entry: q_w * c_q in the units of the stored weights.
  std::vector<float> qwc(q.keypoints.size());
  std::vector<uint8_t> qang(q.keypoints.size());

  // Marks an image as scored, so that its accumulator is read and reset afterwards.
  auto Touch = [&s](uint32_t img) {
    if (!s.seen[img]) {
      s.seen[img] = 1;
      s.touched.push_back(img);
    }
  };
  size_t k = 0;
  for (const BowEntry& e : q.entries) {
    if (e.row >= num_rows_) continue;
    while (k < q.keypoints.size() && q.keypoints[k].row < e.row) ++k;
    const size_t kb = k;
    size_t ke = kb;
    while (ke < q.keypoints.size() && q.keypoints[ke].row == e.row) ++ke;
    const std::vector<Entry>& entries = rows_[e.row].entries;
    const Entry* x = entries.data();
    const Entry* end = x + entries.size();
    if (l1) {
      // DBoW2's L1 score needs each posting's d_w: the sum of its entries' weights.
      while (x < end) {
        const uint32_t img = x->image();
        uint32_t w = 0;
        for (; x < end && x->image() == img; ++x) w += x->weight;
        if (removed_[img]) continue;
        Touch(img);
        s.acc[img] += std::min(e.weight, static_cast<float>(w) * kWeightStep);
      }
    } else if (!ov) {
      const float wq = e.weight * kWeightStep;
      for (; x < end; ++x) {
        const uint32_t img = x->image();
        if (removed_[img]) continue;
        Touch(img);
        s.acc[img] += wq * static_cast<float>(x->weight);
      }
    } else {
      for (size_t i = kb; i < ke; ++i) {
        qwc[i] = e.weight * q.keypoints[i].contribution * kWeightStep;
        qang[i] = qa[q.keypoints[i].keypoint];
      }
      for (; x < end; ++x) {
        const uint32_t img = x->image();
        if (removed_[img]) continue;
        Touch(img);
        float* acc = &s.acc[static_cast<size_t>(img) * bins];
        const uint8_t a = x->angle();
        const float w = static_cast<float>(x->weight);
        for (size_t i = kb; i < ke; ++i) {
          acc[bin_of[static_cast<uint8_t>(a - qang[i])]] += qwc[i] * w;
        }
      }
    }
    k = ke;
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
    for (const Entry& x : rows_[e.row].entries) {
      const int32_t sl = slot[x.image()];
      if (sl < 0) continue;
      QueryResult& r = results[sl];
      const float w = e.weight * static_cast<float>(x.weight) * kWeightStep;
      for (size_t i = k; i < ke; ++i) {
        const uint8_t aq = qa[q.keypoints[i].keypoint];
        if (ov && bin_of[static_cast<uint8_t>(x.angle() - aq)] != r.orientation_bin) continue;
        r.matches.push_back({q.keypoints[i].keypoint, x.keypoint, w * q.keypoints[i].contribution});
      }
    }
    k = ke;
  }
  return results;
}

void BowDatabase::Save(const std::filesystem::path& path) const {
  WriteFramedFile(path, kDatabaseMagic, kDatabaseVersion, Serialize());
}

void BowDatabase::Load(const std::filesystem::path& path) {
  const FramedPayload payload = ReadFramedFile(path, kDatabaseMagic, kDatabaseVersion, "database");
  Deserialize(payload.data(), payload.size(), path.string());
}

std::string BowDatabase::Serialize() const {
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
  // Compressed sparse rows: the non-empty rows' indices and sizes, then all entries.
  std::vector<uint32_t> index, count;
  size_t total = 0;
  for (uint32_t i = 0; i < num_rows_; ++i) {
    const size_t c = rows_[i].entries.size();
    if (c == 0) continue;
    index.push_back(i);
    count.push_back(static_cast<uint32_t>(c));
    total += c;
  }
  w.PutVector(index);
  w.PutVector(count);
  w.Put<uint64_t>(total);
  w.buffer().reserve(w.buffer().size() + total * sizeof(Entry));
  for (uint32_t i : index) {
    const auto& e = rows_[i].entries;
    w.buffer().append(reinterpret_cast<const char*>(e.data()), e.size() * sizeof(Entry));
  }
  return std::move(w.buffer());
}

void BowDatabase::Deserialize(const char* data, size_t size, const std::string& source) {
  BinaryReader r(data, size, source);
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
  auto removed = r.GetVector<uint8_t>(kMaxImages);
  const auto index = r.GetVector<uint32_t>(num_rows_);
  const auto count = r.GetVector<uint32_t>(num_rows_);
  const uint64_t total = r.Get<uint64_t>();
  if (count.size() != index.size()) r.Fail("row table is inconsistent");
  uint64_t sum = 0;
  for (size_t n = 0; n < index.size(); ++n) {
    if (index[n] >= num_rows_ || (n > 0 && index[n] <= index[n - 1])) r.Fail("row index out of order");
    if (count[n] == 0) r.Fail("empty row in the row table");
    sum += count[n];
  }
  if (sum != total || total * sizeof(Entry) != r.remaining()) r.Fail("entry count does not match the rows");
  const char* src = data + (size - r.remaining());
  const uint32_t n_images = static_cast<uint32_t>(removed.size());
  std::vector<Row> new_rows(num_rows_);
  for (size_t n = 0; n < index.size(); ++n) {
    auto& e = new_rows[index[n]].entries;
    e.resize(count[n]);
    std::memcpy(e.data(), src, count[n] * sizeof(Entry));
    src += count[n] * sizeof(Entry);
    uint32_t last = 0;
    for (const Entry& x : e) {
      // Postings of a row are in insertion order, so image ids never decrease.
      if (x.image() >= n_images || x.image() < last || x.weight == 0) {
        r.Fail("invalid entry in row " + std::to_string(index[n]));
      }
      last = x.image();
    }
  }
  size_t live = 0;
  for (uint8_t x : removed) live += x ? 0 : 1;
  std::unique_lock<std::shared_mutex> lock(mutex_);
  rows_.swap(new_rows);
  removed_.swap(removed);
  live_ = live;
}

}  // namespace gtbow
