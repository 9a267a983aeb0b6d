// The SIMD kernels the engine runs on this CPU, by name, for reports beside timings. They are
// chosen at run time, once per process (SetSimdLimit aside): the widest the CPU supports, or up to
// the one that the environment variable GTBOW_SIMD names (portable, popcnt, avx2, avx512 on x86-64;
// portable, neon on aarch64). Unset: every instruction set the CPU has. (One exception: on AMD's
// first Zen cores the Hamming distances run popcnt, the faster there, unless GTBOW_SIMD=avx2.)
#pragma once

#include <string>

namespace gtbow {

// The Hamming kernel (binary words: the binary IVF word search, Hamming k-means and vocabulary
// trees, descriptor matching in verification): "portable", "popcnt", "avx2", "avx512" or "neon".
const char* ActiveHammingKernelName();
// The squared-L2 kernel between bytes (the l2_bytes IVF word search): "portable", "avx2" or
// "avx512".
const char* ActiveByteDistanceKernelName();
// Both, for one line of a report: "hamming avx512, l2_bytes avx512".
std::string ActiveSimdKernels();

// For benchmarks that time the kernels side by side in one process (gtbow eval
// --timing-kernels): caps every family's kernel as GTBOW_SIMD=name would, from now on ("" lifts
// the cap). Returns false, changing nothing, for a name this build does not know. Not while
// another thread runs the engine.
bool SetSimdLimit(const std::string& name);
// The cap in force, as SetSimdLimit takes it back: the name of the widest kernel allowed, or ""
// for none. (Not always the active kernel's name: a CPU may lack the kernel named, and on AMD's
// first Zen cores the Hamming distances run popcnt, not avx2, unless the cap is avx2.)
std::string SimdLimit();

}  // namespace gtbow
