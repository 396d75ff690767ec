#include "network_onednn.h"

#include <omp.h>

#include <algorithm>
#include <dnnl.hpp>
#include <string>
#include <vector>

namespace skinbus::estimators::detail {
namespace {

using dnnl::memory;
using Tag = memory::format_tag;
using Dt = memory::data_type;

// One primitive execution with its arguments bound once.
struct Step {
  dnnl::primitive prim;
  std::vector<dnnl_exec_arg_t> args;
  std::vector<memory> keep;  // owners of the memories in args
};

// The steps of one chunk size in one slot.
struct Chunk {
  int n = 0;
  std::vector<Step> conv;     // convolutions (+ a reorder to channel-last)
  float* pool_src = nullptr;  // n x cells x c, channel last
  float* fc_in = nullptr;     // n x 2c
  std::vector<Step> fc;
};

struct Slot {
  dnnl::stream stream;
  std::vector<float> input, output;
  std::vector<float> head;                  // the head's output of the chunk that ran last
  std::vector<std::vector<float>> buffers;  // activations this slot owns
  std::vector<Chunk> chunks;                // one per kOneDnnChunks entry
};

class OneDnnNetImpl final : public OneDnnNet {
 public:
  float* input(int slot) override { return slots_[slot].input.data(); }
  int input_row() const override { return input_row_; }
  const float* output(int slot) const override { return slots_[slot].output.data(); }

  void run(int slot, int n) override {
    Slot& s = slots_[slot];
    int done = 0;
    for (std::size_t ci = 0; ci < s.chunks.size(); ++ci) {
      Chunk& ch = s.chunks[ci];
      while (n - done >= ch.n) {
        run_chunk(s, ch, done);
        done += ch.n;
      }
    }
  }

  Status build(const ModelFile& model, int slots);

 private:
  void exec(Slot& s, Step& st) {
    dnnl_primitive_execute(st.prim.get(), s.stream.get(), static_cast<int>(st.args.size()),
                           st.args.data());
  }

  // Runs chunk `ch` on rows [row0, row0 + ch.n): the chunk's memories point at row 0, so the
  // rows are moved there first (rows before row0 are done) and the outputs copied out.
  void run_chunk(Slot& s, Chunk& ch, int row0) {
    if (row0 != 0) {
      std::copy_n(s.input.data() + static_cast<std::ptrdiff_t>(row0) * input_row_,
                  static_cast<std::ptrdiff_t>(ch.n) * input_row_, s.input.data());
    }
    for (Step& st : ch.conv) exec(s, st);
    if (cnn_) {
      s.stream.wait();
      const float inv = 1.0f / static_cast<float>(cells_);
      for (int b = 0; b < ch.n; ++b) {
        const float* src = ch.pool_src + static_cast<std::ptrdiff_t>(b) * cells_ * last_c_;
        float* avg = ch.fc_in + static_cast<std::ptrdiff_t>(b) * 2 * last_c_;
        float* mx = avg + last_c_;
        for (int c = 0; c < last_c_; ++c) {
          avg[c] = 0.0f;
          mx[c] = src[c];
        }
        for (int cell = 0; cell < cells_; ++cell) {
          const float* row = src + static_cast<std::ptrdiff_t>(cell) * last_c_;
          for (int c = 0; c < last_c_; ++c) {
            avg[c] += row[c];
            mx[c] = std::max(mx[c], row[c]);
          }
        }
        for (int c = 0; c < last_c_; ++c) avg[c] *= inv;
      }
    }
    for (Step& st : ch.fc) exec(s, st);
    s.stream.wait();
    std::copy_n(s.head.data(), static_cast<std::ptrdiff_t>(ch.n) * outputs_,
                s.output.data() + static_cast<std::ptrdiff_t>(row0) * outputs_);
  }

