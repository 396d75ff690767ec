// The oneDNN backend in a build without oneDNN (SKINBUS_ONEDNN=OFF, as the Arm cross build): the
// same interface (network_onednn.h), creating a network refuses with kUnsupported, so the runtime
// answers a request for RuntimeBackend::kOneDnn with that error. Built instead of
// network_onednn.cc.
#include "network_onednn.h"

namespace skinbus::estimators::detail {

Result<std::unique_ptr<OneDnnNet>> OneDnnNet::create(const ModelFile&, int) {
  return make_error(ErrorCode::kUnsupported,
                    "the oneDNN backend is not in this build (SKINBUS_ONEDNN=OFF): use the "
                    "kernels or the portable backend");
}

int set_openmp_threads(int) {
  return 0;  // no OpenMP without oneDNN
}

}  // namespace skinbus::estimators::detail
