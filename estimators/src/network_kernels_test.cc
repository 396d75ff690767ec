// Every kernel of every instruction set this CPU has, against the portable kernels on random
// shapes and values: int8 sums, quantisation, bfloat16 rounding, ReLU, pooling and the Winograd
// transforms exactly; float32 products to rounding (and bit for bit between the x86 sets, which
// form every sum in the same order with FMA). The portable kernels themselves are checked
// against a direct double-precision sum. Needs no LibTorch: this test also runs on Arm (under
// qemu-aarch64 in CI) and with SKINBUS_MAX_ISA capping the sets.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "network_kernels.h"

namespace skinbus::estimators::detail {
namespace {

uint32_t test_seed() {
  static const uint32_t seed = [] {
    const char* s = std::getenv("SKINBUS_TEST_SEED");
    const uint32_t v =
        s != nullptr ? static_cast<uint32_t>(std::strtoul(s, nullptr, 10)) : std::random_device{}();
    std::printf("network_kernels_test seed %u (SKINBUS_TEST_SEED=%u repeats it)\n", v, v);
    return v;
  }();
  return seed;
}

// The vector sets this CPU has, within SKINBUS_MAX_ISA.
std::vector<const KernelSet*> vector_sets() {
  std::vector<const KernelSet*> out;
  const KernelIsa cap = env_isa_cap();
  for (KernelIsa isa : {KernelIsa::kAvx512, KernelIsa::kAvx2, KernelIsa::kNeon}) {
    if (!isa_allowed(isa, cap)) continue;
    if (const KernelSet* k = kernels_for(isa)) out.push_back(k);
  }
  // The AVX2 int8 kernels' dot-product form (AVX-VNNI, or its EVEX twin on AVX-512 CPUs).
  if (isa_allowed(KernelIsa::kAvx2, cap)) {
    if (const KernelSet* k = avx2_dot_product_kernels()) out.push_back(k);
  }
  return out;
}

// The int8 paths to check: every vector set's, and NEON's widening path too where the CPU has
// the dot-product instructions (the set then runs SDOT).
std::vector<const KernelSet*> int8_sets() {
  std::vector<const KernelSet*> out = vector_sets();
  const KernelSet* widening = neon_widening_kernels();
  if (widening != nullptr && widening != neon_kernels() &&
      isa_allowed(KernelIsa::kNeon, env_isa_cap())) {
    out.push_back(widening);
  }
  return out;
}

template <typename T>
std::vector<T> uniform(std::mt19937& rng, std::size_t n, double lo, double hi) {
  std::uniform_real_distribution<double> d(lo, hi);
  std::vector<T> v(n);
  for (T& x : v) x = static_cast<T>(d(rng));
  return v;
}

// One random float32 problem: R rows x 16V columns, `segments` products of K.
struct F32Case {
  int r, v, segments, k;
  bool bias, relu;
  std::vector<std::vector<float>> a;  // segments * r rows of k
  std::vector<std::vector<float>> b;  // segments panels of k x 16V
  std::vector<float> bias_v, c0;      // 16V; r x 16V start when no bias
};

F32Case make_f32(std::mt19937& rng, int r, int v) {
  F32Case t;
  t.r = r;
  t.v = v;
  t.segments = 1 + static_cast<int>(rng() % 3);
  t.k = 1 + static_cast<int>(rng() % 70);
  t.bias = rng() % 2 == 0;
  t.relu = rng() % 2 == 0;
  const std::size_t cols = static_cast<std::size_t>(kLanes * v);
  for (int s = 0; s < t.segments; ++s) {
    for (int i = 0; i < r; ++i) t.a.push_back(uniform<float>(rng, t.k, -1, 1));
    t.b.push_back(uniform<float>(rng, cols * t.k, -1, 1));
  }
  t.bias_v = uniform<float>(rng, cols, -1, 1);
  t.c0 = uniform<float>(rng, cols * r, -1, 1);
  return t;
}

std::vector<float> run_f32(const KernelSet& ks, const F32Case& t) {
  const std::size_t cols = static_cast<std::size_t>(kLanes * t.v);
  std::vector<float> c = t.c0;
  std::vector<const float*> a, b;
  for (const auto& row : t.a) a.push_back(row.data());
  for (const auto& p : t.b) b.push_back(p.data());
  std::vector<float*> c_rows;
  for (int i = 0; i < t.r; ++i) c_rows.push_back(c.data() + cols * i);
  ks.f32[t.r - 1][t.v - 1](a.data(), b.data(), t.segments, t.k, c_rows.data(),
                           t.bias ? t.bias_v.data() : nullptr, t.relu);
  return c;
}

TEST(NetworkKernelsTest, PortableFloat32IsTheDirectSum) {
  std::mt19937 rng(test_seed());
  for (int r = 1; r <= kMaxRows; ++r) {
    for (int v = 1; v <= kMaxVectors; ++v) {
      const F32Case t = make_f32(rng, r, v);
      const std::vector<float> got = run_f32(portable_kernels(), t);
      const std::size_t cols = static_cast<std::size_t>(kLanes * v);
      for (int i = 0; i < r; ++i) {
        for (std::size_t j = 0; j < cols; ++j) {
          double sum = t.bias ? t.bias_v[j] : t.c0[cols * i + j];
          for (int s = 0; s < t.segments; ++s) {
            for (int kk = 0; kk < t.k; ++kk) {
              sum += double{t.a[static_cast<std::size_t>(s * r + i)][kk]} *
                     t.b[static_cast<std::size_t>(s)][cols * kk + j];
            }
          }
          if (t.relu && sum < 0) sum = 0;
          ASSERT_NEAR(got[cols * i + j], sum, 1e-4) << "R " << r << " V " << v;
        }
      }
    }
  }
}

TEST(NetworkKernelsTest, Float32MatchesPortableOnEverySet) {
  std::mt19937 rng(test_seed());
  const std::vector<const KernelSet*> sets = vector_sets();
  if (sets.empty()) GTEST_SKIP() << "no vector kernels on this CPU: the portable ones are checked";
  for (int rep = 0; rep < 4; ++rep) {
    for (int r = 1; r <= kMaxRows; ++r) {
      for (int v = 1; v <= kMaxVectors; ++v) {
        const F32Case t = make_f32(rng, r, v);
        const std::vector<float> want = run_f32(portable_kernels(), t);
        std::vector<float> first;
        for (const KernelSet* ks : sets) {
          const std::vector<float> got = run_f32(*ks, t);
          for (std::size_t j = 0; j < want.size(); ++j) {
            ASSERT_NEAR(got[j], want[j], 1e-4 * t.segments * t.k)
                << ks->name << " R " << r << " V " << v << " at " << j;
          }
#if defined(__x86_64__)
          // AVX-512 and AVX2 form each column's sum in the same order with FMA: the same bits.
          if (!first.empty()) {
            ASSERT_EQ(got, first) << ks->name << " R " << r << " V " << v;
          }
          first = got;
#elif defined(__aarch64__) && defined(__GNUC__) && !defined(__clang__)
          // NEON forms each column's sum in the portable kernel's order with FMA, and GCC
          // contracts the portable kernel's acc + a * b to the same FMA on aarch64: the same bits.
          ASSERT_EQ(got, want) << ks->name << " R " << r << " V " << v;
#endif
        }
      }
    }
  }
}

// One int8 problem, as the runtime feeds it: rows quantised from ReLU outputs, weights in
// -127..127, K padded to quads with zeros.
TEST(NetworkKernelsTest, Int8SumsAndQuantisationEqualPortableExactly) {
  std::mt19937 rng(test_seed());
  const std::vector<const KernelSet*> sets = int8_sets();
  bool any = false;
  for (const KernelSet* ks : sets) {
    if (ks->i8[0][0] == nullptr) continue;
    std::printf("int8 kernels checked: %s (%s)\n", ks->name, ks->i8_name);
    any = true;
    for (int rep = 0; rep < 3; ++rep) {
      for (int r = 1; r <= kMaxRows; ++r) {
        for (int v = 1; v <= kMaxVectors; ++v) {
          const int k_quads = 1 + static_cast<int>(rng() % 64);
          const int n = 4 * k_quads;
          const std::size_t cols = static_cast<std::size_t>(kLanes * v);
          std::vector<std::vector<uint8_t>> q(static_cast<std::size_t>(r),
                                              std::vector<uint8_t>(static_cast<std::size_t>(n)));
          std::vector<float> scale(static_cast<std::size_t>(r));
          for (int i = 0; i < r; ++i) {
            // Activations after a ReLU: about half zero, one row all zero now and then.
            std::vector<float> x = uniform<float>(rng, static_cast<std::size_t>(n), -3, 5);
            if (rng() % 7 == 0) std::fill(x.begin(), x.end(), -1.0f);
            std::vector<uint8_t> want(static_cast<std::size_t>(n));
            const float s_want = portable_kernels().quantise_u8(x.data(), n, want.data());
            const float s_got = ks->quantise_u8(x.data(), n, q[static_cast<std::size_t>(i)].data());
            ASSERT_EQ(s_got, s_want) << ks->name;
            ASSERT_EQ(q[static_cast<std::size_t>(i)], want) << ks->name << " n " << n;
            for (uint8_t e : want) ASSERT_LE(e, kActMax);
            scale[static_cast<std::size_t>(i)] = s_want;
          }
          std::uniform_int_distribution<int> w(-127, 127);
          std::vector<int8_t> b(cols * static_cast<std::size_t>(n));
          for (int8_t& e : b) e = static_cast<int8_t>(w(rng));
          // The extremes: every activation at the maximum against +-127 weights.
          if (rep == 0) {
            std::fill(q[0].begin(), q[0].end(), static_cast<uint8_t>(kActMax));
            for (std::size_t e = 0; e < b.size(); ++e) b[e] = e % 3 == 0 ? -127 : 127;
          }
          const std::vector<float> ws = uniform<float>(rng, cols, 0.001, 0.02);
          const std::vector<float> bias = uniform<float>(rng, cols, -1, 1);
          const bool relu = rng() % 2 == 0;
          std::vector<float> want(cols * r, 0.5f), got(cols * r, 0.5f);
          std::vector<const uint8_t*> a;
          std::vector<float*> cw, cg;
          for (int i = 0; i < r; ++i) {
            a.push_back(q[static_cast<std::size_t>(i)].data());
            cw.push_back(want.data() + cols * i);
            cg.push_back(got.data() + cols * i);
          }
          const float* bp = rep == 1 ? nullptr : bias.data();
          portable_kernels().i8[r - 1][v - 1](a.data(), b.data(), k_quads, cw.data(), bp,
                                              scale.data(), ws.data(), relu);
          ks->i8[r - 1][v - 1](a.data(), b.data(), k_quads, cg.data(), bp, scale.data(), ws.data(),
                               relu);
          ASSERT_EQ(got, want) << ks->name << " (" << ks->i8_name << ") R " << r << " V " << v
                               << " quads " << k_quads;
        }
      }
    }
  }
  if (!any) GTEST_SKIP() << "no vector int8 kernels on this CPU: the portable ones are checked";
}

TEST(NetworkKernelsTest, QuantisationRefusesNonFiniteRows) {
  std::vector<const KernelSet*> sets = vector_sets();
  sets.push_back(&portable_kernels());
  for (const KernelSet* ks : sets) {
    if (ks->quantise_u8 == nullptr) continue;
    for (float bad : {std::nanf(""), INFINITY, -INFINITY}) {
      for (int at : {0, 5, 16, 20}) {
        std::vector<float> x(21, 1.0f);
        x[static_cast<std::size_t>(at)] = bad;
        std::vector<uint8_t> q(21, 9);
        EXPECT_TRUE(std::isnan(ks->quantise_u8(x.data(), 21, q.data()))) << ks->name << " " << at;
        for (uint8_t e : q) EXPECT_EQ(e, 0);
      }
    }
    std::vector<float> zeros(40, 0.0f);
    std::vector<uint8_t> q(40, 9);
    EXPECT_EQ(ks->quantise_u8(zeros.data(), 40, q.data()), 0.0f) << ks->name;
  }
}

TEST(NetworkKernelsTest, Bfloat16MatchesPortable) {
  std::mt19937 rng(test_seed());
  bool any = false;
  for (const KernelSet* ks : vector_sets()) {
    if (ks->bf16[0][0] == nullptr) continue;
    any = true;
    for (int r = 1; r <= kMaxRows; ++r) {
      for (int v = 1; v <= kMaxVectors; ++v) {
        const int k_pairs = 1 + static_cast<int>(rng() % 40);
        const std::size_t cols = static_cast<std::size_t>(kLanes * v);
        const int n = 2 * k_pairs + 3;
        std::vector<std::vector<uint16_t>> h(static_cast<std::size_t>(r));
        for (auto& row : h) {
          const std::vector<float> x = uniform<float>(rng, static_cast<std::size_t>(n), -2, 2);
          std::vector<uint16_t> want(x.size());
          row.resize(x.size());
          const bool relu = rng() % 2 == 0;
          portable_kernels().to_bf16(x.data(), want.data(), n, relu);
          ks->to_bf16(x.data(), row.data(), n, relu);
          ASSERT_EQ(row, want) << ks->name;
        }
        std::vector<uint16_t> b(cols * 2 * static_cast<std::size_t>(k_pairs));
        for (uint16_t& e : b) e = to_bf16_bits(static_cast<float>(rng() % 2001) / 1000.0f - 1.0f);
        const std::vector<float> bias = uniform<float>(rng, cols, -1, 1);
        std::vector<float> want(cols * r), got(cols * r);
        std::vector<const uint16_t*> a;
        std::vector<float*> cw, cg;
        for (int i = 0; i < r; ++i) {
          a.push_back(h[static_cast<std::size_t>(i)].data());
          cw.push_back(want.data() + cols * i);
          cg.push_back(got.data() + cols * i);
        }
        portable_kernels().bf16[r - 1][v - 1](a.data(), b.data(), k_pairs, cw.data(), bias.data(),
                                              true);
        ks->bf16[r - 1][v - 1](a.data(), b.data(), k_pairs, cg.data(), bias.data(), true);
        for (std::size_t j = 0; j < want.size(); ++j) {
          ASSERT_NEAR(got[j], want[j], 1e-4 * k_pairs) << ks->name << " R " << r << " V " << v;
        }
      }
    }
  }
  if (!any) GTEST_SKIP() << "no vector bfloat16 kernels on this CPU: the portable ones are checked";
}

TEST(NetworkKernelsTest, ElementWiseKernelsEqualPortableExactly) {
  std::mt19937 rng(test_seed());
  const KernelSet& p = portable_kernels();
  for (const KernelSet* ks : vector_sets()) {
    for (int n : {1, 7, 8, 15, 16, 17, 64, 100}) {
      std::vector<float> x = uniform<float>(rng, static_cast<std::size_t>(n), -1, 1), y = x;
      p.relu(x.data(), n);
      ks->relu(y.data(), n);
      ASSERT_EQ(x, y) << ks->name;
    }
    for (int c : {3, 16, 24, 40, 64}) {
      const int ld = (c + kLanes - 1) / kLanes * kLanes, cells = 1 + static_cast<int>(rng() % 16);
      const std::vector<float> x = uniform<float>(rng, static_cast<std::size_t>(cells * ld), -1, 1);
      std::vector<float> want(2 * static_cast<std::size_t>(c) + 8, 7.0f), got = want;
      p.pool(x.data(), cells, ld, c, want.data());
      ks->pool(x.data(), cells, ld, c, got.data());
      ASSERT_EQ(got, want) << ks->name << " c " << c;  // and nothing written past 2c
    }
    for (int c : {16, 48}) {
      std::vector<std::vector<float>> d(16), v(16), vw(16), m(16), y(4), yw(4);
      const float *dp[16], *mp[16];
      float *vp[16], *vwp[16], *yp[4], *ywp[4];
      for (int i = 0; i < 16; ++i) {
        d[i] = uniform<float>(rng, static_cast<std::size_t>(c), -1, 1);
        m[i] = uniform<float>(rng, static_cast<std::size_t>(c), -1, 1);
        v[i].assign(static_cast<std::size_t>(c), 0);
        vw[i] = v[i];
        dp[i] = d[i].data();
        mp[i] = m[i].data();
        vp[i] = v[i].data();
        vwp[i] = vw[i].data();
      }
      for (int q = 0; q < 4; ++q) {
        y[q].assign(static_cast<std::size_t>(c), 0);
        yw[q] = y[q];
        yp[q] = y[q].data();
        ywp[q] = yw[q].data();
      }
      p.winograd_input(dp, vwp, c);
      ks->winograd_input(dp, vp, c);
      for (int i = 0; i < 16; ++i) ASSERT_EQ(v[i], vw[i]) << ks->name;
      const std::vector<float> bias = uniform<float>(rng, static_cast<std::size_t>(c), -1, 1);
      p.winograd_output(mp, ywp, c, bias.data(), true);
      ks->winograd_output(mp, yp, c, bias.data(), true);
      for (int q = 0; q < 4; ++q) ASSERT_EQ(y[q], yw[q]) << ks->name;
    }
  }
}

TEST(NetworkKernelsTest, TheCapLimitsTheChoice) {
  EXPECT_EQ(&best_kernels(KernelIsa::kPortable), &portable_kernels());
  const KernelSet& best = best_kernels(KernelIsa::kAvx512);
  if (const KernelSet* avx512 = avx512_kernels()) {
    EXPECT_EQ(&best, avx512);
  }
  if (avx2_kernels() != nullptr) {
    EXPECT_EQ(&best_kernels(KernelIsa::kAvx2), avx2_kernels());
  }
  if (const KernelSet* neon = neon_kernels()) {
    EXPECT_EQ(&best, neon);
    EXPECT_EQ(&best_kernels(KernelIsa::kNeon), neon);
  }
#if defined(__aarch64__)
  EXPECT_NE(neon_kernels(), nullptr);  // every aarch64 CPU has NEON
#else
  EXPECT_EQ(neon_kernels(), nullptr);
#endif
  KernelIsa isa = KernelIsa::kPortable;
  EXPECT_TRUE(parse_isa("avx2", &isa));
  EXPECT_EQ(isa, KernelIsa::kAvx2);
  EXPECT_FALSE(parse_isa("sse9", &isa));
  // What runs here, for the log.
  std::printf("kernels here: %s (int8 %s); SKINBUS_MAX_ISA cap %s\n",
              best_kernels(env_isa_cap()).name, best_kernels(env_isa_cap()).i8_name,
              isa_name(env_isa_cap()));
}

}  // namespace
}  // namespace skinbus::estimators::detail
