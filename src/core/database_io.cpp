// The inverted index's file form: Save/Load (a memory-mapped file with the entries at an aligned
// offset and a checksum per 64 MB chunk) and Serialize/Deserialize (the same bytes embedded in
// another file, the ROS map).
#include "ground_texture_bow/core/database.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <mutex>
#include <stdexcept>
#include <type_traits>

#include "database_entries.h"
#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/parallel.h"

namespace gtbow {
namespace {

using namespace database_internal;

// Writes the entries of every non-empty row (base, then tail) to `out`.
template <class E, class Out>
void WriteEntries(const PostingIndex<E>& index, Out&& out) {
  for (uint32_t i = 0; i < index.num_rows(); ++i) {
    index.ForEachSegment(i, [&](const E* data, size_t count) { out(data, count * sizeof(E)); });
  }
}

// The index's entries, written in chunks of kChecksumChunk bytes whose checksums are kept.
class ChunkedEntryWriter {
 public:
  explicit ChunkedEntryWriter(AtomicFileWriter* file) : file_(file) {
    buf_.reserve(kChecksumChunk);
  }
  void operator()(const void* data, size_t size) {
    const char* p = Bytes(data);
    while (size > 0) {
      const size_t n = std::min(size, kChecksumChunk - buf_.size());
      buf_.append(p, n);
      p += n;
      size -= n;
      if (buf_.size() == kChecksumChunk) Flush();
    }
  }
  // Writes the last partial chunk; returns the chunk checksums.
  const std::vector<uint64_t>& Finish() {
    if (!buf_.empty()) Flush();
    return sums_;
  }

 private:
  void Flush() {
    sums_.push_back(Checksum64(buf_.data(), buf_.size()));
    file_->Write(buf_.data(), buf_.size());
    buf_.clear();
  }
  AtomicFileWriter* file_;
  std::string buf_;
  std::vector<uint64_t> sums_;
};

// The index header (what Serialize writes before the entries): sizes, options, image flags
// and the table of non-empty rows, each row's entry count given by `count` (all its entries, or
// the frozen ones a map save writes).
template <class E, class Count>
std::string SerializeHeader(const PostingIndex<E>& index, uint32_t num_rows, uint64_t fingerprint,
                            const BowOptions& o, const std::vector<uint8_t>& removed,
                            uint64_t* entries_bytes, Count&& count) {
  BinaryWriter w;
  w.Put<uint32_t>(num_rows);
  w.Put<uint64_t>(fingerprint);
  w.Put<uint8_t>(static_cast<uint8_t>(o.size_binning));
  w.Put<int32_t>(o.num_size_bins);
  w.Put<int32_t>(o.soft_assignment);
  w.Put<double>(o.sigma);
  w.Put<uint8_t>(o.orientation_verification ? 1 : 0);
  w.Put<int32_t>(o.orientation_bins);
  w.Put<uint8_t>(static_cast<uint8_t>(o.scoring));
  w.Put<uint8_t>(o.compact_postings ? 1 : 0);
  w.Put<uint32_t>(sizeof(E));
  w.PutVector(removed);
  // Compressed sparse rows: the non-empty rows' indices and sizes; the entries follow.
  std::vector<uint32_t> rows, counts;
  uint64_t total = 0;
  for (uint32_t i = 0; i < num_rows; ++i) {
    const uint64_t c = count(index, i);
    if (c == 0) continue;
    rows.push_back(i);
    counts.push_back(static_cast<uint32_t>(c));
    total += c;
  }
  w.PutVector(rows);
  w.PutVector(counts);
  w.Put<uint64_t>(total);
  *entries_bytes = total * sizeof(E);
  return std::move(w.buffer());
}

template <class Index>
uint64_t AllEntries(const Index& index, uint32_t row) {
  return index.Frozen(row) + index.tail[row].size();
}

uint64_t Get64(const char* p) {
  uint64_t v;
  std::memcpy(&v, p, 8);
  return v;
}

}  // namespace

std::string BowDatabase::Serialize() const {
  std::string out;
  SerializeTo([&out](uint64_t size) { out.reserve(size); },
              [&out](const void* data, size_t size) { out.append(Bytes(data), size); });
  return out;
}

void BowDatabase::SerializeTo(
    const std::function<void(uint64_t size)>& begin,
    const std::function<void(const void* data, size_t size)>& write) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  uint64_t entries_bytes = 0;
  const std::string header =
      compact_ ? SerializeHeader(*compact_, num_rows_, fingerprint_, options_, removed_,
                                 &entries_bytes, AllEntries<PostingIndex<CompactEntry>>)
               : SerializeHeader(*precise_, num_rows_, fingerprint_, options_, removed_,
                                 &entries_bytes, AllEntries<PostingIndex<PreciseEntry>>);
  const uint64_t hs = header.size();
  begin(8 + hs + entries_bytes);
  write(&hs, 8);
  write(header.data(), header.size());
  if (compact_) {
    WriteEntries(*compact_, write);
  } else {
    WriteEntries(*precise_, write);
  }
}

