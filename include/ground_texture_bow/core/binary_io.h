// Binary file framing shared by the vocabulary and database files: a magic number, a format
// version, the payload, and a 64-bit checksum of the payload. Files are written atomically
// (file_util.h); readers check every length against the bytes present, so a truncated or
// corrupt file gives a clear error instead of a crash or a silent wrong answer.
#pragma once

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <initializer_list>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

namespace gtbow {

// Fast 64-bit checksum over a byte range (word-wise multiply-xor; not cryptographic).
uint64_t Checksum64(const void* data, size_t size);

// Checksum64 of bytes given in pieces of any sizes whose total is known up front (it seeds
// the checksum): Add() the pieces in order, then Finish() equals Checksum64 of their
// concatenation.
class Checksum64Builder {
 public:
  explicit Checksum64Builder(uint64_t total_size);
  void Add(const void* data, size_t size);
  uint64_t Finish();

 private:
  uint64_t h_;
  unsigned char word_[8];
  size_t partial_ = 0;  // bytes in word_
};

// Appends plain values and arrays to a byte buffer.
class BinaryWriter {
 public:
  template <typename T>
  void Put(const T& v) {
    static_assert(std::is_trivially_copyable<T>::value, "POD only");
    const size_t at = buf_.size();
    buf_.resize(at + sizeof(T));
    std::memcpy(&buf_[at], &v, sizeof(T));
  }
  template <typename T>
  void PutArray(const T* data, size_t count) {
    static_assert(std::is_trivially_copyable<T>::value, "POD only");
    Put<uint64_t>(count);
    const size_t at = buf_.size();
    buf_.resize(at + count * sizeof(T));
    if (count > 0) std::memcpy(&buf_[at], data, count * sizeof(T));
  }
  template <typename T>
  void PutVector(const std::vector<T>& v) {
    PutArray(v.data(), v.size());
  }
  void PutString(const std::string& s) { PutArray(s.data(), s.size()); }
  std::string& buffer() { return buf_; }

 private:
  std::string buf_;
};

// Reads values back with bounds checks; errors name `source`.
class BinaryReader {
 public:
  BinaryReader(const char* data, size_t size, std::string source)
      : data_(data), size_(size), source_(std::move(source)) {}
  template <typename T>
  T Get() {
    static_assert(std::is_trivially_copyable<T>::value, "POD only");
    Need(sizeof(T));
    T v;
    std::memcpy(&v, data_ + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  // Reads an array of at most `max_count` elements.
  template <typename T>
  std::vector<T> GetVector(uint64_t max_count) {
    const uint64_t n = Get<uint64_t>();
    if (n > max_count) Fail("array of " + std::to_string(n) + " elements exceeds the limit");
    Need(n * sizeof(T));
    std::vector<T> v(n);
    if (n > 0) std::memcpy(v.data(), data_ + pos_, n * sizeof(T));
    pos_ += n * sizeof(T);
    return v;
  }
  std::string GetString(uint64_t max_len) {
    const auto v = GetVector<char>(max_len);
    return std::string(v.begin(), v.end());
  }
  size_t remaining() const { return size_ - pos_; }
  void Skip(uint64_t n) {
    Need(n);
    pos_ += n;
  }
  [[noreturn]] void Fail(const std::string& what) const {
    throw std::runtime_error(source_ + ": " + what + " (at byte " + std::to_string(pos_) + ")");
  }

 private:
  void Need(uint64_t n) {
    if (n > size_ - pos_) Fail("file is truncated");
  }
  const char* data_;
  size_t size_;
  size_t pos_ = 0;
  std::string source_;
};

// Writes magic (8 bytes), version, payload size, payload and checksum atomically to `path`.
void WriteFramedFile(const std::filesystem::path& path, const char magic[8], uint32_t version,
                     const std::string& payload);
// The same for a payload given in pieces, streamed to the file without a joined copy.
void WriteFramedFile(const std::filesystem::path& path, const char magic[8], uint32_t version,
                     std::initializer_list<std::string_view> payload);

// A framed file whose payload of a size known up front is streamed in pieces of any size
// (no copy of the payload in memory), then published atomically by Commit(), which checks
// that exactly `payload_size` bytes came. Destroyed without Commit(), nothing changes at `path`.
class FramedFileWriter {
 public:
  FramedFileWriter(const std::filesystem::path& path, const char magic[8], uint32_t version,
                   uint64_t payload_size);
  ~FramedFileWriter();
  FramedFileWriter(const FramedFileWriter&) = delete;
  FramedFileWriter& operator=(const FramedFileWriter&) = delete;
  void Write(const void* data, size_t size);
  void Write(std::string_view piece) { Write(piece.data(), piece.size()); }
  void Commit();

 private:
  std::unique_ptr<class AtomicFileWriter> file_;
  Checksum64Builder sum_;
  uint64_t size_, written_ = 0;
};

// A framed file's contents, with the payload located inside it (no copy of the payload).
class FramedPayload {
 public:
  FramedPayload(std::string file, size_t offset, size_t size, uint32_t version = 0)
      : file_(std::move(file)), offset_(offset), size_(size), version_(version) {}
  const char* data() const { return file_.data() + offset_; }
  size_t size() const { return size_; }
  uint32_t version() const { return version_; }  // the file's format version

 private:
  std::string file_;
  size_t offset_;
  size_t size_;
  uint32_t version_;
};

// Reads a framed file; throws std::runtime_error naming the file when the magic, version, size
// or checksum is wrong.
FramedPayload ReadFramedFile(const std::filesystem::path& path, const char magic[8],
                             uint32_t version, const std::string& what);
// The same for a reader of versions oldest..newest.
FramedPayload ReadFramedFile(const std::filesystem::path& path, const char magic[8],
                             uint32_t oldest, uint32_t newest, const std::string& what);

}  // namespace gtbow
