#include "skinbus/estimators/contact_proposal.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace skinbus::estimators {

bool is_proposer(const ModelMeta& meta) {
  if (meta.outputs.size() != kProposerOutputs.size()) return false;
  for (std::size_t j = 0; j < kProposerOutputs.size(); ++j) {
    if (meta.outputs[j] != kProposerOutputs[j]) return false;
  }
  return true;
}

ContactProposal proposal_from_outputs(std::span<const double> outputs) {
  ContactProposal p;
  if (outputs.size() < kProposerOutputs.size()) return p;
  p.count_raw = outputs[kProposerOutputs.size() - 1];
  // The finite slots, deepest first.
  int slots[kMaxContacts];
  int finite = 0;
  for (int s = 0; s < kMaxContacts; ++s) {
    const double* x = outputs.data() + 3 * s;
    if (!(std::isfinite(x[0]) && std::isfinite(x[1]) && std::isfinite(x[2]))) continue;
    int at = finite++;  // insertion by depth, deepest first
    for (; at > 0 && outputs[3 * slots[at - 1] + 2] < x[2]; --at) slots[at] = slots[at - 1];
    slots[at] = s;
  }
  const double rounded = std::isfinite(p.count_raw) ? std::round(p.count_raw) : 0.0;
  p.count = static_cast<int>(std::clamp(rounded, 0.0, static_cast<double>(finite)));
  for (int k = 0; k < p.count; ++k) {
    const double* x = outputs.data() + 3 * slots[k];
    ContactEstimate& e = p.contacts[k];
    e.u_mm = x[0];
    e.v_mm = x[1];
    e.depth_mm = std::max(x[2], 0.0);
  }
  return p;
}

Result<NetworkRuntime> load_proposer(const std::string& path, int channels) {
  auto m = read_model(path);
  if (!m.ok()) return m.error();
  if (!is_proposer(m->meta) || m->meta.channels() != channels) {
    return make_error(ErrorCode::kInvalidArgument,
                      "proposer " + path + ": not a proposer for this design (its " +
                          "outputs or channel count differ; docs/models.md)");
  }
  return NetworkRuntime::create(*m);
}

ContactProposal propose_contacts(NetworkRuntime& proposer, std::span<const double> field_ut) {
  double y[kProposerOutputCount];
  if (!proposer.run_outputs(field_ut, 1, y).ok()) return {};
  return proposal_from_outputs(y);
}

}  // namespace skinbus::estimators