void BowDatabase::Deserialize(const char* data, size_t size, const std::string& source) {
  if (size < 8) throw std::runtime_error(source + ": database is truncated");
  const uint64_t hs = Get64(data);
  if (hs > size - 8) throw std::runtime_error(source + ": database header is truncated");
  // One owned block for the entries, which the rows then point into.
  const size_t n = size - 8 - hs;
  std::shared_ptr<char> block(new char[std::max<size_t>(n, 1)], std::default_delete<char[]>());
  if (n > 0) std::memcpy(block.get(), data + 8 + hs, n);
  const char* entries = block.get();
  Attach(data + 8, hs, entries, n, std::move(block), source, false);
}

BowDatabase::Frozen BowDatabase::PrepareFreeze() const {
  Frozen f;
  if (compact_) {
    f.spare = std::make_shared<std::vector<std::vector<CompactEntry>>>(num_rows_);
  } else {
    f.spare = std::make_shared<std::vector<std::vector<PreciseEntry>>>(num_rows_);
  }
  return f;
}

void BowDatabase::Freeze(Frozen* f) {
  auto seal = [](auto* index, auto* fresh) {
    if (index->sealed.empty()) {  // two swaps: the tails become the sealed entries
      index->sealed.swap(index->tail);
      index->tail.swap(*fresh);
    } else {  // an earlier save failed before Rebase: its sealed entries stay sealed
      for (uint32_t r = 0; r < index->num_rows(); ++r) {
        auto& t = index->tail[r];
        index->sealed[r].insert(index->sealed[r].end(), t.begin(), t.end());
        t.clear();
      }
    }
  };
  std::unique_lock<std::shared_mutex> lock(mutex_);
  if (compact_) {
    seal(compact_.get(), static_cast<std::vector<std::vector<CompactEntry>>*>(f->spare.get()));
  } else {
    seal(precise_.get(), static_cast<std::vector<std::vector<PreciseEntry>>*>(f->spare.get()));
  }
  f->removed = removed_;
  f->images = static_cast<uint32_t>(removed_.size());
  lock.unlock();
  f->spare.reset();  // the swapped-out empty array (or the unused spare) freed without the lock
}

void BowDatabase::DescribeFrozen(Frozen* f) const {
  // Without the lock: base and sealed entries change only in Rebase, which this saver calls.
  auto frozen = [](const auto& index, uint32_t row) -> uint64_t { return index.Frozen(row); };
  f->header = compact_ ? SerializeHeader(*compact_, num_rows_, fingerprint_, options_, f->removed,
                                         &f->entries_bytes, frozen)
                       : SerializeHeader(*precise_, num_rows_, fingerprint_, options_, f->removed,
                                         &f->entries_bytes, frozen);
}

