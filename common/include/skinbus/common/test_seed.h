// skinbus/common/test_seed.h: the seed of a randomized test (tests, fuzz helpers, benchmarks
// only; not used by the libraries).
#pragma once

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <random>

namespace skinbus {

// $SKINBUS_TEST_SEED if set, else fresh entropy. Printed with `test_name`, so a failure can be
// replayed with SKINBUS_TEST_SEED=<seed>.
inline uint64_t test_seed(const char* test_name) {
  uint64_t seed = 0;
  if (const char* env = std::getenv("SKINBUS_TEST_SEED")) {
    seed = std::strtoull(env, nullptr, 0);
  } else {
    seed = (static_cast<uint64_t>(std::random_device{}()) << 32) ^ std::random_device{}();
  }
  std::printf("[ seed     ] %s: SKINBUS_TEST_SEED=%llu\n", test_name,
              static_cast<unsigned long long>(seed));
  return seed;
}

}  // namespace skinbus
