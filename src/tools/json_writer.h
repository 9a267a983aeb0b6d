// The JSON that gtbow eval writes (results.json).
#pragma once

#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

namespace gtbow {
namespace tools {

// A minimal JSON writer: values are appended in order; the caller keeps the structure valid.
class Json {
 public:
  Json& Key(const std::string& k) {
    Sep();
    s_ << Quote(k) << ": ";
    fresh_ = true;
    return *this;
  }
  Json& Str(const std::string& v) { return Raw(Quote(v)); }
  Json& Num(double v) {
    if (!std::isfinite(v)) return Raw("null");
    char b[32];
    std::snprintf(b, sizeof(b), "%.9g", v);
    return Raw(b);
  }
  Json& Int(long long v) { return Raw(std::to_string(v)); }
  Json& Bool(bool v) { return Raw(v ? "true" : "false"); }
  Json& Open(char c) {
    Sep();
    s_ << c;
    fresh_ = true;
    return *this;
  }
  Json& Close(char c) {
    s_ << c;
    fresh_ = false;
    return *this;
  }
  Json& Nums(const std::vector<double>& v) {
    Open('[');
    for (double x : v) Num(x);
    return Close(']');
  }
  std::string str() const { return s_.str() + "\n"; }

 private:
  Json& Raw(const std::string& v) {
    Sep();
    s_ << v;
    return *this;
  }
  void Sep() {
    if (!fresh_) s_ << ", ";
    fresh_ = false;
  }
  static std::string Quote(const std::string& v) {
    std::string o = "\"";
    for (char ch : v) {
      if (ch == '"' || ch == '\\') o += '\\';
      if (static_cast<unsigned char>(ch) < 0x20) {
        char b[8];
        std::snprintf(b, sizeof(b), "\\u%04x", ch);
        o += b;
        continue;
      }
      o += ch;
    }
    return o + "\"";
  }
  std::ostringstream s_;
  bool fresh_ = true;
};

}  // namespace tools
}  // namespace gtbow