void BowDatabase::WriteFrozen(
    const std::function<void(const void* data, size_t size)>& write) const {
  auto all = [&](const auto& index) {
    for (uint32_t i = 0; i < index.num_rows(); ++i) {
      index.ForEachFrozenSegment(
          i, [&](const auto* data, size_t count) { write(data, count * sizeof(*data)); });
    }
  };
  if (compact_) {
    all(*compact_);
  } else {
    all(*precise_);
  }
}

double BowDatabase::Rebase(const Frozen& frozen, const char* entries,
                           std::shared_ptr<const void> keep_alive,
                           std::shared_ptr<void>* replaced) {
  double held = 0;
  auto rebase = [&](auto* index) {
    using Index = std::remove_reference_t<decltype(*index)>;
    using E = typename Index::Entry;
    // The new base array is made without the lock: the frozen entries do not change.
    std::vector<typename Index::Base> fresh(index->num_rows());
    const char* p = entries;
    for (uint32_t r = 0; r < index->num_rows(); ++r) {
      const size_t n = index->Frozen(r);
      if (n == 0) continue;
      fresh[r] = {reinterpret_cast<const E*>(p), n};
      p += n * sizeof(E);
    }
    if (static_cast<uint64_t>(p - entries) != frozen.entries_bytes) {
      throw std::logic_error("BowDatabase::Rebase: the index changed since Freeze");
    }
    struct Replaced {
      std::vector<typename Index::Base> base;
      std::vector<std::vector<E>> sealed;
      std::shared_ptr<const void> keep_alive;
    };
    auto old = std::make_shared<Replaced>();
    old->base = std::move(fresh);
    old->keep_alive = std::move(keep_alive);
    std::unique_lock<std::shared_mutex> lock(mutex_);
    const auto t0 = std::chrono::steady_clock::now();
    index->base.swap(old->base);
    index->sealed.swap(old->sealed);
    index->keep_alive.swap(old->keep_alive);
    index->base_bytes = frozen.entries_bytes;
    index->base_mapped = true;
    held = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    lock.unlock();
    // The heap copies, the old base array and the old mapping: freed without the lock, here or
    // by the caller.
    if (replaced != nullptr) *replaced = std::move(old);
  };
  if (compact_) {
    rebase(compact_.get());
  } else {
    rebase(precise_.get());
  }
  return held;
}

void BowDatabase::AttachMapped(const char* header, size_t header_size, const char* entries,
                               size_t entries_size, std::shared_ptr<const void> keep_alive,
                               const std::string& source) {
  Attach(header, header_size, entries, entries_size, std::move(keep_alive), source, true);
}

void BowDatabase::Save(const std::filesystem::path& path) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  uint64_t entries_bytes = 0;
  const uint32_t entry_size = compact_ ? sizeof(CompactEntry) : sizeof(PreciseEntry);
  const std::string header =
      compact_ ? SerializeHeader(*compact_, num_rows_, fingerprint_, options_, removed_,
                                 &entries_bytes, AllEntries<PostingIndex<CompactEntry>>)
               : SerializeHeader(*precise_, num_rows_, fingerprint_, options_, removed_,
                                 &entries_bytes, AllEntries<PostingIndex<PreciseEntry>>);
  std::string head(kFixedHeader, '\0');
  std::memcpy(&head[0], kDatabaseMagic, 8);
  std::memcpy(&head[8], &kDatabaseVersion, 4);
  std::memcpy(&head[12], &entry_size, 4);
  const uint64_t hs = header.size();
  std::memcpy(&head[16], &hs, 8);
  std::memcpy(&head[24], &entries_bytes, 8);
  head += header;
  const uint64_t head_sum = Checksum64(head.data(), head.size());
  head.append(reinterpret_cast<const char*>(&head_sum), 8);
  head.resize((head.size() + kEntriesAlignment - 1) / kEntriesAlignment * kEntriesAlignment, '\0');

  AtomicFileWriter file(path);
  file.Write(head);
  ChunkedEntryWriter chunks(&file);
  if (compact_) {
    WriteEntries(*compact_, chunks);
  } else {
    WriteEntries(*precise_, chunks);
  }
  const std::vector<uint64_t>& sums = chunks.Finish();
  file.Write(sums.data(), sums.size() * 8);
  const uint64_t table_sum = Checksum64(sums.data(), sums.size() * 8);
  file.Write(&table_sum, 8);
  file.Commit();
}

