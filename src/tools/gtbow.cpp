// gtbow: the command-line front end of ground_texture_bow.
#include <malloc.h>

#include <cstdio>
#include <exception>

#include <CLI/CLI.hpp>

#include "commands.h"

int main(int argc, char** argv) {
  // Rendering and training allocate many large, short-lived buffers: keep them in the heap
  // rather than returning them to the kernel (and page-faulting them back) every time.
  mallopt(M_MMAP_THRESHOLD, 512 << 20);
  mallopt(M_TRIM_THRESHOLD, 1024 << 20);
  CLI::App app{
      "gtbow: ground-texture bag-of-words tools (dataset synthesis, vocabularies, "
      "maps, evaluation)"};
  app.require_subcommand(1);
  gtbow::tools::RegisterSynth(app);
  gtbow::tools::RegisterTrainVocab(app);
  gtbow::tools::RegisterBenchRetrieval(app);
  gtbow::tools::RegisterBenchScaling(app);
  gtbow::tools::RegisterBenchMap(app);
  gtbow::tools::RegisterEval(app);
  gtbow::tools::RegisterMapCommands(app);
  gtbow::tools::RegisterSlam(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "gtbow: error: %s\n", e.what());
    return 2;
  }
  return 0;
}
