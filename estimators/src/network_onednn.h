// network_onednn.h (internal): the oneDNN backend of the network runtime (float32).
//
// Primitives (convolution with fused ReLU, inner product) are created for chunks of
// kOneDnnChunks samples, weights reordered once per chunk size into the layout each primitive
// chose. Every thread slot owns its stream, scratchpads and activation buffers, so slots run
// concurrently. A run of n samples is cut greedily into those chunk sizes.
#pragma once

#include <memory>

#include "skinbus/common/result.h"
#include "skinbus/estimators/model_file.h"

namespace skinbus::estimators::detail {

inline constexpr int kOneDnnChunks[] = {32, 8, 1};
inline constexpr int kOneDnnMaxChunk = 32;

class OneDnnNet {
 public:
  // `slots` thread slots. Errors: kUnsupported when oneDNN cannot build a primitive.
  static Result<std::unique_ptr<OneDnnNet>> create(const ModelFile& model, int slots);
  virtual ~OneDnnNet() = default;

  // The normalised input of slot `slot`: kOneDnnMaxChunk rows of input_row() floats (kCnn:
  // rows x cols x 3 image, channel last; kMlp: the channel vector).
  virtual float* input(int slot) = 0;
  virtual int input_row() const = 0;
  // The head outputs (normalised) of slot `slot`: rows of outputs() floats.
  virtual const float* output(int slot) const = 0;
  // Runs the first `n` (<= kOneDnnMaxChunk) rows of input(slot) into output(slot). Call from one
  // thread per slot at a time; the calling thread should have OpenMP limited to one thread.
  virtual void run(int slot, int n) = 0;
};

// Sets the calling thread's OpenMP thread count (oneDNN's threading runtime here) and returns
// the previous one; does nothing and returns 0 without OpenMP.
int set_openmp_threads(int threads);

}  // namespace skinbus::estimators::detail