void BowDatabase::Load(const std::filesystem::path& path, int threads) {
  const std::string src = path.string();
  const auto map = MappedFile::Open(path);
  const char* d = map->data();
  const size_t size = map->size();
  auto fail = [&src](const std::string& what) { throw std::runtime_error(src + ": " + what); };
  if (size < kFixedHeader + 8)
    fail("not a database file (too short: " + std::to_string(size) + " bytes)");
  if (std::memcmp(d, kDatabaseMagic, 8) != 0) fail("not a database file (wrong magic number)");
  uint32_t version, entry_size;
  std::memcpy(&version, d + 8, 4);
  std::memcpy(&entry_size, d + 12, 4);
  if (version != kDatabaseVersion) {
    fail("database format version " + std::to_string(version) +
         " is not supported (this build reads version " + std::to_string(kDatabaseVersion) + ")");
  }
  const uint64_t hs = Get64(d + 16);
  const uint64_t entries_bytes = Get64(d + 24);
  if (hs > size - kFixedHeader - 8) fail("database file is truncated (header)");
  if (Checksum64(d, kFixedHeader + hs) != Get64(d + kFixedHeader + hs)) {
    fail("database file is corrupt (header checksum mismatch)");
  }
  const uint64_t at =
      (kFixedHeader + hs + 8 + kEntriesAlignment - 1) / kEntriesAlignment * kEntriesAlignment;
  const uint64_t n_chunks = (entries_bytes + kChecksumChunk - 1) / kChecksumChunk;
  if (entries_bytes > size || at > size - entries_bytes ||
      size - at - entries_bytes != n_chunks * 8 + 8) {
    fail("database file is truncated or has trailing bytes");
  }
  const char* table = d + at + entries_bytes;
  if (Checksum64(table, n_chunks * 8) != Get64(table + n_chunks * 8)) {
    fail("database file is corrupt (checksum table mismatch)");
  }
  // Every chunk of entries against its checksum, chunks shared among threads.
  const size_t n_threads = std::max<size_t>(1, std::min<size_t>(ThreadCount(threads), n_chunks));
  std::vector<uint64_t> bad(n_threads, UINT64_MAX);
  RunTasks(static_cast<int>(n_threads), [&](int t) {
    for (uint64_t c = static_cast<uint64_t>(t); c < n_chunks; c += n_threads) {
      const uint64_t off = c * kChecksumChunk;
      const size_t len = std::min<uint64_t>(kChecksumChunk, entries_bytes - off);
      if (Checksum64(d + at + off, len) != Get64(table + c * 8)) {
        bad[static_cast<size_t>(t)] = c;
        return;
      }
    }
  });
  for (uint64_t c : bad) {
    if (c != UINT64_MAX) {
      fail("database file is corrupt (checksum mismatch in entries at byte " +
           std::to_string(at + c * kChecksumChunk) + ")");
    }
  }
  if (entry_size != (options_.compact_postings ? sizeof(CompactEntry) : sizeof(PreciseEntry))) {
    fail("database has " + std::to_string(entry_size) + "-byte entries; these BoW options use " +
         (options_.compact_postings ? "compact 6-byte" : "precise 8-byte") + " entries");
  }
  Attach(d + kFixedHeader, hs, d + at, entries_bytes, map, src, true);
}

