#include "ground_texture_bow/eval/dataset.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ground_texture_bow/core/file_util.h"

namespace fs = std::filesystem;

namespace gtbow {

namespace {

[[noreturn]] void Fail(const std::string& source, int line, const std::string& what) {
  std::ostringstream s;
  s << source;
  if (line > 0) s << ":" << line;
  s << ": " << what;
  throw std::runtime_error(s.str());
}

std::string Trim(const std::string& s) {
  const char* ws = " \t\r\n";
  const size_t b = s.find_first_not_of(ws);
  if (b == std::string::npos) return "";
  const size_t e = s.find_last_not_of(ws);
  return s.substr(b, e - b + 1);
}

std::vector<std::string> SplitLines(const std::string& text) {
  std::vector<std::string> lines;
  std::string cur;
  for (char c : text) {
    if (c == '\n') {
      lines.push_back(cur);
      cur.clear();
    } else {
      cur.push_back(c);
    }
  }
  if (!cur.empty()) lines.push_back(cur);
  return lines;
}

// Splits one CSV line; supports double-quoted fields with "" escapes.
std::vector<std::string> SplitCsv(const std::string& line, const std::string& source, int lineno) {
  std::vector<std::string> out;
  std::string cur;
  bool quoted = false;
  bool was_quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"') {
        if (i + 1 < line.size() && line[i + 1] == '"') {
          cur.push_back('"');
          ++i;
        } else {
          quoted = false;
        }
      } else {
        cur.push_back(c);
      }
    } else if (c == '"') {
      quoted = true;
      was_quoted = true;
    } else if (c == ',') {
      out.push_back(was_quoted ? cur : Trim(cur));
      cur.clear();
      was_quoted = false;
    } else {
      cur.push_back(c);
    }
  }
  if (quoted) Fail(source, lineno, "unterminated quoted field");
  out.push_back(was_quoted ? cur : Trim(cur));
  return out;
}

bool ParseDouble(const std::string& s, double* value) {
  if (s.empty()) return false;
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size() || errno == ERANGE || !std::isfinite(v)) return false;
  *value = v;
  return true;
}

bool IsControl(char c) { return static_cast<unsigned char>(c) < 0x20 || c == 0x7f; }

// A name as it can be shown in a message: control characters as \xNN.
std::string Printable(const std::string& name) {
  std::string out;
  for (const char c : name) {
    if (IsControl(c)) {
      char buf[8];
      std::snprintf(buf, sizeof(buf), "\\x%02x", static_cast<unsigned char>(c));
      out += buf;
    } else {
      out += c;
    }
  }
  return out;
}

// Valid UTF-8 without control characters other than tab (YAML text; free-text fields).
bool IsText(const std::string& s) {
  for (size_t i = 0; i < s.size();) {
    const auto c = static_cast<unsigned char>(s[i]);
    if (c < 0x80) {
      if (IsControl(s[i]) && c != '\t') return false;
      ++i;
      continue;
    }
    const int n = (c & 0xE0) == 0xC0 ? 1 : (c & 0xF0) == 0xE0 ? 2 : (c & 0xF8) == 0xF0 ? 3 : -1;
    if (n < 0 || c == 0xC0 || c == 0xC1 || c > 0xF4 || i + static_cast<size_t>(n) >= s.size()) {
      return false;
    }
    for (int k = 1; k <= n; ++k) {
      if ((static_cast<unsigned char>(s[i + k]) & 0xC0) != 0x80) return false;
    }
    i += static_cast<size_t>(n) + 1;
  }
  return true;
}

void CheckImageName(const std::string& name, const std::string& source, int lineno) {
  if (name.empty()) Fail(source, lineno, "empty image name");
  if (std::any_of(name.begin(), name.end(), IsControl)) {
    Fail(source, lineno, "image name '" + Printable(name) + "' contains a control character");
  }
  const fs::path p(name);
  if (p.is_absolute()) Fail(source, lineno, "image name '" + name + "' must be relative");
  for (const auto& part : p) {
    if (part == "..") Fail(source, lineno, "image name '" + name + "' leaves images/");
  }
}

// A split name names the file sequences/<name>.txt: one plain file name.
void CheckSplitName(const std::string& name, const std::string& source, int lineno) {
  if (name.empty() || name == "." || name == ".." || !IsText(name) ||
      name.find('\t') != std::string::npos || name.find_first_of("/\\") != std::string::npos) {
    Fail(source, lineno,
         "query_days: '" + Printable(name) +
             "' is not a split name (a plain file name "
             "under sequences/, UTF-8 text without '/' or control characters)");
  }
}

