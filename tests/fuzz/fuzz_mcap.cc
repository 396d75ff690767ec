// Fuzzes the recording readers (record/mcap.h, record/ros2_messages.h): the input is an MCAP
// file. Every message read is also given to every CDR decoder. Invariants beyond "does not
// crash, hang or read out of bounds":
// - a reader error names the stream ("fuzz: byte N: ...");
// - a message that decodes re-encodes and decodes again to the same value (a contact array, a
//   patch sample, a CAN frame, a joint state), and nothing decoded holds a NaN where the decoder
//   promises finite values (joint positions) or a frame longer than its kind allows.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "skinbus/record/mcap.h"
#include "skinbus/record/ros2_messages.h"

using namespace skinbus;
using namespace skinbus::record;

namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_mcap: %s\n", what);
  std::abort();
}

void decode_all(std::span<const uint8_t> data) {
  std::vector<uint8_t> buf;
  if (auto c = decode_contacts(data); c.ok()) {
    if (!encode(*c, &buf).ok()) return;  // a value the encoder refuses (NaN, time): fine
    auto again = decode_contacts(buf);
    if (!again.ok() || again->contacts.size() != c->contacts.size() ||
        again->stamp_us != c->stamp_us || again->base_frame != c->base_frame) {
      fail("a contact array does not survive re-encoding");
    }
  }
  if (auto s = decode_patch_sample(data); s.ok()) {
    if (encode(*s, &buf).ok()) {
      auto again = decode_patch_sample(buf);
      if (!again.ok() || again->field_ut.size() != s->field_ut.size() || again->node != s->node ||
          again->stamp_us != s->stamp_us) {
        fail("a patch sample does not survive re-encoding");
      }
    }
  }
  if (auto f = decode_can_frame(data); f.ok()) {
    if (f->frame.len > (f->frame.fd ? 64 : 8)) fail("a frame longer than its kind allows");
    if (!encode(*f, &buf).ok()) fail("a decoded frame is refused by the encoder");
    auto again = decode_can_frame(buf);
    if (!again.ok() || !(again->frame == f->frame) || again->rx_us != f->rx_us ||
        again->interface != f->interface) {
      fail("a CAN frame does not survive re-encoding");
    }
  }
  if (auto j = decode_joint_state(data); j.ok()) {
    for (double p : j->positions) {
      if (!std::isfinite(p)) fail("a joint state with a non-finite position");
    }
    if (!encode(*j, &buf).ok()) fail("a decoded joint state is refused by the encoder");
    auto again = decode_joint_state(buf);
    if (!again.ok() || !(*again == *j)) fail("a joint state does not survive re-encoding");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  // The bytes as CDR messages too (the decoders' own input).
  decode_all(std::span<const uint8_t>(data, size));
  std::FILE* f = fmemopen(const_cast<uint8_t*>(data), size, "rb");
  if (f == nullptr) return 0;
  McapReaderOptions o;
  o.max_record_bytes = 1u << 20;
  auto r = McapReader::open(f, "fuzz", o);
  if (r.ok()) {
    McapMessage m;
    for (int n = 0; n < 100000; ++n) {
      auto more = (*r)->next(&m);
      if (!more.ok()) {
        if (more.error().message.rfind("fuzz: ", 0) != 0)
          fail("an error that does not name the file");
        break;
      }
      if (!*more) break;
      decode_all(m.data);
    }
  }
  std::fclose(f);
  return 0;
}
