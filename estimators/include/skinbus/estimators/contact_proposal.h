// skinbus/estimators/contact_proposal.h: a proposer network's answer: how many contacts a sample
// holds (0 to kMaxContacts) and roughly where, as starts for the physics count
// (PhysicsEstimator::count_contacts, which decides the count by its own test; the proposal only
// spares it the search from nothing).
//
// A proposer is an ordinary model file (model_file.h) whose outputs are kProposerOutputs: three
// contact slots (u, v, depth; a slot without a contact is trained to depth 0, the slots in no
// particular order) and the contact count as a number. train_proposer() (training.h) makes one
// from simulated presses; NetworkRuntime::run_outputs() runs it like any other model.
#pragma once

#include <array>
#include <span>
#include <string>

#include "skinbus/common/result.h"
#include "skinbus/estimators/estimate.h"
#include "skinbus/estimators/model_file.h"
#include "skinbus/estimators/network_runtime.h"

namespace skinbus::estimators {

inline constexpr int kProposerOutputCount = 3 * kMaxContacts + 1;
inline constexpr std::array<const char*, kProposerOutputCount> kProposerOutputs = {
    "u_mm",      "v_mm",  "depth_mm", "u2_mm",     "v2_mm",
    "depth2_mm", "u3_mm", "v3_mm",    "depth3_mm", "contacts"};

// Whether `meta` is a proposer's (its outputs are kProposerOutputs, in order).
bool is_proposer(const ModelMeta& meta);

struct ContactProposal {
  int count = 0;  // the count output rounded and clamped to [0, kMaxContacts]; 0 when not finite
  double count_raw = 0;                    // the count output as the network gave it
  ContactEstimate contacts[kMaxContacts];  // the first `count`: the deepest slots, deepest first
};

// One sample's proposer outputs (kProposerOutputCount values in kProposerOutputs' order,
// physical units, as NetworkRuntime::run_outputs() gives them) to a proposal. A slot with a
// non-finite value is never proposed (the count is lowered to the finite slots). No allocation.
ContactProposal proposal_from_outputs(std::span<const double> outputs);

// The proposer in `path` (a model path stem) in the host's runtime (default options), for
// samples of `channels` channels. Errors name the file: read_model()'s, or kInvalidArgument when
// it is not a proposer or was made for another channel count.
Result<NetworkRuntime> load_proposer(const std::string& path, int channels);

// One tared sample's proposal (`field_ut`: the proposer's channel count, uT) from a proposer
// loaded by load_proposer(): one network run (not concurrently on one runtime). A failed run
// proposes nothing (count 0).
ContactProposal propose_contacts(NetworkRuntime& proposer, std::span<const double> field_ut);

}  // namespace skinbus::estimators