  dnnl::engine eng_{dnnl::engine::kind::cpu, 0};
  std::vector<Slot> slots_;
  bool cnn_ = false;
  int cells_ = 0, rows_ = 0, cols_ = 0, last_c_ = 0, input_row_ = 0, outputs_ = 0;
  std::vector<memory> weights_;  // reordered weights and biases, shared by the slots
};

memory user_memory(const Tensor& t, const memory::dims& dims, Tag tag, const dnnl::engine& eng) {
  memory m({dims, Dt::f32, tag}, eng);
  std::copy(t.data.begin(), t.data.end(), static_cast<float*>(m.get_data_handle()));
  return m;
}

dnnl::primitive_attr make_attr(bool relu) {
  dnnl::primitive_attr attr;
  attr.set_scratchpad_mode(dnnl::scratchpad_mode::user);
  if (relu) {
    dnnl::post_ops po;
    po.append_eltwise(1.0f, dnnl::algorithm::eltwise_relu, 0.0f, 0.0f);
    attr.set_post_ops(po);
  }
  return attr;
}

Status OneDnnNetImpl::build(const ModelFile& model, int slots) {
  const Architecture& a = model.meta.architecture;
  cnn_ = a.kind == ArchitectureKind::kCnn;
  rows_ = a.grid_rows;
  cols_ = a.grid_cols;
  cells_ = rows_ * cols_;
  outputs_ = static_cast<int>(model.meta.outputs.size());
  input_row_ = cnn_ ? cells_ * 3 : model.meta.channels();
  slots_.resize(static_cast<std::size_t>(slots));
  for (Slot& s : slots_) {
    s.stream = dnnl::stream(eng_);
    s.input.assign(static_cast<std::size_t>(kOneDnnMaxChunk) * input_row_, 0.0f);
    s.output.assign(static_cast<std::size_t>(kOneDnnMaxChunk) * outputs_, 0.0f);
    s.head.assign(static_cast<std::size_t>(kOneDnnMaxChunk) * outputs_, 0.0f);
  }
  dnnl::stream setup(eng_);
  auto reorder_weights = [&](memory user, const memory::desc& want) {
    if (user.get_desc() == want) {
      weights_.push_back(user);
      return user;
    }
    memory m(want, eng_);
    dnnl::reorder(user, m).execute(setup, user, m);
    setup.wait();
    weights_.push_back(m);
    return m;
  };
  auto arg = [](int kind, const memory& m) { return dnnl_exec_arg_t{kind, m.get()}; };
  for (int n : kOneDnnChunks) {
    // Primitive descriptors and weights for chunk size n.
    struct Layer {
      dnnl::primitive prim;
      memory::desc src, dst, scratch;
      memory weights, bias;
    };
    std::vector<Layer> convs, fcs;
    memory::desc prev;
    int c_in = 3;
    for (std::size_t k = 0; cnn_ && k < a.conv_channels.size(); ++k) {
      const int c_out = a.conv_channels[k];
      const std::string name = "conv" + std::to_string(k);
      // Every layout left to oneDNN: with the input's channel-last layout forced on the first
      // convolution, oneDNN 2.6 has JIT convolutions only on AVX-512 (brgconv) and ran the
      // reference loop (ref:any) on AVX2, 50x slower; the input is reordered into its choice.
      memory::desc src = k == 0 ? memory::desc({n, c_in, rows_, cols_}, Dt::f32, Tag::any) : prev;
      memory::desc w({c_out, c_in, 3, 3}, Dt::f32, Tag::any);
      memory::desc b({c_out}, Dt::f32, Tag::x);
      memory::desc dst({n, c_out, rows_, cols_}, Dt::f32, Tag::any);
      dnnl::convolution_forward::desc d(dnnl::prop_kind::forward_inference,
                                        dnnl::algorithm::convolution_direct, src, w, b, dst, {1, 1},
                                        {1, 1}, {1, 1});
      dnnl::convolution_forward::primitive_desc pd(d, make_attr(true), eng_);
      Layer l;
      l.prim = dnnl::convolution_forward(pd);
      l.src = pd.src_desc();
      l.dst = pd.dst_desc();
      l.scratch = pd.scratchpad_desc();
      l.weights = reorder_weights(
          user_memory(*model.find(name + ".weight"), {c_out, c_in, 3, 3}, Tag::oihw, eng_),
          pd.weights_desc());
      l.bias = user_memory(*model.find(name + ".bias"), {c_out}, Tag::x, eng_);
      weights_.push_back(l.bias);
      prev = l.dst;
      convs.push_back(std::move(l));
      c_in = c_out;
    }
    last_c_ = c_in;
    int in = cnn_ ? 2 * c_in : model.meta.channels();
    const std::size_t n_fc = a.hidden.size() + 1;
    for (std::size_t k = 0; k < n_fc; ++k) {
      const bool head = k + 1 == n_fc;
      const int out = head ? outputs_ : a.hidden[k];
      const std::string name = head ? "head" : "fc" + std::to_string(k);
      memory::desc src({n, in}, Dt::f32, Tag::nc);
      memory::desc w({out, in}, Dt::f32, Tag::any);
      memory::desc b({out}, Dt::f32, Tag::x);
      memory::desc dst({n, out}, Dt::f32, Tag::nc);
      dnnl::inner_product_forward::desc d(dnnl::prop_kind::forward_inference, src, w, b, dst);
      dnnl::inner_product_forward::primitive_desc pd(d, make_attr(!head), eng_);
      Layer l;
      l.prim = dnnl::inner_product_forward(pd);
      l.src = pd.src_desc();
      l.dst = pd.dst_desc();
      l.scratch = pd.scratchpad_desc();
      l.weights = reorder_weights(
          user_memory(*model.find(name + ".weight"), {out, in}, Tag::oi, eng_), pd.weights_desc());
      l.bias = user_memory(*model.find(name + ".bias"), {out}, Tag::x, eng_);
      weights_.push_back(l.bias);
      fcs.push_back(std::move(l));
      in = out;
    }
    // Per slot: activations, scratchpads and bound arguments.
    for (Slot& s : slots_) {
      Chunk ch;
      ch.n = n;
      auto step = [&](const Layer& l, const memory& src, const memory& dst) {
        Step st;
        st.prim = l.prim;
        memory scratch(l.scratch, eng_);
        st.keep = {src, dst, scratch};
        st.args = {arg(DNNL_ARG_SRC, src), arg(DNNL_ARG_WEIGHTS, l.weights),
                   arg(DNNL_ARG_BIAS, l.bias), arg(DNNL_ARG_DST, dst),
                   arg(DNNL_ARG_SCRATCHPAD, scratch)};
        return st;
      };
      // `src` in layout `want`: a reorder step into a new memory where the layouts differ.
      auto reorder_to = [&](memory& src, const memory::desc& want) {
        if (src.get_desc() == want) return;
        memory m(want, eng_);
        Step st;
        st.prim = dnnl::reorder(src, m);
        st.keep = {src, m};
        st.args = {arg(DNNL_ARG_FROM, src), arg(DNNL_ARG_TO, m)};
        ch.conv.push_back(std::move(st));
        src = m;
      };
      memory src;
      if (cnn_) {
        // The input rows are channel-last (input_row()), the pooling reads channel-last: the
        // convolutions' own layouts in between.
        src = memory({{n, 3, rows_, cols_}, Dt::f32, Tag::nhwc}, eng_, s.input.data());
        reorder_to(src, convs[0].src);
        for (const Layer& l : convs) {
          memory dst(l.dst, eng_);
          ch.conv.push_back(step(l, src, dst));
          src = dst;
        }
        reorder_to(src, {{n, c_in, rows_, cols_}, Dt::f32, Tag::nhwc});
        ch.pool_src = static_cast<float*>(src.get_data_handle());
        src = memory(fcs[0].src, eng_);
        ch.fc_in = static_cast<float*>(src.get_data_handle());
      } else {
        src = memory(fcs[0].src, eng_, s.input.data());
      }
      for (std::size_t k = 0; k < fcs.size(); ++k) {
        memory dst = k + 1 == fcs.size() ? memory(fcs[k].dst, eng_, s.head.data())
                                         : memory(fcs[k].dst, eng_);
        ch.fc.push_back(step(fcs[k], src, dst));
        src = dst;
      }
      s.chunks.push_back(std::move(ch));
    }
  }
  return Status::Ok();
}

}  // namespace

Result<std::unique_ptr<OneDnnNet>> OneDnnNet::create(const ModelFile& model, int slots) {
  auto net = std::make_unique<OneDnnNetImpl>();
  // Primitives plan their work split for the thread count at creation: one thread per slot.
  const int saved = set_openmp_threads(1);
  try {
    Status st = net->build(model, slots);
    set_openmp_threads(saved);
    if (!st.ok()) return st.error();
  } catch (const dnnl::error& e) {
    set_openmp_threads(saved);
    return make_error(ErrorCode::kUnsupported, std::string("oneDNN: ") + e.what());
  }
  return std::unique_ptr<OneDnnNet>(std::move(net));
}

int set_openmp_threads(int threads) {
  const int previous = omp_get_max_threads();
  omp_set_num_threads(threads);
  return previous;
}

}  // namespace skinbus::estimators::detail