int YamlLine(const YAML::Node& node) { return node.Mark().line >= 0 ? node.Mark().line + 1 : 0; }

template <typename T>
T YamlScalar(const YAML::Node& root, const std::string& key, const std::string& source,
             const std::string& expected) {
  const YAML::Node node = root[key];
  if (!node) Fail(source, 0, "missing required key '" + key + "'");
  if (!node.IsScalar()) Fail(source, YamlLine(node), "'" + key + "' must be " + expected);
  try {
    return node.as<T>();
  } catch (const YAML::Exception&) {
    Fail(source, YamlLine(node),
         "'" + key + "' must be " + expected + ", found '" + node.Scalar() + "'");
  }
}

// A CSV field as SplitCsv reads it back: quoted (quotes doubled) when it holds a comma, a
// quote or a '#', or begins or ends with white space.
std::string CsvField(const std::string& v) {
  if (v.find_first_of(",\"#") == std::string::npos && v == Trim(v)) return v;
  std::string out = "\"";
  for (const char c : v) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
}

// Fixed-point with `digits` decimals, however large the value (%f of 1e300 has 301 digits).
std::string FormatDouble(double v, int digits) {
  const int n = std::snprintf(nullptr, 0, "%.*f", digits, v);
  std::string out(static_cast<size_t>(n) + 1, '\0');
  std::snprintf(&out[0], out.size(), "%.*f", digits, v);
  out.resize(static_cast<size_t>(n));
  return out;
}

}  // namespace

DatasetInfo ParseDatasetYaml(const std::string& text, const std::string& source) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::ParserException& e) {
    Fail(source, e.mark.line + 1, "invalid YAML: " + e.msg);
  }
  if (!root.IsMap()) Fail(source, 0, "expected a mapping of keys at the top level");
  DatasetInfo info;
  info.format_version = YamlScalar<int>(root, "format_version", source, "an integer");
  if (info.format_version != 1) {
    Fail(source, YamlLine(root["format_version"]),
         "unsupported format_version " + std::to_string(info.format_version) +
             " (this reader supports 1)");
  }
  for (const auto& [key, field] :
       {std::pair<const char*, std::string*>{"name", &info.name}, {"surface", &info.surface}}) {
    const YAML::Node node = root[key];
    if (!node || !node.IsScalar()) continue;
    if (!IsText(node.Scalar())) {
      Fail(source, YamlLine(node),
           std::string("'") + key + "' must be UTF-8 text without control characters");
    }
    *field = node.Scalar();
  }
  info.geometry.width = YamlScalar<int>(root, "image_width", source, "a positive integer");
  info.geometry.height = YamlScalar<int>(root, "image_height", source, "a positive integer");
  info.geometry.meters_per_pixel =
      YamlScalar<double>(root, "meters_per_pixel", source, "a positive number");
  if (info.geometry.width <= 0) {
    Fail(source, YamlLine(root["image_width"]), "image_width must be positive");
  }
  if (info.geometry.height <= 0) {
    Fail(source, YamlLine(root["image_height"]), "image_height must be positive");
  }
  if (!(info.geometry.meters_per_pixel > 0.0) || !std::isfinite(info.geometry.meters_per_pixel)) {
    Fail(source, YamlLine(root["meters_per_pixel"]), "meters_per_pixel must be positive");
  }
  if (const YAML::Node days = root["query_days"]) {
    if (!days.IsMap() && !days.IsNull()) {
      Fail(source, YamlLine(days), "query_days must map split names to days");
    }
    if (days.IsMap()) {
      for (const auto& kv : days) {
        if (!kv.first.IsScalar())
          Fail(source, YamlLine(kv.first), "query_days: a split name must be text");
        const std::string split = kv.first.Scalar();
        CheckSplitName(split, source, YamlLine(kv.first));
        double d = 0.0;
        if (!kv.second.IsScalar() || !ParseDouble(kv.second.Scalar(), &d)) {
          Fail(source, YamlLine(kv.second), "query_days." + split + " must be a number");
        }
        info.query_days[split] = d;
      }
    }
  }
  return info;
}

