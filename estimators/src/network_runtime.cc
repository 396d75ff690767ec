#include "skinbus/estimators/network_runtime.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "network_kernels.h"
#include "network_onednn.h"

namespace skinbus::estimators {
namespace {

using detail::KernelSet;
// RuntimeOptions::max_isa names the kernel sets in their order.
static_assert(static_cast<int>(RuntimeIsa::kAvx512) ==
                  static_cast<int>(detail::KernelIsa::kAvx512) &&
              static_cast<int>(RuntimeIsa::kAvx2) == static_cast<int>(detail::KernelIsa::kAvx2) &&
              static_cast<int>(RuntimeIsa::kNeon) == static_cast<int>(detail::KernelIsa::kNeon) &&
              static_cast<int>(RuntimeIsa::kPortable) ==
                  static_cast<int>(detail::KernelIsa::kPortable));
using detail::kLanes;
using detail::kMaxRows;
using detail::kMaxVectors;

// Samples per pass of the kernel backends: their activations (16 x 16 cells x 256 floats for
// the seed CNN's widest layer) stay in L2 while the weights stream once per pass.
constexpr int kKernelChunk = 16;
// K steps per pass of the kernels over a weight panel: bfloat16 pairs and int8 quads in blocks of
// 64, whose panel slice (64 x 64 columns, 16 KB) stays in L1 while every row block passes over
// it; floats in blocks of 256 (64 KB, from L2), as measured faster: each pass loads and stores
// its rows' accumulators, and the float32 kernel's loads keep up from L2.
constexpr int kKBlock = 64;
constexpr int kKBlockF32 = 256;
// A batch of at least this many samples runs float32 convolutions cell by cell (every tap of a
// cell in one kernel call, the samples as rows); smaller ones tap by tap (the cells as rows).
constexpr int kByCellMinSamples = 4;
constexpr int kMaxTaps = 9;
// Winograd F(2x2, 3x3): a 4x4 input tile and 16 products per 2x2 output tile.
constexpr int kWinogradPoints = 16;
// kAuto runs Winograd for the convolutions with at least this many input channels: narrower
// ones spend more on the transforms and the 16 short kernel calls per row block than they save
// (measured on the seed CNN at widths 1 to 0.125; docs/benchmarks/runtime.md).
constexpr int kWinogradMinInputs = 32;
constexpr std::size_t kAlign = 64;
constexpr int kMaxThreads = 64;
constexpr int kMaxSpinUs = 100000;
// kInt8 runs a layer in int8 when it carries at least 1/kInt8MinShare of the multiply-adds
// (seed CNN: conv1-conv3, fc0, fc1). 1/20 (conv2, conv3, fc0) moved the trained model's XY by
// 0.10 mm instead of 0.13 mm, but was only 1.9x as fast as Winograd float32 at batch 1, not 2.3x
// (docs/benchmarks/runtime.md).
constexpr int64_t kInt8MinShare = 40;

int round_up(int n, int m) {
  return (n + m - 1) / m * m;
}

// `rows` kernel rows split into the fewest blocks of at most kMaxRows, of nearly equal size
// (16 = 6 + 5 + 5, not 6 + 6 + 4): block `block` of row_blocks(rows) is [first, first + count).
int row_blocks(int rows) {
  return (rows + kMaxRows - 1) / kMaxRows;
}
struct RowBlock {
  int first, count;
};
RowBlock row_block(int rows, int block, int blocks) {
  const int first = rows * block / blocks;
  return {first, rows * (block + 1) / blocks - first};
}

// A zero-filled, 64-byte aligned array.
template <typename T>
class Aligned {
 public:
  void assign(std::size_t n) {
    const std::size_t bytes = (n * sizeof(T) + kAlign - 1) / kAlign * kAlign;
    p_.reset(static_cast<T*>(std::aligned_alloc(kAlign, bytes == 0 ? kAlign : bytes)));
    // Sizes are bounded by validate_model() (a few MB at most): failing here is running out of
    // memory, as fatal as operator new failing, but without an exception.
    if (p_ == nullptr) std::abort();
    std::memset(static_cast<void*>(p_.get()), 0, bytes == 0 ? kAlign : bytes);
    n_ = n;
  }
  T* data() const { return p_.get(); }
  std::size_t size() const { return n_; }

 private:
  struct Free {
    void operator()(T* p) const { std::free(p); }
  };
  std::unique_ptr<T, Free> p_;
  std::size_t n_ = 0;
};

// Spins (with the CPU's pause hint) until `done()` or `spin_us` have passed. A sleeping thread's
// futex wake-up costs tens to hundreds of microseconds on a virtual machine, as much as a batch of
// a few samples: the pool's threads spin this long before they sleep.
template <typename Done>
void spin_until(int spin_us, Done done) {
  if (spin_us <= 0) return;
  const auto until = std::chrono::steady_clock::now() + std::chrono::microseconds(spin_us);
  for (;;) {
    for (int i = 0; i < 64; ++i) {
      if (done()) return;
#if defined(__x86_64__) || defined(__i386__)
      __builtin_ia32_pause();
#endif
    }
    if (std::chrono::steady_clock::now() >= until) return;
  }
}

// A persistent pool: the caller runs part 0, worker w runs part w; every worker acknowledges
// every job, so no worker reads a job while the next is being posted.
class WorkerPool {
 public:
  using Fn = void (*)(void* ctx, int part);

  WorkerPool(int workers, int spin_us, bool single_openmp) : spin_us_(spin_us) {
    for (int w = 0; w < workers; ++w) {
      threads_.emplace_back([this, w, single_openmp] { loop(w + 1, single_openmp); });
    }
  }
  ~WorkerPool() {
    stop_.store(true, std::memory_order_relaxed);
    generation_.fetch_add(1, std::memory_order_release);
    generation_.notify_all();
    for (std::thread& t : threads_) t.join();
  }
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  int workers() const { return static_cast<int>(threads_.size()); }

  void run(int parts, Fn fn, void* ctx) {
    if (parts <= 1 || threads_.empty()) {
      for (int p = 0; p < parts; ++p) fn(ctx, p);
      return;
    }
    fn_ = fn;
    ctx_ = ctx;
    parts_ = parts;
    pending_.store(static_cast<int>(threads_.size()), std::memory_order_relaxed);
    generation_.fetch_add(1, std::memory_order_release);
    generation_.notify_all();
    fn(ctx, 0);
    spin_until(spin_us_, [&] { return pending_.load(std::memory_order_acquire) == 0; });
    for (int p = pending_.load(std::memory_order_acquire); p != 0;
         p = pending_.load(std::memory_order_acquire)) {
      pending_.wait(p, std::memory_order_acquire);
    }
  }

