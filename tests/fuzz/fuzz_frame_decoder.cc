// Fuzzes the single-frame decoder: parse_frame, decode_single and describe_frame must accept or
// reject any frame without crashing, and what they accept must be self-consistent.
#include <cstdlib>
#include <cstring>

#include "fuzz_input.h"
#include "skinbus/bus/codec.h"
#include "skinbus/bus/format.h"

using namespace skinbus::bus;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  std::size_t pos = 0;
  CanFrame f;
  while (fuzz::next_frame(data, size, &pos, &f)) {
    FrameView v;
    if (parse_frame(f, &v) == DecodeError::kNone) {
      if (kHeaderLen + v.part_len > f.len) std::abort();
      if (v.header.part >= v.part_count) std::abort();
      if (v.payload_offset + v.part_len > payload_len(v.message_class)) std::abort();
    }
    Message m;
    if (decode_single(f, &m) == DecodeError::kNone) {
      // A decoded single frame re-encodes to the same payload bytes.
      CanFrame out[kMaxParts];
      const EncodeResult r = encode(m, out);
      if (r.frames != 1 || std::memcmp(out[0].data.data(), f.data.data(),
                                       kHeaderLen + payload_len(m.message_class()))) {
        std::abort();
      }
    }
    (void)describe_frame(f);
  }
  return 0;
}