std::vector<PoseRecord> ParsePosesCsv(const std::string& text, const std::string& source) {
  const auto lines = SplitLines(text);
  std::vector<PoseRecord> out;
  int col_image = -1, col_x = -1, col_y = -1, col_theta = -1;
  size_t num_cols = 0;
  bool have_header = false;
  std::unordered_map<std::string, int> seen;
  for (size_t i = 0; i < lines.size(); ++i) {
    const int lineno = static_cast<int>(i) + 1;
    std::string line = lines[i];
    if (i == 0 && line.size() >= 3 && line.compare(0, 3, "\xEF\xBB\xBF") == 0) line.erase(0, 3);
    const std::string t = Trim(line);
    if (t.empty() || t[0] == '#') continue;
    const auto fields = SplitCsv(t, source, lineno);
    if (!have_header) {
      for (size_t c = 0; c < fields.size(); ++c) {
        std::string name = fields[c];
        std::transform(name.begin(), name.end(), name.begin(), ::tolower);
        int* slot = name == "image"   ? &col_image
                    : name == "x"     ? &col_x
                    : name == "y"     ? &col_y
                    : name == "theta" ? &col_theta
                                      : nullptr;
        if (slot != nullptr) {
          if (*slot >= 0) Fail(source, lineno, "column '" + name + "' appears twice in header");
          *slot = static_cast<int>(c);
        }
      }
      for (const auto& [name, col] : {std::pair<const char*, int>{"image", col_image},
                                      {"x", col_x},
                                      {"y", col_y},
                                      {"theta", col_theta}}) {
        if (col < 0) {
          Fail(source, lineno,
               std::string("header lacks required column '") + name + "' (found: " + t + ")");
        }
      }
      num_cols = fields.size();
      have_header = true;
      continue;
    }
    if (fields.size() != num_cols) {
      Fail(source, lineno,
           "expected " + std::to_string(num_cols) + " fields as in the header, found " +
               std::to_string(fields.size()));
    }
    PoseRecord r;
    r.image = fields[col_image];
    CheckImageName(r.image, source, lineno);
    const std::pair<int, double*> numeric[] = {
        {col_x, &r.pose.x}, {col_y, &r.pose.y}, {col_theta, &r.pose.theta}};
    const char* names[] = {"x", "y", "theta"};
    for (int k = 0; k < 3; ++k) {
      if (!ParseDouble(fields[numeric[k].first], numeric[k].second)) {
        Fail(source, lineno,
             std::string("column '") + names[k] + "': expected a finite number, found '" +
                 fields[numeric[k].first] + "'");
      }
    }
    auto [it, inserted] = seen.emplace(r.image, lineno);
    if (!inserted) {
      Fail(source, lineno,
           "image '" + r.image + "' already listed on line " + std::to_string(it->second));
    }
    out.push_back(std::move(r));
  }
  if (!have_header) Fail(source, 0, "missing header line 'image,x,y,theta'");
  return out;
}

namespace {

// The names of a sequence file with the line each stands on.
std::vector<std::pair<std::string, int>> ParseSequenceLines(const std::string& text,
                                                            const std::string& source) {
  std::vector<std::pair<std::string, int>> out;
  const auto lines = SplitLines(text);
  for (size_t i = 0; i < lines.size(); ++i) {
    std::string line = lines[i];
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.erase(hash);
    line = Trim(line);
    if (line.empty()) continue;
    const int lineno = static_cast<int>(i) + 1;
    CheckImageName(line, source, lineno);
    out.emplace_back(line, lineno);
  }
  return out;
}

}  // namespace

std::vector<std::string> ParseSequence(const std::string& text, const std::string& source) {
  std::vector<std::string> out;
  for (auto& [name, line] : ParseSequenceLines(text, source)) out.push_back(std::move(name));
  return out;
}

std::string FormatDatasetYaml(const DatasetInfo& info) {
  YAML::Emitter e;
  e << YAML::BeginMap;
  e << YAML::Key << "format_version" << YAML::Value << info.format_version;
  e << YAML::Key << "name" << YAML::Value << info.name;
  e << YAML::Key << "surface" << YAML::Value << info.surface;
  e << YAML::Key << "image_width" << YAML::Value << info.geometry.width;
  e << YAML::Key << "image_height" << YAML::Value << info.geometry.height;
  e << YAML::Key << "meters_per_pixel" << YAML::Value << YAML::Precision(17)
    << info.geometry.meters_per_pixel;
  if (!info.query_days.empty()) {
    e << YAML::Key << "query_days" << YAML::Value << YAML::Flow << YAML::BeginMap;
    for (const auto& [split, day] : info.query_days) {
      e << YAML::Key << split << YAML::Value << YAML::Precision(17) << day;
    }
    e << YAML::EndMap;
  }
  e << YAML::EndMap;
  return std::string(e.c_str()) + "\n";
}

std::string FormatPosesCsv(const std::vector<PoseRecord>& poses) {
  std::string out = "image,x,y,theta\n";
  out.reserve(poses.size() * 48 + out.size());
  for (const auto& r : poses) {
    out += CsvField(r.image);
    out += ',';
    out += FormatDouble(r.pose.x, 7);
    out += ',';
    out += FormatDouble(r.pose.y, 7);
    out += ',';
    out += FormatDouble(r.pose.theta, 7);
    out += '\n';
  }
  return out;
}