 private:
  void loop(int part, bool single_openmp) {
    if (single_openmp) detail::set_openmp_threads(1);
    uint32_t seen = 0;
    for (;;) {
      spin_until(spin_us_, [&] { return generation_.load(std::memory_order_acquire) != seen; });
      generation_.wait(seen, std::memory_order_acquire);
      seen = generation_.load(std::memory_order_acquire);
      if (stop_.load(std::memory_order_relaxed)) return;
      if (part < parts_) fn_(ctx_, part);
      if (pending_.fetch_sub(1, std::memory_order_acq_rel) == 1) pending_.notify_one();
    }
  }

  const int spin_us_;
  std::vector<std::thread> threads_;
  std::atomic<uint32_t> generation_{0};
  std::atomic<int> pending_{0};
  std::atomic<bool> stop_{false};
  Fn fn_ = nullptr;
  void* ctx_ = nullptr;
  int parts_ = 0;
};

// One column block of a packed layer: columns [col0, col0 + 16 * vectors), its panels for every
// tap consecutive from `offset` (elements of the packed array).
struct ColBlock {
  int col0 = 0, vectors = 0;
  std::size_t offset = 0, panel = 0;  // panel: elements of one tap's panel
};

struct KernelLayer {
  bool conv = false, relu = true;
  bool int8 = false;      // u8 activations x s8 weights (else float32 or bfloat16 as the runtime)
  bool winograd = false;  // a float32 convolution as Winograd F(2x2, 3x3): 16 panels, not taps
  int k = 0, k_pairs = 0, k_quads = 0, n = 0, n_ld = 0;
  std::vector<ColBlock> blocks;  // offsets into w8 when int8, else w32 or w16
  Aligned<float> bias;           // n_ld
  Aligned<float> w_scale;        // int8: weight scales per tap and output channel [tap][n_ld]
};

// The in-bounds pairs of one 3x3 tap over the grid.
struct Tap {
  int weight_tap = 4;  // ky * 3 + kx
  std::vector<int> out_cell, in_cell;
  // The same over a chunk of samples: rows (sample * cells + cell) in sample order.
  std::vector<int> chunk_out, chunk_in;
};

// The in-bounds taps of one output cell, in the order of Impl::taps.
struct CellTaps {
  std::vector<int> tap;      // index into Impl::taps
  std::vector<int> in_cell;  // the input cell each reads
};

// One 2x2 output tile of the grid for Winograd convolutions: its 4x4 input cells (row-major,
// -1 outside the grid: zero padding) and its 2x2 output cells (-1 outside: discarded).
struct WinogradTile {
  int in_cell[kWinogradPoints];
  int out_cell[4];
};

// Per thread: input, activations and scratch, sized at create.
struct Slot {
  Aligned<float> x;            // normalised input rows (kernel backends)
  Aligned<float> f0, f1;       // float activations
  Aligned<uint16_t> h;         // bfloat16 activations
  Aligned<uint8_t> q;          // int8 path: quantised activations
  std::vector<float> q_scale;  // int8 path: scale of each row of q
  std::vector<uint8_t> ok;     // channel mask scratch
  std::vector<int> index;      // chunk row -> sample
  std::vector<double> raw;     // chunk outputs, physical units
  Aligned<float> wv;           // Winograd: transformed input [point][row][a_ld]
  Aligned<float> wm;           // Winograd: products of one column block [point][row][64]
  Aligned<float> sink;         // Winograd: where output cells outside the grid go
};

}  // namespace

struct NetworkRuntime::Impl {
  RuntimeOptions opt;
  RuntimeBackend backend = RuntimeBackend::kKernels;
  std::string kernel_name;
  bool cnn = false;
  int channels = 0, outputs = 0, cells = 1, chunk = kKernelChunk;
  int x_row = 0;          // floats per sample in an input buffer
  std::vector<int> dest;  // channel -> offset in an input row
  std::vector<float> in_mean, in_inv_scale;
  std::vector<double> out_mean, out_scale;
  int field_index[4] = {-1, -1, -1, -1};  // u, v, depth, force -> output index
  double half_u_mm = 70, half_v_mm = 70, max_depth_mm = 9;

  // Kernel backends.
  const KernelSet* ks = nullptr;
  bool bf16 = false, int8 = false;
  std::vector<KernelLayer> layers;
  std::vector<Tap> taps;            // centre first
  std::vector<CellTaps> cell_taps;  // per output cell
  bool winograd = false;            // some float32 convolutions run as Winograd F(2x2, 3x3)
  int64_t macs = 0;                 // multiply-adds per sample as computed
  std::vector<NetworkRuntime::LayerCost> costs;  // per layer, as computed
  std::vector<WinogradTile> wtiles;
  Aligned<float> zeros;  // a zero row as wide as the widest layer
  int last_conv = -1;
  Aligned<float> w32;
  Aligned<uint16_t> w16;
  Aligned<int8_t> w8;
  // oneDNN backend.
  std::unique_ptr<detail::OneDnnNet> dnn;

  std::vector<Slot> slots;
  std::unique_ptr<WorkerPool> pool;

