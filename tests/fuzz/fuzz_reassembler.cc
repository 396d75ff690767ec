// Fuzzes the reassembler with arbitrary frame streams. Whatever it emits must be a valid
// message: re-encoded and reassembled again it comes back equal. Memory stays bounded.
#include <cstdlib>

#include "fuzz_input.h"
#include "skinbus/bus/reassembler.h"

using namespace skinbus::bus;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  Reassembler r(Reassembler::Config{4, 1000});
  std::size_t pos = 0;
  CanFrame f;
  uint64_t t = 0;
  while (fuzz::next_frame(data, size, &pos, &f)) {
    t += (f.data[0] & 0x3) * 400;  // time moves on, sometimes past the timeout
    const FeedResult res = r.feed(f, t);
    if (r.slots_in_use() > 4) std::abort();
    if (res.status != FeedStatus::kMessage) continue;
    const Message m = *res.message;
    CanFrame out[kMaxParts];
    const EncodeResult e = encode(m, out);
    if (e.error != EncodeError::kNone) std::abort();
    Reassembler check;
    const FeedResult* last = nullptr;
    FeedResult back;
    for (std::size_t i = 0; i < e.frames; ++i) {
      back = check.feed(out[i], i);
      last = &back;
    }
    if (!last || last->status != FeedStatus::kMessage || !(*last->message == m)) std::abort();
  }
  const ReassemblyStats& s = r.stats();
  if (s.messages > s.frames) std::abort();
  return 0;
}