std::string FormatSequence(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& n : names) {
    // A line is trimmed and '#' starts a comment: such names have no sequence-file form.
    if (n.empty() || n.find('#') != std::string::npos || n != Trim(n) ||
        n.find_first_of("\r\n") != std::string::npos) {
      throw std::invalid_argument("FormatSequence: image name '" + n +
                                  "' cannot be written "
                                  "to a sequence file (empty, '#', or surrounding spaces)");
    }
    out += n;
    out += '\n';
  }
  return out;
}

void WriteDatasetFiles(const fs::path& root, const DatasetInfo& info,
                       const std::vector<PoseRecord>& poses,
                       const std::map<std::string, std::vector<std::string>>& splits) {
  fs::create_directories(root / "sequences");
  WriteFileAtomic(root / "dataset.yaml", FormatDatasetYaml(info));
  WriteFileAtomic(root / "poses.csv", FormatPosesCsv(poses));
  for (const auto& [split, names] : splits) {
    WriteFileAtomic(root / "sequences" / (split + ".txt"), FormatSequence(names));
  }
}

Dataset Dataset::Load(const fs::path& root) {
  if (!fs::is_directory(root)) {
    throw std::runtime_error("dataset '" + root.string() + "' is not a directory");
  }
  Dataset d;
  d.root_ = root;
  const fs::path yaml = root / "dataset.yaml";
  d.info_ = ParseDatasetYaml(ReadFile(yaml), yaml.string());
  const fs::path csv = root / "poses.csv";
  d.poses_ = ParsePosesCsv(ReadFile(csv), csv.string());
  d.index_.reserve(d.poses_.size());
  for (size_t i = 0; i < d.poses_.size(); ++i) d.index_.emplace(d.poses_[i].image, i);
  return d;
}

const Pose2D& Dataset::PoseOf(const std::string& image) const {
  const auto it = index_.find(image);
  if (it == index_.end()) {
    throw std::out_of_range("image '" + image + "' has no pose in " +
                            (root_ / "poses.csv").string());
  }
  return poses_[it->second].pose;
}

std::vector<std::string> Dataset::SplitNames() const {
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(root_ / "sequences", ec)) {
    if (entry.path().extension() == ".txt") names.push_back(entry.path().stem().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

std::vector<std::string> Dataset::Split(const std::string& split) const {
  const fs::path file = root_ / "sequences" / (split + ".txt");
  if (!fs::exists(file)) {
    throw std::runtime_error("split '" + split + "' not found: " + file.string() +
                             " does not exist");
  }
  const auto entries = ParseSequenceLines(ReadFile(file), file.string());
  if (entries.empty()) throw std::runtime_error(file.string() + ": split '" + split + "' is empty");
  std::vector<std::string> names;
  names.reserve(entries.size());
  for (const auto& [name, line] : entries) {
    if (!HasImage(name)) {
      Fail(file.string(), line, "image '" + name + "' has no pose in poses.csv");
    }
    names.push_back(name);
  }
  return names;
}

fs::path Dataset::ImagePath(const std::string& image) const { return root_ / "images" / image; }

cv::Mat Dataset::LoadGray(const std::string& image) const {
  const fs::path path = ImagePath(image);
  if (!fs::exists(path)) throw std::runtime_error("image file missing: " + path.string());
  cv::Mat img = cv::imread(path.string(), cv::IMREAD_UNCHANGED);
  if (img.empty()) throw std::runtime_error("cannot decode image: " + path.string());
  if (img.depth() != CV_8U) {
    throw std::runtime_error(path.string() + ": expected an 8-bit image");
  }
  if (img.channels() == 3) {
    cv::cvtColor(img, img, cv::COLOR_BGR2GRAY);
  } else if (img.channels() == 4) {
    cv::cvtColor(img, img, cv::COLOR_BGRA2GRAY);
  } else if (img.channels() != 1) {
    throw std::runtime_error(path.string() + ": unsupported channel count " +
                             std::to_string(img.channels()));
  }
  if (img.cols != info_.geometry.width || img.rows != info_.geometry.height) {
    throw std::runtime_error(path.string() + ": image is " + std::to_string(img.cols) + "x" +
                             std::to_string(img.rows) + ", dataset.yaml says " +
                             std::to_string(info_.geometry.width) + "x" +
                             std::to_string(info_.geometry.height));
  }
  return img;
}

}  // namespace gtbow