  Status build_kernels(const ModelFile& model);
  void forward_kernels(Slot& s, int n);
  // One column block of a float32 convolution over n samples, cell by cell (ReLU included).
  void forward_cell_block(const KernelLayer& l, const ColBlock& b, const float* a32, int a_ld,
                          float* out, int n) const;
  // A float32 convolution over n samples as Winograd F(2x2, 3x3) (bias and ReLU included).
  void forward_winograd(const KernelLayer& l, Slot& s, const float* a32, int a_ld, float* out,
                        int n) const;
  // Runs the first n rows of slot's input; fills slot.raw (n x outputs, physical units).
  void forward(int slot, int n);
  float* input(int slot) {
    return dnn ? dnn->input(slot) : slots[static_cast<std::size_t>(slot)].x.data();
  }
};

namespace {

const char* output_names[4] = {"u_mm", "v_mm", "depth_mm", "force_n"};

}  // namespace

Status NetworkRuntime::Impl::build_kernels(const ModelFile& model) {
  const Architecture& a = model.meta.architecture;
  // Convolutions: Winograd a candidate for float32 (kept below where it computes less), for the
  // layers with kWinogradMinInputs inputs or more unless asked for every layer.
  winograd = cnn && !bf16 && !int8 && opt.convolution != RuntimeConvolution::kDirect;
  const int winograd_min_inputs =
      opt.convolution == RuntimeConvolution::kWinograd ? 0 : kWinogradMinInputs;
  // Taps of the grid, centre first (it covers every cell, so it initialises every row).
  if (cnn) {
    for (int t : {4, 0, 1, 2, 3, 5, 6, 7, 8}) {
      Tap tap;
      tap.weight_tap = t;
      const int dy = t / 3 - 1, dx = t % 3 - 1;
      for (int r = 0; r < a.grid_rows; ++r) {
        for (int c = 0; c < a.grid_cols; ++c) {
          const int rr = r + dy, cc = c + dx;
          if (rr < 0 || rr >= a.grid_rows || cc < 0 || cc >= a.grid_cols) continue;
          tap.out_cell.push_back(r * a.grid_cols + c);
          tap.in_cell.push_back(rr * a.grid_cols + cc);
        }
      }
      const int cells_n = a.grid_rows * a.grid_cols;
      for (int sample = 0; sample < chunk; ++sample) {
        for (std::size_t p = 0; p < tap.out_cell.size(); ++p) {
          tap.chunk_out.push_back(sample * cells_n + tap.out_cell[p]);
          tap.chunk_in.push_back(sample * cells_n + tap.in_cell[p]);
        }
      }
      if (!tap.out_cell.empty()) taps.push_back(std::move(tap));
    }
    if (winograd) {
      for (int ty = 0; ty < a.grid_rows; ty += 2) {
        for (int tx = 0; tx < a.grid_cols; tx += 2) {
          WinogradTile tile;
          auto cell = [&](int r, int c) {
            return r < 0 || r >= a.grid_rows || c < 0 || c >= a.grid_cols ? -1
                                                                          : r * a.grid_cols + c;
          };
          for (int p = 0; p < kWinogradPoints; ++p) {
            tile.in_cell[p] = cell(ty - 1 + p / 4, tx - 1 + p % 4);
          }
          for (int q = 0; q < 4; ++q) tile.out_cell[q] = cell(ty + q / 2, tx + q % 2);
          wtiles.push_back(tile);
        }
      }
    }
    cell_taps.resize(static_cast<std::size_t>(a.grid_rows * a.grid_cols));
    for (std::size_t t = 0; t < taps.size(); ++t) {
      for (std::size_t p = 0; p < taps[t].out_cell.size(); ++p) {
        CellTaps& ct = cell_taps[static_cast<std::size_t>(taps[t].out_cell[p])];
        ct.tap.push_back(static_cast<int>(t));
        ct.in_cell.push_back(taps[t].in_cell[p]);
      }
    }
  }
  // Layer shapes and packed sizes.
  struct Source {
    const Tensor* w;
    const Tensor* b;
  };
  std::vector<Source> src;
  int in = cnn ? 3 : channels;
  std::size_t packed = 0, packed8 = 0;
  int64_t tap_cells = 0;  // in-bounds (cell, tap) pairs of a convolution
  for (const Tap& tap : taps) tap_cells += static_cast<int64_t>(tap.out_cell.size());
  // kAuto: Winograd only where its 16 products per tile are fewer than the in-bounds taps (the
  // 4x4 grid: 64 against 100; 3x3: 64 against 49).
  if (winograd && opt.convolution == RuntimeConvolution::kAuto &&
      int64_t{kWinogradPoints} * static_cast<int64_t>(wtiles.size()) >= tap_cells) {
    winograd = false;
    wtiles.clear();
  }
  const int64_t total_macs = model.macs();
  bool any_winograd = false;
  auto add_layer = [&](const std::string& name, bool conv, int out, bool relu) {
    KernelLayer l;
    l.conv = conv;
    l.relu = relu;
    // int8 serves the layers whose input is a ReLU output (non-negative, so unsigned 8 bits
    // lose no sign) and that carry at least 1/kInt8MinShare of the network's multiply-adds; the
    // first layer (signed normalised fields), the head and the small layers stay float32: every
    // int8 layer adds about the same rounding noise whatever its size, so small ones would cost
    // accuracy for little speed (docs/benchmarks/runtime.md).
    const int64_t layer_macs = static_cast<int64_t>(in) * out * (conv ? tap_cells : 1);
    l.int8 = int8 && !layers.empty() && relu && layer_macs * kInt8MinShare >= total_macs;
    l.winograd = conv && winograd && in >= winograd_min_inputs;
    any_winograd = any_winograd || l.winograd;
    NetworkRuntime::LayerCost cost;
    cost.macs = l.winograd
                    ? int64_t{kWinogradPoints} * static_cast<int64_t>(wtiles.size()) * in * out
                    : layer_macs;
    macs += cost.macs;
    l.k = in;
    l.k_pairs = (in + 1) / 2;
    l.k_quads = (in + 3) / 4;
    l.n = out;
    l.n_ld = round_up(out, kLanes);
    const int ntaps = l.winograd ? kWinogradPoints : conv ? static_cast<int>(taps.size()) : 1;
    const int k_rows = l.int8 ? 4 * l.k_quads : bf16 ? 2 * l.k_pairs : l.k;
    std::size_t& at = l.int8 ? packed8 : packed;
    const std::size_t first = at;
    for (int col0 = 0; col0 < l.n_ld; col0 += kLanes * kMaxVectors) {
      ColBlock b;
      b.col0 = col0;
      b.vectors = std::min(kMaxVectors, (l.n_ld - col0) / kLanes);
      b.panel = static_cast<std::size_t>(k_rows) * kLanes * b.vectors;
      b.offset = at;
      at += b.panel * static_cast<std::size_t>(ntaps);
      l.blocks.push_back(b);
    }
    const std::size_t element = l.int8 ? sizeof(int8_t) : bf16 ? sizeof(uint16_t) : sizeof(float);
    cost.weight_bytes = static_cast<int64_t>((at - first) * element);
    costs.push_back(cost);
    l.bias.assign(static_cast<std::size_t>(l.n_ld));
    if (l.int8)
      l.w_scale.assign(static_cast<std::size_t>(l.n_ld) * static_cast<std::size_t>(ntaps));
    src.push_back({model.find(name + ".weight"), model.find(name + ".bias")});
    layers.push_back(std::move(l));
    in = out;
  };
  if (cnn) {
    for (std::size_t k = 0; k < a.conv_channels.size(); ++k) {
      add_layer("conv" + std::to_string(k), true, a.conv_channels[k], true);
    }
    last_conv = static_cast<int>(layers.size()) - 1;
    in = 2 * in;
  }
  for (std::size_t k = 0; k < a.hidden.size(); ++k) {
    add_layer("fc" + std::to_string(k), false, a.hidden[k], true);
  }
  add_layer("head", false, outputs, false);
  winograd = any_winograd;
  // An int8 kernel call sums at most 4 * kKBlock = 256 products of at most 255 * 127 in int32:
  // no overflow whatever the layer's size.

  // Pack: panel[k][cols] (float32), panel[k/2][cols][2] (bfloat16) or panel[k/4][cols][4]
  // (int8), zeros beyond the shape.
  if (bf16) {
    w16.assign(packed);
  } else {
    w32.assign(packed);
  }
  w8.assign(packed8);
  for (std::size_t li = 0; li < layers.size(); ++li) {
    KernelLayer& l = layers[li];
    const float* w = src[li].w->data.data();
    std::copy(src[li].b->data.begin(), src[li].b->data.end(), l.bias.data());
    const int ntaps = l.winograd ? kWinogradPoints : l.conv ? static_cast<int>(taps.size()) : 1;
    // Winograd: U = G g G^T of every (output, input) pair's 3x3 kernel g, in double, rounded
    // once to float; G = [1 0 0; 1/2 1/2 1/2; 1/2 -1/2 1/2; 0 0 1].
    std::vector<float> u;
    if (l.winograd) {
      static constexpr double kG[4][3] = {{1, 0, 0}, {0.5, 0.5, 0.5}, {0.5, -0.5, 0.5}, {0, 0, 1}};
      u.resize(static_cast<std::size_t>(l.n) * static_cast<std::size_t>(l.k) * kWinogradPoints);
      for (std::size_t pair = 0; pair < static_cast<std::size_t>(l.n) * l.k; ++pair) {
        const float* g = w + pair * 9;
        double gt[4][3];  // G g
        for (int r = 0; r < 4; ++r) {
          for (int c = 0; c < 3; ++c) {
            gt[r][c] = 0;
            for (int e = 0; e < 3; ++e) gt[r][c] += kG[r][e] * g[e * 3 + c];
          }
        }
        for (int r = 0; r < 4; ++r) {
          for (int c = 0; c < 4; ++c) {
            double sum = 0;
            for (int e = 0; e < 3; ++e) sum += gt[r][e] * kG[c][e];
            u[pair * kWinogradPoints + static_cast<std::size_t>(r * 4 + c)] =
                static_cast<float>(sum);
          }
        }
      }
    }
    auto weight = [&](int o, int i, int t) -> float {
      if (o >= l.n || i >= l.k) return 0.0f;
      if (!l.conv) return w[static_cast<std::size_t>(o) * l.k + i];
      if (l.winograd) {
        return u[(static_cast<std::size_t>(o) * l.k + i) * kWinogradPoints +
                 static_cast<std::size_t>(t)];
      }
      return w[(static_cast<std::size_t>(o) * l.k + i) * 9 + static_cast<std::size_t>(t)];
    };
    if (l.int8) {
      // Symmetric per tap and output channel: scale = max |w| / 127 over its inputs.
      for (int t = 0; t < ntaps; ++t) {
        const int wt = l.conv ? taps[static_cast<std::size_t>(t)].weight_tap : 0;
        for (int o = 0; o < l.n; ++o) {
          float mx = 0.0f;
          for (int i = 0; i < l.k; ++i) mx = std::max(mx, std::fabs(weight(o, i, wt)));
          l.w_scale.data()[t * l.n_ld + o] = mx / 127.0f;
        }
      }
    }
    auto weight_s8 = [&](int o, int i, int t, int wt) -> int8_t {
      if (o >= l.n) return 0;
      const float scale = l.w_scale.data()[t * l.n_ld + o];
      if (scale == 0.0f) return 0;
      const float q = std::nearbyint(weight(o, i, wt) / scale);
      return static_cast<int8_t>(std::clamp(q, -127.0f, 127.0f));
    };
    for (const ColBlock& b : l.blocks) {
      const int cols = kLanes * b.vectors;
      for (int t = 0; t < ntaps; ++t) {
        const int wt = l.winograd ? t : l.conv ? taps[static_cast<std::size_t>(t)].weight_tap : 0;
        const std::size_t base = b.offset + b.panel * static_cast<std::size_t>(t);
        if (l.int8) {
          for (int kq = 0; kq < l.k_quads; ++kq) {
            for (int j = 0; j < cols; ++j) {
              for (int e = 0; e < 4; ++e) {
                w8.data()[base + (static_cast<std::size_t>(kq) * cols + j) * 4 + e] =
                    weight_s8(b.col0 + j, 4 * kq + e, t, wt);
              }
            }
          }
        } else if (bf16) {
          for (int kp = 0; kp < l.k_pairs; ++kp) {
            for (int j = 0; j < cols; ++j) {
              for (int e = 0; e < 2; ++e) {
                w16.data()[base + (static_cast<std::size_t>(kp) * cols + j) * 2 + e] =
                    detail::to_bf16_bits(weight(b.col0 + j, 2 * kp + e, wt));
              }
            }
          }
        } else {
          for (int kk = 0; kk < l.k; ++kk) {
            for (int j = 0; j < cols; ++j) {
              w32.data()[base + static_cast<std::size_t>(kk) * cols + j] =
                  weight(b.col0 + j, kk, wt);
            }
          }
        }
      }
    }
  }

  // Buffers.
  int widest = round_up(cnn ? 3 : channels, kLanes);
  for (const KernelLayer& l : layers) widest = std::max(widest, l.n_ld);
  if (cnn)
    widest = std::max(widest, round_up(2 * layers[static_cast<std::size_t>(last_conv)].n, kLanes));
  const std::size_t rows = static_cast<std::size_t>(chunk) * static_cast<std::size_t>(cells);
  const std::size_t tile_rows = static_cast<std::size_t>(chunk) * wtiles.size();
  zeros.assign(static_cast<std::size_t>(widest));
  for (Slot& s : slots) {
    if (winograd) {
      s.wv.assign(kWinogradPoints * tile_rows * static_cast<std::size_t>(widest));
      s.wm.assign(kWinogradPoints * tile_rows * kLanes * kMaxVectors);
      s.sink.assign(static_cast<std::size_t>(widest));
    }
    s.x.assign(static_cast<std::size_t>(chunk) * static_cast<std::size_t>(x_row));
    s.f0.assign(rows * static_cast<std::size_t>(widest));
    s.f1.assign(rows * static_cast<std::size_t>(widest));
    if (bf16) s.h.assign(rows * static_cast<std::size_t>(widest));
    if (int8) {
      s.q.assign(rows * static_cast<std::size_t>(widest));
      s.q_scale.assign(rows, 0.0f);
    }
  }
  return Status::Ok();
}

void NetworkRuntime::Impl::forward_cell_block(const KernelLayer& l, const ColBlock& b,
                                              const float* a32, int a_ld, float* out, int n) const {
  const float* a_rows[kMaxTaps * kMaxRows];
  const float* panels[kMaxTaps];
  float* c_rows[kMaxRows];
  const int blocks = row_blocks(n);
  for (int cell = 0; cell < cells; ++cell) {
    const CellTaps& ct = cell_taps[static_cast<std::size_t>(cell)];
    const int segments = static_cast<int>(ct.tap.size());
    for (int seg = 0; seg < segments; ++seg) {
      panels[seg] = w32.data() + b.offset +
                    b.panel * static_cast<std::size_t>(ct.tap[static_cast<std::size_t>(seg)]);
    }
    for (int block = 0; block < blocks; ++block) {
      const auto [r0, r] = row_block(n, block, blocks);
      for (int i = 0; i < r; ++i) {
        const std::ptrdiff_t sample_row = static_cast<std::ptrdiff_t>(r0 + i) * cells;
        c_rows[i] = out + (sample_row + cell) * l.n_ld + b.col0;
        for (int seg = 0; seg < segments; ++seg) {
          a_rows[seg * r + i] =
              a32 + (sample_row + ct.in_cell[static_cast<std::size_t>(seg)]) * a_ld;
        }
      }
      ks->f32[r - 1][b.vectors - 1](a_rows, panels, segments, l.k, c_rows, l.bias.data() + b.col0,
                                    l.relu);
    }
  }
}

void NetworkRuntime::Impl::forward_winograd(const KernelLayer& l, Slot& s, const float* a32,
                                            int a_ld, float* out, int n) const {
  const int tiles = static_cast<int>(wtiles.size());
  const int rows = n * tiles;  // row = sample * tiles + tile
  const std::ptrdiff_t point_rows = rows;
  constexpr int kMld = kLanes * kMaxVectors;
  const float* d[kWinogradPoints];
  float* v[kWinogradPoints];
  // Input transform of every tile of every sample, all a_ld channels (the pad ones are zero).
  for (int row = 0; row < rows; ++row) {
    const int sample = row / tiles;
    const WinogradTile& tile = wtiles[static_cast<std::size_t>(row % tiles)];
    for (int p = 0; p < kWinogradPoints; ++p) {
      const int cell = tile.in_cell[p];
      d[p] = cell < 0 ? zeros.data()
                      : a32 + (static_cast<std::ptrdiff_t>(sample) * cells + cell) * a_ld;
      v[p] = s.wv.data() + (p * point_rows + row) * a_ld;
    }
    ks->winograd_input(d, v, a_ld);
  }
  const float* a_rows[kMaxRows];
  float* c_rows[kMaxRows];
  const float* m[kWinogradPoints];
  float* y[4];
  const int blocks = row_blocks(rows);
  for (const ColBlock& b : l.blocks) {
    const int cols = kLanes * b.vectors;
    // The 16 products of every row for this block's columns: one matrix product per point.
    for (int p = 0; p < kWinogradPoints; ++p) {
      const float* panel = w32.data() + b.offset + b.panel * static_cast<std::size_t>(p);
      for (int k0 = 0; k0 < l.k; k0 += kKBlockF32) {
        const int kn = std::min(kKBlockF32, l.k - k0);
        const float* panel_k = panel + static_cast<std::ptrdiff_t>(k0) * cols;
        for (int block = 0; block < blocks; ++block) {
          const auto [r0, r] = row_block(rows, block, blocks);
          for (int i = 0; i < r; ++i) {
            const std::ptrdiff_t at = p * point_rows + r0 + i;
            a_rows[i] = s.wv.data() + at * a_ld + k0;
            c_rows[i] = s.wm.data() + at * kMld;
          }
          ks->f32[r - 1][b.vectors - 1](a_rows, &panel_k, 1, kn, c_rows,
                                        k0 == 0 ? zeros.data() : nullptr, false);
        }
      }
    }
    // Output transform, bias and ReLU into the cells.
    for (int row = 0; row < rows; ++row) {
      const int sample = row / tiles;
      const WinogradTile& tile = wtiles[static_cast<std::size_t>(row % tiles)];
      for (int p = 0; p < kWinogradPoints; ++p) m[p] = s.wm.data() + (p * point_rows + row) * kMld;
      for (int q = 0; q < 4; ++q) {
        const int cell = tile.out_cell[q];
        y[q] = cell < 0
                   ? s.sink.data()
                   : out + (static_cast<std::ptrdiff_t>(sample) * cells + cell) * l.n_ld + b.col0;
      }
      ks->winograd_output(m, y, cols, l.bias.data() + b.col0, l.relu);
    }
  }
}

void NetworkRuntime::Impl::forward_kernels(Slot& s, int n) {
  const float* a32 = s.x.data();
  int a_ld = cnn ? kLanes : round_up(channels, kLanes);
  if (bf16) ks->to_bf16(s.x.data(), s.h.data(), n * cells * a_ld, false);
  float* out = s.f0.data();
  const float* a_rows[kMaxRows];
  const uint16_t* h_rows[kMaxRows];
  const uint8_t* q_rows[kMaxRows];
  float q_scales[kMaxRows];
  float* c_rows[kMaxRows];
  for (std::size_t li = 0; li < layers.size(); ++li) {
    const KernelLayer& l = layers[li];
    const int rows_per_sample = l.conv ? cells : 1;
    if (l.int8) {
      // Every input row (a cell of a sample, or a sample) on its own scale.
      for (int row = 0; row < n * rows_per_sample; ++row) {
        const std::ptrdiff_t at = static_cast<std::ptrdiff_t>(row) * a_ld;
        s.q_scale[static_cast<std::size_t>(row)] = ks->quantise_u8(a32 + at, a_ld, s.q.data() + at);
      }
    }
    // float32 convolutions of a batch: cell by cell, each call summing every in-bounds tap of up
    // to kMaxRows samples' same cell (the same products in the same order as tap by tap, so the
    // same bits, without storing and reloading the accumulators between taps).
    const bool by_cell = l.conv && !l.int8 && !bf16 && n >= kByCellMinSamples;
    if (l.winograd) {
      forward_winograd(l, s, a32, a_ld, out, n);
    } else {
      for (const ColBlock& b : l.blocks) {
        if (by_cell) {
          forward_cell_block(l, b, a32, a_ld, out, n);
          continue;
        }
        const int ntaps = l.conv ? static_cast<int>(taps.size()) : 1;
        const int cols = kLanes * b.vectors;
        for (int t = 0; t < ntaps; ++t) {
          const Tap* tap = l.conv ? &taps[static_cast<std::size_t>(t)] : nullptr;
          const int nt = l.conv ? static_cast<int>(tap->out_cell.size()) : 1;
          const int total = n * nt;
          const bool relu = !l.conv && l.relu;
          const std::size_t panel = b.offset + b.panel * static_cast<std::size_t>(t);
          const int k_steps = l.int8 ? l.k_quads : bf16 ? l.k_pairs : l.k;
          const int k_block = l.int8 || bf16 ? kKBlock : kKBlockF32;
          for (int k0 = 0; k0 < k_steps; k0 += k_block) {
            const int kn = std::min(k_block, k_steps - k0);
            const bool last_k = k0 + kn == k_steps;
            const float* bias = t == 0 && k0 == 0 ? l.bias.data() + b.col0 : nullptr;
            const std::ptrdiff_t a_k = l.int8 ? 4 * k0 : bf16 ? 2 * k0 : k0;
            for (int r0 = 0; r0 < total; r0 += kMaxRows) {
              const int r = std::min(kMaxRows, total - r0);
              for (int i = 0; i < r; ++i) {
                const int in_row = l.conv ? tap->chunk_in[r0 + i] : r0 + i;
                const int out_row = l.conv ? tap->chunk_out[r0 + i] : r0 + i;
                const std::ptrdiff_t a_off = static_cast<std::ptrdiff_t>(in_row) * a_ld + a_k;
                const std::ptrdiff_t c_off = static_cast<std::ptrdiff_t>(out_row) * l.n_ld + b.col0;
                c_rows[i] = out + c_off;
                if (l.int8) {
                  q_rows[i] = s.q.data() + a_off;
                  q_scales[i] = s.q_scale[static_cast<std::size_t>(in_row)];
                } else {
                  a_rows[i] = a32 + a_off;
                  if (bf16) h_rows[i] = s.h.data() + a_off;
                }
              }
              if (l.int8) {
                ks->i8[r - 1][b.vectors - 1](
                    q_rows, w8.data() + panel + 4 * k0 * cols, kn, c_rows, bias, q_scales,
                    l.w_scale.data() + static_cast<std::ptrdiff_t>(t) * l.n_ld + b.col0,
                    relu && last_k);
              } else if (bf16) {
                ks->bf16[r - 1][b.vectors - 1](h_rows, w16.data() + panel + 2 * k0 * cols, kn,
                                               c_rows, bias, relu && last_k);
              } else {
                const float* panel_k = w32.data() + panel + k0 * cols;
                ks->f32[r - 1][b.vectors - 1](a_rows, &panel_k, 1, kn, c_rows, bias,
                                              relu && last_k);
              }
            }
          }
        }
      }
    }
    const int count = n * rows_per_sample * l.n_ld;
    if (l.conv && !by_cell && !l.winograd && (!bf16 || static_cast<int>(li) == last_conv)) {
      // A convolution's rows finish at different taps: ReLU afterwards (in the conversion to
      // bfloat16 when the next layer reads that).
      ks->relu(out, count);
    }
    float* next = out == s.f0.data() ? s.f1.data() : s.f0.data();
    a32 = out;
    a_ld = l.n_ld;
    if (static_cast<int>(li) == last_conv) {
      // Global average and max over the cells, average first.
      const int c = l.n, ld = round_up(2 * c, kLanes);
      for (int sample = 0; sample < n; ++sample) {
        float* dst = next + static_cast<std::ptrdiff_t>(sample) * ld;
        ks->pool(out + static_cast<std::ptrdiff_t>(sample) * cells * l.n_ld, cells, l.n_ld, c, dst);
        for (int j = 2 * c; j < ld; ++j) dst[j] = 0.0f;
      }
      a32 = next;
      a_ld = ld;
      next = out;
      if (bf16) ks->to_bf16(a32, s.h.data(), n * a_ld, false);
    } else if (bf16 && li + 1 < layers.size()) {
      ks->to_bf16(out, s.h.data(), count, l.conv);
    }
    out = next;
  }
  // a32 holds the head: n rows of a_ld floats.
  for (int sample = 0; sample < n; ++sample) {
    for (int j = 0; j < outputs; ++j) {
      s.raw[static_cast<std::size_t>(sample * outputs + j)] =
          static_cast<double>(a32[sample * a_ld + j]) * out_scale[static_cast<std::size_t>(j)] +
          out_mean[static_cast<std::size_t>(j)];
    }
  }
}

void NetworkRuntime::Impl::forward(int slot, int n) {
  Slot& s = slots[static_cast<std::size_t>(slot)];
  if (n <= 0) return;
  if (dnn) {
    dnn->run(slot, n);
    const float* y = dnn->output(slot);
    for (int i = 0; i < n * outputs; ++i) {
      const std::size_t j = static_cast<std::size_t>(i % outputs);
      s.raw[static_cast<std::size_t>(i)] = static_cast<double>(y[i]) * out_scale[j] + out_mean[j];
    }
    return;
  }
  forward_kernels(s, n);
}

namespace {

// One call of run()/run_outputs(), shared by the parts.
struct Call {
  NetworkRuntime::Impl* impl = nullptr;
  const double* field = nullptr;
  const uint8_t* channel_ok = nullptr;
  ContactEstimate* out = nullptr;  // estimates, or
  double* raw = nullptr;           // bare outputs
  int batch = 0, parts = 1;
};

void normalise(const NetworkRuntime::Impl& impl, const double* field, float* row) {
  for (int c = 0; c < impl.channels; ++c) {
    const std::size_t i = static_cast<std::size_t>(c);
    row[impl.dest[i]] = (static_cast<float>(field[c]) - impl.in_mean[i]) * impl.in_inv_scale[i];
  }
}

void run_part(void* ctx, int part) {
  Call& call = *static_cast<Call*>(ctx);
  NetworkRuntime::Impl& impl = *call.impl;
  Slot& s = impl.slots[static_cast<std::size_t>(part)];
  const int begin = static_cast<int>(static_cast<int64_t>(call.batch) * part / call.parts);
  const int end = static_cast<int>(static_cast<int64_t>(call.batch) * (part + 1) / call.parts);
  const std::size_t ch = static_cast<std::size_t>(impl.channels);
  float* x = impl.input(part);
  int m = 0;
  auto flush = [&] {
    impl.forward(part, m);
    for (int i = 0; i < m; ++i) {
      const std::size_t sample = static_cast<std::size_t>(s.index[static_cast<std::size_t>(i)]);
      const double* y = s.raw.data() + static_cast<std::size_t>(i * impl.outputs);
      if (call.raw != nullptr) {
        std::copy_n(y, impl.outputs, call.raw + sample * static_cast<std::size_t>(impl.outputs));
        continue;
      }
      ContactEstimate e;
      double* fields[4] = {&e.u_mm, &e.v_mm, &e.depth_mm, &e.force_n};
      for (int f = 0; f < 4; ++f) {
        if (impl.field_index[f] >= 0) *fields[f] = y[impl.field_index[f]];
      }
      flag_range(e, impl.half_u_mm, impl.half_v_mm, impl.max_depth_mm, impl.opt.margin_mm,
                 impl.opt.margin_depth_mm);
      call.out[sample] = e;
    }
    m = 0;
  };
  for (int sample = begin; sample < end; ++sample) {
    const double* field = call.field + static_cast<std::size_t>(sample) * ch;
    if (call.raw == nullptr) {
      if (call.channel_ok != nullptr) {
        std::copy_n(call.channel_ok + static_cast<std::size_t>(sample) * ch, ch, s.ok.data());
      } else {
        std::fill(s.ok.begin(), s.ok.end(), uint8_t{1});
      }
      const SampleCheck check = check_sample({field, ch}, {s.ok.data(), ch}, impl.opt.limits);
      if (check.masked > 0) {
        ContactEstimate e;
        e.flags = kEstimateRejected;
        e.reason = check.first_reason;
        call.out[sample] = e;
        continue;
      }
    }
    s.index[static_cast<std::size_t>(m)] = sample;
    normalise(impl, field, x + static_cast<std::ptrdiff_t>(m) * impl.x_row);
    if (++m == impl.chunk) flush();
  }
  flush();
}

}  // namespace

Status check_runtime_options(const RuntimeOptions& options) {
  if (options.threads < 1 || options.threads > kMaxThreads) {
    return make_error(ErrorCode::kInvalidArgument, "threads must be 1.." +
                                                       std::to_string(kMaxThreads) + ", got " +
                                                       std::to_string(options.threads));
  }
  if (options.spin_us < 0 || options.spin_us > kMaxSpinUs) {
    return make_error(ErrorCode::kInvalidArgument, "spin_us must be 0.." +
                                                       std::to_string(kMaxSpinUs) + ", got " +
                                                       std::to_string(options.spin_us));
  }
  return Status::Ok();
}

Result<NetworkRuntime> NetworkRuntime::create(const ModelFile& model,
                                              const RuntimeOptions& options) {
  if (Status st = validate_model(model); !st.ok()) return st.error();
  if (Status st = check_runtime_options(options); !st.ok()) return st.error();
  auto impl = std::make_unique<Impl>();
  Impl& im = *impl;
  im.opt = options;
  const ModelMeta& meta = model.meta;
  const Architecture& a = meta.architecture;
  im.cnn = a.kind == ArchitectureKind::kCnn;
  im.channels = meta.channels();
  im.outputs = static_cast<int>(meta.outputs.size());
  im.cells = im.cnn ? a.grid_rows * a.grid_cols : 1;
  im.half_u_mm = meta.half_u_mm;
  im.half_v_mm = meta.half_v_mm;
  im.max_depth_mm = meta.max_depth_mm;
  for (int f = 0; f < 4; ++f) {
    for (int j = 0; j < im.outputs; ++j) {
      if (meta.outputs[static_cast<std::size_t>(j)] == output_names[f]) im.field_index[f] = j;
    }
  }
  if (im.field_index[0] < 0 || im.field_index[1] < 0 || im.field_index[2] < 0) {
    return make_error(ErrorCode::kInvalidArgument,
                      "model '" + meta.name + "' lacks one of the outputs u_mm, v_mm, depth_mm");
  }
  for (int c = 0; c < im.channels; ++c) {
    const std::size_t i = static_cast<std::size_t>(c);
    im.in_mean.push_back(static_cast<float>(meta.input_mean[i]));
    im.in_inv_scale.push_back(static_cast<float>(1.0 / meta.input_scale[i]));
  }
  im.out_mean = meta.output_mean;
  im.out_scale = meta.output_scale;

  // Backend and kernels.
  im.bf16 = options.precision == RuntimePrecision::kBfloat16;
  im.int8 = options.precision == RuntimePrecision::kInt8;
  if (!im.bf16 && !im.int8 && options.precision != RuntimePrecision::kFloat32) {
    return make_error(ErrorCode::kInvalidArgument, "unknown precision");
  }
  const KernelSet& best = detail::best_kernels(std::max(env_isa_cap(), options.max_isa));
  RuntimeBackend be = options.backend;
  // kAuto: this library's kernels for the widest instruction set the CPU has, on every CPU.
  // oneDNN was slower than them everywhere it was measured, and 50x slower than the portable
  // kernels on AVX2 (docs/benchmarks/runtime.md): it runs only when asked for.
  if (be == RuntimeBackend::kAuto) be = RuntimeBackend::kKernels;
  if (be == RuntimeBackend::kOneDnn && (im.bf16 || im.int8)) {
    return make_error(ErrorCode::kUnsupported, "the oneDNN backend serves float32 only");
  }
  if (be == RuntimeBackend::kKernels) {
    im.ks = &best;  // every set serves every precision (a CPU with none: the portable kernels)
  } else if (be == RuntimeBackend::kPortable) {
    im.ks = &detail::portable_kernels();
  }
  im.backend = be;
  if (options.convolution == RuntimeConvolution::kWinograd &&
      (im.bf16 || im.int8 || be == RuntimeBackend::kOneDnn)) {
    return make_error(ErrorCode::kUnsupported,
                      "Winograd convolutions run float32 on the kernels or portable backend only");
  }
  im.slots.resize(static_cast<std::size_t>(options.threads));
  if (be == RuntimeBackend::kOneDnn) {
    auto net = detail::OneDnnNet::create(model, options.threads);
    if (!net.ok()) {
      return net.error();
    } else {
      im.dnn = std::move(net.value());
      im.chunk = detail::kOneDnnMaxChunk;
      im.kernel_name = "onednn float32";
      im.macs = model.macs();
    }
  }
  // Where each channel lands in an input row.
  if (im.dnn) {
    im.x_row = im.dnn->input_row();
  } else {
    im.x_row = im.cnn ? im.cells * kLanes : round_up(im.channels, kLanes);
  }
  for (int c = 0; c < im.channels; ++c) {
    if (!im.cnn) {
      im.dest.push_back(c);
      continue;
    }
    const int cell = a.sensor_cell[static_cast<std::size_t>(c / 3)];
    im.dest.push_back(cell * (im.dnn ? 3 : kLanes) + c % 3);
  }
  if (!im.dnn) {
    if (Status st = im.build_kernels(model); !st.ok()) return st.error();
    im.kernel_name =
        std::string("kernels ") + im.ks->name + " " + runtime_precision_name(options.precision);
    if (im.int8 && std::string_view(im.ks->i8_name) != im.ks->name) {
      im.kernel_name += std::string(" (") + im.ks->i8_name + ")";
    }
    if (be == RuntimeBackend::kPortable) {
      im.kernel_name = std::string("portable ") + runtime_precision_name(options.precision);
    }
    if (im.winograd) im.kernel_name += " winograd";
  }
  for (Slot& s : im.slots) {
    s.ok.assign(static_cast<std::size_t>(im.channels), 1);
    s.index.assign(static_cast<std::size_t>(im.chunk), 0);
    s.raw.assign(static_cast<std::size_t>(im.chunk * im.outputs), 0.0);
  }
  im.pool = std::make_unique<WorkerPool>(options.threads - 1, options.spin_us, im.dnn != nullptr);
  return NetworkRuntime(std::move(impl));
}

NetworkRuntime::NetworkRuntime(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
NetworkRuntime::NetworkRuntime(NetworkRuntime&&) noexcept = default;
NetworkRuntime& NetworkRuntime::operator=(NetworkRuntime&&) noexcept = default;
NetworkRuntime::~NetworkRuntime() = default;

namespace {

void run_call(NetworkRuntime::Impl& impl, Call& call) {
  call.impl = &impl;
  call.parts = std::max(1, std::min(impl.opt.threads, call.batch));
  const int saved = impl.dnn ? detail::set_openmp_threads(1) : 0;
  impl.pool->run(call.parts, &run_part, &call);
  if (impl.dnn) detail::set_openmp_threads(saved);
}

}  // namespace

Status NetworkRuntime::run(std::span<const double> field_ut, int batch,
                           std::span<ContactEstimate> out, std::span<const uint8_t> channel_ok) {
  Impl& im = *impl_;
  if (batch < 0 || out.size() < static_cast<std::size_t>(batch)) {
    return make_error(ErrorCode::kInvalidArgument, "run: out holds fewer than batch estimates");
  }
  const std::size_t values =
      static_cast<std::size_t>(batch) * static_cast<std::size_t>(im.channels);
  if (field_ut.size() != values || (!channel_ok.empty() && channel_ok.size() != values)) {
    for (int i = 0; i < batch; ++i) {
      ContactEstimate e;
      e.flags = kEstimateRejected;
      e.reason = RejectReason::kWrongShape;
      out[static_cast<std::size_t>(i)] = e;
    }
    return make_error(ErrorCode::kInvalidArgument,
                      "run: expected " + std::to_string(values) + " values (batch " +
                          std::to_string(batch) + " x " + std::to_string(im.channels) +
                          " channels), got " + std::to_string(field_ut.size()));
  }
  if (batch == 0) return Status::Ok();
  Call call;
  call.field = field_ut.data();
  call.channel_ok = channel_ok.empty() ? nullptr : channel_ok.data();
  call.out = out.data();
  call.batch = batch;
  run_call(im, call);
  return Status::Ok();
}

ContactEstimate NetworkRuntime::estimate(std::span<const double> field_ut,
                                         std::span<const uint8_t> channel_ok) {
  Impl& im = *impl_;
  const std::size_t ch = static_cast<std::size_t>(im.channels);
  ContactEstimate e;
  if (field_ut.size() != ch || (!channel_ok.empty() && channel_ok.size() != ch)) {
    e.flags = kEstimateRejected;
    e.reason = RejectReason::kWrongShape;
    return e;
  }
  Call call;
  call.impl = &im;
  call.field = field_ut.data();
  call.channel_ok = channel_ok.empty() ? nullptr : channel_ok.data();
  call.out = &e;
  call.batch = 1;
  call.parts = 1;
  const int saved = im.dnn ? detail::set_openmp_threads(1) : 0;
  run_part(&call, 0);
  if (im.dnn) detail::set_openmp_threads(saved);
  return e;
}

Status NetworkRuntime::run_outputs(std::span<const double> field_ut, int batch,
                                   std::span<double> outputs) {
  Impl& im = *impl_;
  const std::size_t b = static_cast<std::size_t>(std::max(batch, 0));
  if (batch < 0 || field_ut.size() != b * static_cast<std::size_t>(im.channels) ||
      outputs.size() < b * static_cast<std::size_t>(im.outputs)) {
    return make_error(ErrorCode::kInvalidArgument,
                      "run_outputs: sizes do not match batch " + std::to_string(batch));
  }
  if (batch == 0) return Status::Ok();
  Call call;
  call.field = field_ut.data();
  call.raw = outputs.data();
  call.batch = batch;
  run_call(im, call);
  return Status::Ok();
}

int NetworkRuntime::channels() const {
  return impl_->channels;
}
int NetworkRuntime::outputs() const {
  return impl_->outputs;
}
int NetworkRuntime::threads() const {
  return impl_->opt.threads;
}
RuntimeBackend NetworkRuntime::backend() const {
  return impl_->backend;
}
RuntimePrecision NetworkRuntime::precision() const {
  return impl_->opt.precision;
}
int64_t NetworkRuntime::macs() const {
  return impl_->macs;
}
std::span<const NetworkRuntime::LayerCost> NetworkRuntime::layer_costs() const {
  return impl_->costs;
}
RuntimeConvolution NetworkRuntime::convolution() const {
  return impl_->winograd ? RuntimeConvolution::kWinograd : RuntimeConvolution::kDirect;
}
const char* NetworkRuntime::kernel_name() const {
  return impl_->kernel_name.c_str();
}

}  // namespace skinbus::estimators
