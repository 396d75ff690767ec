#include "skinbus/bus/can_frame.h"

#include <algorithm>

namespace skinbus::bus {

bool CanFrame::operator==(const CanFrame& o) const {
  return id == o.id && extended == o.extended && fd == o.fd && brs == o.brs && esi == o.esi &&
         rtr == o.rtr && error == o.error && len == o.len &&
         std::equal(data.begin(), data.begin() + (len < kFdMaxLen ? len : kFdMaxLen),
                    o.data.begin());
}

}  // namespace skinbus::bus
