#include "ground_texture_bow/core/binary_io.h"

#include "ground_texture_bow/core/file_util.h"

namespace gtbow {

namespace {

constexpr uint64_t kWordMul = 0xff51afd7ed558ccdULL;

inline uint64_t MixWord(uint64_t h, uint64_t w) {
  h = (h ^ (w * kWordMul)) * 0xc4ceb9fe1a85ec53ULL;
  return h ^ (h >> 29);
}

inline uint64_t MixByte(uint64_t h, unsigned char b) { return (h ^ b) * 0x100000001b3ULL; }

inline uint64_t Final(uint64_t h) {
  h ^= h >> 33;
  h *= kWordMul;
  return h ^ (h >> 33);
}

}  // namespace

uint64_t Checksum64(const void* data, size_t size) {
  const auto* p = static_cast<const unsigned char*>(data);
  uint64_t h = 0x9E3779B97F4A7C15ULL ^ size;
  size_t i = 0;
  for (; i + 8 <= size; i += 8) {
    uint64_t w;
    std::memcpy(&w, p + i, 8);
    h = MixWord(h, w);
  }
  for (; i < size; ++i) h = MixByte(h, p[i]);
  return Final(h);
}

Checksum64Builder::Checksum64Builder(uint64_t total_size)
    : h_(0x9E3779B97F4A7C15ULL ^ total_size) {}

void Checksum64Builder::Add(const void* data, size_t size) {
  const auto* p = static_cast<const unsigned char*>(data);
  while (size > 0 && partial_ > 0) {  // complete a word begun by an earlier piece
    word_[partial_++] = *p++;
    --size;
    if (partial_ == 8) {
      uint64_t w;
      std::memcpy(&w, word_, 8);
      h_ = MixWord(h_, w);
      partial_ = 0;
    }
  }
  for (; size >= 8; p += 8, size -= 8) {
    uint64_t w;
    std::memcpy(&w, p, 8);
    h_ = MixWord(h_, w);
  }
  std::memcpy(word_ + partial_, p, size);
  partial_ += size;
}

uint64_t Checksum64Builder::Finish() {
  for (size_t i = 0; i < partial_; ++i) h_ = MixByte(h_, word_[i]);
  partial_ = 0;
  return Final(h_);
}

void WriteFramedFile(const std::filesystem::path& path, const char magic[8], uint32_t version,
                     const std::string& payload) {
  WriteFramedFile(path, magic, version, {std::string_view(payload)});
}

void WriteFramedFile(const std::filesystem::path& path, const char magic[8], uint32_t version,
                     std::initializer_list<std::string_view> payload) {
  uint64_t size = 0;
  for (const std::string_view& piece : payload) size += piece.size();
  FramedFileWriter file(path, magic, version, size);
  for (const std::string_view& piece : payload) file.Write(piece);
  file.Commit();
}

FramedFileWriter::FramedFileWriter(const std::filesystem::path& path, const char magic[8],
                                   uint32_t version, uint64_t payload_size)
    : file_(std::make_unique<AtomicFileWriter>(path)), sum_(payload_size), size_(payload_size) {
  char header[8 + sizeof(uint32_t) + sizeof(uint64_t)];
  std::memcpy(header, magic, 8);
  std::memcpy(header + 8, &version, sizeof(version));
  std::memcpy(header + 12, &payload_size, sizeof(payload_size));
  file_->Write(header, sizeof(header));
}

FramedFileWriter::~FramedFileWriter() = default;

void FramedFileWriter::Write(const void* data, size_t size) {
  if (written_ + size > size_)
    throw std::logic_error("FramedFileWriter: more bytes than announced");
  sum_.Add(data, size);
  file_->Write(data, size);
  written_ += size;
}

void FramedFileWriter::Commit() {
  if (written_ != size_) throw std::logic_error("FramedFileWriter: fewer bytes than announced");
  const uint64_t checksum = sum_.Finish();
  file_->Write(&checksum, sizeof(checksum));
  file_->Commit();
}

FramedPayload ReadFramedFile(const std::filesystem::path& path, const char magic[8],
                             uint32_t version, const std::string& what) {
  return ReadFramedFile(path, magic, version, version, what);
}

FramedPayload ReadFramedFile(const std::filesystem::path& path, const char magic[8],
                             uint32_t oldest, uint32_t version, const std::string& what) {
  std::string data = ReadFile(path);
  const std::string src = path.string();
  constexpr size_t kHeader = 8 + sizeof(uint32_t) + sizeof(uint64_t);
  if (data.size() < kHeader + sizeof(uint64_t)) {
    throw std::runtime_error(src + ": not a " + what +
                             " file (too short: " + std::to_string(data.size()) + " bytes)");
  }
  if (std::memcmp(data.data(), magic, 8) != 0) {
    throw std::runtime_error(src + ": not a " + what + " file (wrong magic number)");
  }
  uint32_t v;
  std::memcpy(&v, data.data() + 8, sizeof(v));
  if (v < oldest || v > version) {
    throw std::runtime_error(src + ": " + what + " format version " + std::to_string(v) +
                             " is not supported (this build reads version " +
                             (oldest == version
                                  ? std::to_string(version)
                                  : std::to_string(oldest) + " to " + std::to_string(version)) +
                             ")");
  }
  uint64_t size;
  std::memcpy(&size, data.data() + 12, sizeof(size));
  if (size != data.size() - kHeader - sizeof(uint64_t)) {
    throw std::runtime_error(src + ": " + what + " file is truncated or has trailing bytes");
  }
  uint64_t sum;
  std::memcpy(&sum, data.data() + kHeader + size, sizeof(sum));
  if (Checksum64(data.data() + kHeader, size) != sum) {
    throw std::runtime_error(src + ": " + what + " file is corrupt (checksum mismatch)");
  }
  return FramedPayload(std::move(data), kHeader, size, v);
}

}  // namespace gtbow
