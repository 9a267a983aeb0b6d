// Subcommands of the gtbow command-line tool. Each Register* adds its subcommand to the app;
// the callback runs the command and throws on failure (gtbow's main reports and exits 2).
#pragma once

#include <CLI/CLI.hpp>

namespace gtbow {
namespace tools {

void RegisterSynth(CLI::App& app);
void RegisterTrainVocab(CLI::App& app);
void RegisterBenchRetrieval(CLI::App& app);
void RegisterBenchScaling(CLI::App& app);  // gtbow bench-scaling (alias: bench)
void RegisterBenchMap(CLI::App& app);      // gtbow bench-map
void RegisterEval(CLI::App& app);
void RegisterMapCommands(CLI::App& app);  // map-info, convert-map, localize
void RegisterSlam(CLI::App& app);         // gtbow slam

}  // namespace tools
}  // namespace gtbow
