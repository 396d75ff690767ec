// Reads a candump log of patch traffic and estimates every touched sample with a model:
//   build/examples/estimate_recording estimators/models/nominal_seed_cnn < bus.log
// One line per contact sample: node, patch time, (u, v) on the patch, depth, flags.
#include <cstdio>

#include "skinbus/bus/candump.h"
#include "skinbus/bus/protocol.h"
#include "skinbus/bus/reassembler.h"
#include "skinbus/estimators/model_file.h"
#include "skinbus/estimators/network_runtime.h"

using namespace skinbus;

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: estimate_recording MODEL < candump.log\n");
    return 2;
  }
  auto model = estimators::read_model(argv[1]);  // errors are values: say why and stop
  if (!model) return std::fprintf(stderr, "%s\n", model.error().to_string().c_str()), 1;
  auto runtime = estimators::NetworkRuntime::create(*model);  // the fastest kernels of this CPU
  if (!runtime) return std::fprintf(stderr, "%s\n", runtime.error().to_string().c_str()), 1;
  std::printf("# %s on %s\n", argv[1], runtime->kernel_name());

  bus::CandumpReader log(stdin);
  bus::Reassembler reassembler;  // frames -> messages (a sample spans several CAN frames)
  bus::CandumpRecord record;
  for (;;) {
    const auto status = log.next(&record);
    if (status == bus::CandumpReader::Status::kEof) break;
    if (status == bus::CandumpReader::Status::kBadLine) continue;  // counted by the reader
    const bus::FeedResult r = reassembler.feed(record.frame, record.timestamp_us);
    if (r.status != bus::FeedStatus::kMessage) continue;
    const auto* sample = std::get_if<bus::Sample>(&r.message->body);
    if (sample == nullptr || (sample->flags & bus::sample_flags::kContact) == 0) continue;
    // The wire carries tared fields in 0.1 uT; the model takes uT, sensor-major x, y, z.
    double field_ut[bus::kChannelCount];
    for (int c = 0; c < bus::kChannelCount; ++c) {
      field_ut[c] = sample->field_lsb[static_cast<std::size_t>(c)] * bus::kFieldUtPerLsb;
    }
    const estimators::ContactEstimate e = runtime->estimate(field_ut);
    if (!e.valid()) continue;  // a dead, saturated or non-finite channel: rejected, not guessed
    std::printf("node %u t %u us: u %.1f mm v %.1f mm depth %.2f mm flags %u\n",
                static_cast<unsigned>(r.message->node), sample->timestamp_us, e.u_mm, e.v_mm,
                e.depth_mm, e.flags);
  }
  return 0;
}
