// Subscribes to the body-frame contact topic (rt/skin/contacts) and prints what arrives:
//   build/examples/subscribe_contacts [seconds [domain]]
// Run it beside skinbus-host (or scripts/demo.sh); any ROS 2 node can read the same topic.
#include <cstdio>
#include <cstdlib>

#include "skinbus/dds/dds.h"

using namespace skinbus;

int main(int argc, char** argv) {
  const int seconds = argc > 1 ? std::atoi(argv[1]) : 10;
  dds::DdsOptions options;  // ROS 2 names; the domain CYCLONEDDS_URI gives, else 0
  if (argc > 2) options.domain_id = static_cast<uint32_t>(std::atoi(argv[2]));
  auto sub = dds::SkinSubscriber::create(options);
  if (!sub) return std::fprintf(stderr, "%s\n", sub.error().to_string().c_str()), 1;
  host::ContactArray array;
  for (int waited_ms = 0; waited_ms < seconds * 1000; waited_ms += 100) {
    auto got = (*sub)->wait_contacts(&array, 100);
    if (!got) return std::fprintf(stderr, "%s\n", got.error().to_string().c_str()), 1;
    if (!*got) continue;
    for (const host::BodyContact& c : array.contacts) {
      // Positions in the base frame, mm (the topic itself carries metres, as ROS 2 does).
      std::printf("%.3f s track %u: (%.1f, %.1f, %.1f) mm on %s, depth %.2f mm, +-%.1f mm\n",
                  static_cast<double>(array.stamp_us) * 1e-6, c.track_id, c.position_mm[0],
                  c.position_mm[1], c.position_mm[2], c.link.c_str(), c.depth_mm, c.uncertainty_mm);
    }
  }
  return 0;
}
