#include "ground_texture_bow/core/binary_io.h"

#include "ground_texture_bow/core/file_util.h"

namespace gtbow {

uint64_t Checksum64(const void* data, size_t size) {
  const auto* p = static_cast<const unsigned char*>(data);
  uint64_t h = 0x9E3779B97F4A7C15ULL ^ size;
  size_t i = 0;
  for (; i + 8 <= size; i += 8) {
    uint64_t w;
    std::memcpy(&w, p + i, 8);
    h = (h ^ (w * 0xff51afd7ed558ccdULL)) * 0xc4ceb9fe1a85ec53ULL;
    h ^= h >> 29;
  }
  for (; i < size; ++i) h = (h ^ p[i]) * 0x100000001b3ULL;
  h ^= h >> 33;
  h *= 0xff51afd7ed558ccdULL;
  h ^= h >> 33;
  return h;
}

void WriteFramedFile(const std::filesystem::path& path, const char magic[8], uint32_t version,
                     const std::string& payload) {
  char header[8 + sizeof(uint32_t) + sizeof(uint64_t)];
  std::memcpy(header, magic, 8);
  std::memcpy(header + 8, &version, sizeof(version));
  const uint64_t size = payload.size();
  std::memcpy(header + 12, &size, sizeof(size));
  const uint64_t sum = Checksum64(payload.data(), payload.size());
  WriteFileAtomic(path, {std::string_view(header, sizeof(header)), std::string_view(payload),
                         std::string_view(reinterpret_cast<const char*>(&sum), sizeof(sum))});
}

FramedPayload ReadFramedFile(const std::filesystem::path& path, const char magic[8],
                             uint32_t version, const std::string& what) {
  std::string data = ReadFile(path);
  const std::string src = path.string();
  constexpr size_t kHeader = 8 + sizeof(uint32_t) + sizeof(uint64_t);
  if (data.size() < kHeader + sizeof(uint64_t)) {
    throw std::runtime_error(src + ": not a " + what + " file (too short: " +
                             std::to_string(data.size()) + " bytes)");
  }
  if (std::memcmp(data.data(), magic, 8) != 0) {
    throw std::runtime_error(src + ": not a " + what + " file (wrong magic number)");
  }
  uint32_t v;
  std::memcpy(&v, data.data() + 8, sizeof(v));
  if (v != version) {
    throw std::runtime_error(src + ": " + what + " format version " + std::to_string(v) +
                             " is not supported (this build reads version " +
                             std::to_string(version) + ")");
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
  return FramedPayload(std::move(data), kHeader, size);
}

}  // namespace gtbow
