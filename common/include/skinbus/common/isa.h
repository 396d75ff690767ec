// skinbus/common/isa.h: the vector instruction sets the project's hot loops are built for (the
// network kernels, the simulator's field evaluation), and the cap a process may put on them.
//
// Each hot loop picks, once, the widest set the CPU has within the cap: the environment variable
// SKINBUS_MAX_ISA names it for a whole process (benchmarks and tests run the AVX2 path of an
// AVX-512 CPU this way; docs/testing.md), and RuntimeOptions::max_isa for one network runtime.
#pragma once

#include <cstdint>
#include <cstdlib>
#include <string_view>

namespace skinbus {

// Widest first; a cap allows its own set and every set after it (neon and the x86 sets never
// exist in one build).
enum class Isa : uint8_t { kAvx512, kAvx2, kNeon, kPortable };

constexpr const char* isa_name(Isa i) {
  switch (i) {
    case Isa::kAvx512:
      return "avx512";
    case Isa::kAvx2:
      return "avx2";
    case Isa::kNeon:
      return "neon";
    case Isa::kPortable:
      return "portable";
  }
  return "unknown";
}

// Reads a name as isa_name() writes it; false for any other text.
constexpr bool parse_isa(std::string_view name, Isa* isa) {
  for (Isa i : {Isa::kAvx512, Isa::kAvx2, Isa::kNeon, Isa::kPortable}) {
    if (name == isa_name(i)) {
      *isa = i;
      return true;
    }
  }
  return false;
}

// Whether a cap allows `isa`.
constexpr bool isa_allowed(Isa isa, Isa cap) {
  return static_cast<int>(isa) >= static_cast<int>(cap);
}

// The cap SKINBUS_MAX_ISA names (avx512, avx2, neon, portable; any other text: portable), read
// once per process; kAvx512 (no cap) when unset or empty.
inline Isa env_isa_cap() {
  static const Isa cap = [] {
    Isa isa = Isa::kAvx512;
    const char* v = std::getenv("SKINBUS_MAX_ISA");
    if (v != nullptr && *v != '\0' && !parse_isa(v, &isa)) isa = Isa::kPortable;
    return isa;
  }();
  return cap;
}

}  // namespace skinbus