void BowDatabase::Attach(const char* header, size_t header_size, const char* entries,
                         size_t entries_size, std::shared_ptr<const void> keep_alive,
                         const std::string& source, bool mapped) {
  BinaryReader r(header, header_size, source);
  const uint32_t rows = r.Get<uint32_t>();
  const uint64_t fp = r.Get<uint64_t>();
  if (fp != fingerprint_) r.Fail("database was built with a different vocabulary");
  if (rows != num_rows_) {
    r.Fail("database has " + std::to_string(rows) +
           " rows, this vocabulary and size binning give " + std::to_string(num_rows_));
  }
  BowOptions o;
  o.size_binning = static_cast<SizeBinning>(r.Get<uint8_t>());
  o.num_size_bins = r.Get<int32_t>();
  o.soft_assignment = r.Get<int32_t>();
  o.sigma = r.Get<double>();
  o.orientation_verification = r.Get<uint8_t>() != 0;
  o.orientation_bins = r.Get<int32_t>();
  o.scoring = static_cast<Scoring>(r.Get<uint8_t>());
  o.compact_postings = r.Get<uint8_t>() != 0;
  const uint32_t entry_size = r.Get<uint32_t>();
  if (o.size_binning != options_.size_binning || o.num_size_bins != options_.num_size_bins ||
      o.soft_assignment != options_.soft_assignment || o.sigma != options_.sigma ||
      o.orientation_verification != options_.orientation_verification ||
      o.orientation_bins != options_.orientation_bins || o.scoring != options_.scoring ||
      o.compact_postings != options_.compact_postings) {
    r.Fail("database was built with different BoW options");
  }
  const size_t want_entry = options_.compact_postings ? sizeof(CompactEntry) : sizeof(PreciseEntry);
  if (entry_size != want_entry) r.Fail("entry size does not match the options");
  auto removed = r.GetVector<uint8_t>(kMaxImages);
  const auto index = r.GetVector<uint32_t>(num_rows_);
  const auto count = r.GetVector<uint32_t>(num_rows_);
  const uint64_t total = r.Get<uint64_t>();
  if (r.remaining() != 0) r.Fail("trailing bytes after the row table");
  if (count.size() != index.size()) r.Fail("row table is inconsistent");
  uint64_t sum = 0;
  for (size_t n = 0; n < index.size(); ++n) {
    if (index[n] >= num_rows_ || (n > 0 && index[n] <= index[n - 1]))
      r.Fail("row index out of order");
    if (count[n] == 0) r.Fail("empty row in the row table");
    sum += count[n];
  }
  if (sum != total || total * entry_size != entries_size)
    r.Fail("entry count does not match the rows");
  // Rows point into the entries block; an entry's image id is checked where it is read (a
  // query only visits ids below the image count), so the block is not scanned here.
  auto attach = [&](auto* fresh) {
    using E = typename std::remove_reference_t<decltype(*fresh)>::Entry;
    const char* p = entries;
    for (size_t n = 0; n < index.size(); ++n) {
      fresh->base[index[n]] = {reinterpret_cast<const E*>(p), count[n]};
      p += static_cast<size_t>(count[n]) * sizeof(E);
    }
    fresh->keep_alive = keep_alive;
    fresh->base_bytes = entries_size;
    fresh->base_mapped = mapped;
  };
  std::unique_ptr<PostingIndex<CompactEntry>> c;
  std::unique_ptr<PostingIndex<PreciseEntry>> pr;
  if (options_.compact_postings) {
    c = std::make_unique<PostingIndex<CompactEntry>>(num_rows_);
    attach(c.get());
  } else {
    pr = std::make_unique<PostingIndex<PreciseEntry>>(num_rows_);
    attach(pr.get());
  }
  size_t live = 0;
  for (uint8_t x : removed) live += x ? 0 : 1;
  std::unique_lock<std::shared_mutex> lock(mutex_);
  compact_.swap(c);
  precise_.swap(pr);
  removed_.swap(removed);
  live_ = live;
}

}  // namespace gtbow
