// The core library never calls a software popcount. Built for baseline x86-64 (no -mpopcnt),
// __builtin_popcountll becomes a call of libgcc's __popcountdi2, a bit-twiddling loop about ten
// times slower than the POPCNT instruction; every Hamming distance of the core goes through the
// kernels of hamming_distance.cpp instead, each compiled for its instruction set and chosen at
// run time (the portable one counts bits in plain C++ without the call). This test disassembles
// the built libground_texture_bow_core.so and fails on any call of (or jump to) __popcountdi2,
// __popcountsi2 or __popcountti2, naming the functions that make it.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <map>
#include <memory>
#include <regex>
#include <stdexcept>
#include <string>

namespace gtbow {
namespace {

struct Disassembly {
  std::map<std::string, int> popcount_calls;  // function -> calls of a libgcc popcount
  std::map<std::string, int> popcnt;          // function -> POPCNT instructions
  int vpopcntq = 0;                           // AVX-512 VPOPCNTDQ instructions
  int vpshufb = 0;                            // AVX2 table lookups
  size_t lines = 0;
};

Disassembly Disassemble(const std::string& library) {
  const std::string cmd =
      std::string(GTBOW_OBJDUMP) + " -d --no-show-raw-insn -C '" + library + "' 2>&1";
  std::unique_ptr<FILE, int (*)(FILE*)> p(popen(cmd.c_str(), "r"), pclose);
  if (!p) throw std::runtime_error("cannot run " + cmd);
  const std::regex header("^[0-9a-f]+ <(.*)>:$");
  Disassembly d;
  std::string function, line;
  char buf[8192];
  while (std::fgets(buf, sizeof(buf), p.get()) != nullptr) {
    line = buf;
    if (!line.empty() && line.back() == '\n') line.pop_back();
    ++d.lines;
    std::smatch m;
    if (!line.empty() && line[0] != ' ' && std::regex_match(line, m, header)) {
      function = m[1];
      continue;
    }
    const bool branch =
        line.find("\tcall") != std::string::npos || line.find("\tjmp") != std::string::npos ||
        line.find("\tbl") != std::string::npos || line.find("\tb\t") != std::string::npos;
    // (The PLT stub of __popcountdi2, when there is one, jumps to the function itself.)
    if (branch && line.find("<__popcount") != std::string::npos &&
        function.rfind("__popcount", 0) != 0) {
      ++d.popcount_calls[function];
    }
    if (line.find("\tpopcnt ") != std::string::npos) ++d.popcnt[function];
    if (line.find("\tvpopcntq ") != std::string::npos) ++d.vpopcntq;
    if (line.find("\tvpshufb ") != std::string::npos) ++d.vpshufb;
  }
  return d;
}

// The built library, or another one named by GTBOW_CORE_LIBRARY (to inspect an older build).
std::string Library() {
  const char* other = std::getenv("GTBOW_CORE_LIBRARY");
  return other != nullptr && other[0] != '\0' ? other : GTBOW_CORE_LIBRARY;
}

TEST(PopcountCalls, TheCoreLibraryNeverCallsTheSoftwarePopcount) {
  const std::string library = Library();
  const Disassembly d = Disassemble(library);
  ASSERT_GT(d.lines, 10000u) << "objdump printed too little for " << library;
  int calls = 0;
  for (const auto& [function, n] : d.popcount_calls) {
    calls += n;
    ADD_FAILURE() << n << " call(s) of libgcc's software popcount in " << function;
  }
  std::printf("%s: %d calls of __popcount*2\n", library.c_str(), calls);
  EXPECT_EQ(calls, 0);
#if defined(__x86_64__)
  // The disassembly is the real thing: the kernels are there, with their instructions.
  int popcnt = 0;
  for (const auto& [function, n] : d.popcnt) popcnt += n;
  std::printf("POPCNT in %zu functions (%d instructions), %d VPOPCNTQ, %d VPSHUFB\n",
              d.popcnt.size(), popcnt, d.vpopcntq, d.vpshufb);
  auto has_popcnt = [&](const std::string& name) {
    for (const auto& [function, n] : d.popcnt) {
      if (function.find(name) != std::string::npos) return true;
    }
    return false;
  };
  for (const char* kernel : {"PopcntBelow(", "PopcntAll(", "PopcntPair(", "PopcntNearest("})
    EXPECT_TRUE(has_popcnt(kernel)) << kernel << " has no POPCNT instruction";
  EXPECT_GT(d.vpopcntq, 0);
  EXPECT_GT(d.vpshufb, 0);
#endif
}

}  // namespace
}  // namespace gtbow
