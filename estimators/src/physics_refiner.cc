#include "skinbus/estimators/physics_refiner.h"

#include <algorithm>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "skinbus/estimators/contact_proposal.h"
#include "skinbus/estimators/creep.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/unit_model.h"

namespace skinbus::estimators {

namespace {

// A poor fit's search: the lean fit from this many nearest rows of the start table.
constexpr int kSearchStarts = 3;

class PhysicsRefiner : public ContactRefiner {
 public:
  PhysicsRefiner(PhysicsEstimator estimator, const RefinerOptions& options,
                 std::optional<NetworkRuntime> proposer, std::optional<BiasCorrection> correction)
      : estimator_(std::move(estimator)),
        options_(options),
        proposer_(std::move(proposer)),
        correction_(std::move(correction)) {
    options_.count.max_contacts = options_.max_contacts;  // the count goes as far as asked
  }

  int channel_count() const override { return estimator_.model().channel_count(); }

  RefinedEstimate refine(std::span<const double> field_ut, std::span<const uint8_t> channel_ok,
                         const ContactEstimate& start) const override {
    return from(single_fit(field_ut, channel_ok, start));
  }

  RefinedEstimate search(std::span<const double> field_ut, std::span<const uint8_t> channel_ok,
                         const ContactEstimate& held) const override {
    // The held fit stands for its own basin: one start fewer, none beside it.
    if (held.valid())
      return from(estimator_.search_lm(field_ut, channel_ok, kSearchStarts - 1, &held));
    return from(estimator_.search_lm(field_ut, channel_ok, kSearchStarts));
  }

  std::unique_ptr<Memory> make_memory() const override {
    auto m = std::make_unique<WarmMemory>();
    m->creep = CreepCompensator(CreepLaw::of(estimator_.model().design()));
    return m;
  }

  double press_depth_mm(const ContactEstimate& refined, double t_s, bool same_press,
                        Memory* memory) const override {
    auto* kept = dynamic_cast<WarmMemory*>(memory);
    return kept != nullptr ? kept->creep.depth_mm(t_s, refined.depth_mm, same_press)
                           : refined.depth_mm;
  }

  RefinedContacts refine_contacts(std::span<const double> field_ut,
                                  std::span<const uint8_t> channel_ok, const ContactEstimate& start,
                                  std::span<const ContactEstimate> previous,
                                  double search_above_chi2, Memory* memory) const override {
    RefinedContacts out;
    auto* kept = dynamic_cast<WarmMemory*>(memory);  // another refiner's: not used
    WarmJacobian* warm = kept != nullptr ? &kept->warm : nullptr;
    // Counting contacts has its own search (below): a single fit that ends poor is its signal.
    const PhysicsEstimate single = options_.max_contacts < 2
                                       ? single_fit(field_ut, channel_ok, start, warm)
                                       : estimator_.refine_lm(field_ut, channel_ok, start, warm);
    out.contacts[0] = from(single);
    out.single_reduced_chi2 = single.reduced_chi2;
    const bool known = previous.size() >= 2;  // the previous sample's contacts (2 or 3)
    if (options_.max_contacts < 2 || !single.contact.valid() ||
        !(single.reduced_chi2 > options_.count.try_ratio)) {
      return out;
    }
    // Without previous contacts, the proposer's when it proposes several.
    ContactProposal proposal;
    if (!known && proposer_) proposal = propose(field_ut, channel_ok);
    const int proposed = std::min(proposal.count, options_.max_contacts);
    if (!known && proposed >= 2) {
      previous =
          std::span<const ContactEstimate>(proposal.contacts, static_cast<std::size_t>(proposed));
      out.proposed = true;
    } else if (!known && !(single.reduced_chi2 > search_above_chi2)) {
      return out;
    }
    out.searched = !known && !out.proposed;
    // A search from nothing counts from the better of this single fit and one from the start
    // table (started from a first estimate between several presses, the single fit can end in a
    // poor minimum or off the patch, and the count's starts come from it).
    PhysicsEstimate table;
    if (out.searched) table = estimator_.estimate(field_ut, channel_ok);
    const bool from_table =
        out.searched && table.contact.valid() && !(table.contact.flags & kEstimateNoContact) &&
        (!(single.chi2 <= table.chi2) || (single.contact.flags & kEstimateNoContact) != 0);
    // (A search has fewer than two previous contacts: count_contacts() starts from nothing.)
    const ContactCountEstimate c = estimator_.count_contacts(
        field_ut, channel_ok, from_table ? table : single, options_.count, previous);
    if (c.count < 2) return out;
    out.count = c.count;
    const double reduced = c.count == 3 ? c.triple_reduced_chi2 : c.pair_reduced_chi2;
    for (int k = 0; k < c.count; ++k) {
      RefinedEstimate& r = out.contacts[k];
      r = RefinedEstimate{};
      r.contact = c.contacts[k];
      mark_extrapolated(&r.contact);
      r.sigma_uv_mm = c.sigma_uv_mm[k];
      r.sigma_shear_n = c.sigma_shear_n[k];  // NaN unless the fit had the shear
      r.reduced_chi2 = reduced;
    }
    return out;
  }

 private:
  struct WarmMemory : Memory {
    WarmJacobian warm;
    CreepCompensator creep;  // the unit's identified creep (none: the bend is the depth)
  };

  // The fit from `start` (from `warm`'s Jacobian when near), searched again from the start table
  // when it ends poor.
  PhysicsEstimate single_fit(std::span<const double> field_ut, std::span<const uint8_t> channel_ok,
                             const ContactEstimate& start, WarmJacobian* warm = nullptr) const {
    PhysicsEstimate fit = estimator_.refine_lm(field_ut, channel_ok, start, warm);
    // A rejected sample (too few usable channels) is rejected from any start.
    if (!options_.search_when_poor || !fit.contact.valid() ||
        (fit.contact.flags & (kEstimatePoorFit | kEstimateNoContact)) == 0) {
      return fit;
    }
    PhysicsEstimate searched = estimator_.search_lm(field_ut, channel_ok, kSearchStarts);
    const bool contact =
        searched.contact.valid() && (searched.contact.flags & kEstimateNoContact) == 0;
    return contact && searched.chi2 < fit.chi2 ? searched : fit;
  }

  // The proposer's answer for a sample (none when a channel is left out: a network cannot).
  ContactProposal propose(std::span<const double> field_ut,
                          std::span<const uint8_t> channel_ok) const {
    if (std::find(channel_ok.begin(), channel_ok.end(), uint8_t{0}) != channel_ok.end()) return {};
    const std::lock_guard<std::mutex> lock(proposer_mutex_);  // one run at a time per runtime
    return propose_contacts(*proposer_, field_ut);
  }

  // A single-contact fit as a refined estimate, corrected when the unit has a correction.
  RefinedEstimate from(const PhysicsEstimate& p) const {
    RefinedEstimate out;
    out.contact = correction_ ? correction_->apply(p.contact) : p.contact;
    mark_extrapolated(&out.contact);
    out.sigma_uv_mm = p.sigma_uv_mm;
    out.reduced_chi2 = p.reduced_chi2;
    out.sigma_shear_n = p.sigma_shear_n;  // NaN unless the fit had the shear
    return out;
  }

  // kEstimateExtrapolated on a contact placed outside the unit's pressed area.
  void mark_extrapolated(ContactEstimate* c) const {
    if (options_.pressed_area && c->valid() &&
        !options_.pressed_area->contains(c->u_mm, c->v_mm, sim::kPressedAreaMarginMm)) {
      c->flags |= kEstimateExtrapolated;
    }
  }

  PhysicsEstimator estimator_;
  RefinerOptions options_;
  mutable std::optional<NetworkRuntime> proposer_;
  mutable std::mutex proposer_mutex_;
  std::optional<BiasCorrection> correction_;
};

}  // namespace

Result<std::unique_ptr<ContactRefiner>> make_physics_refiner(const sim::PatchModel& model,
                                                             const RefinerOptions& options) {
  if (options.max_contacts < 1 || options.max_contacts > kMaxContacts) {
    return make_error(ErrorCode::kInvalidArgument,
                      "physics refiner: max_contacts must be 1 to " + std::to_string(kMaxContacts));
  }
  PhysicsOptions po = options.physics;
  po.covariance = true;
  if (options.max_contacts < 2) {
    // A coarse start table: a refinement starts from its first estimate; the table is only the
    // search of a fit that ends poor there (or, with search_when_poor off, one row). Counting
    // contacts needs the whole table (the fit of what a first contact leaves starts from it).
    if (options.search_when_poor) {
      po.start_grid.pitch_mm = 2 * start_pitch_mm(model.design());
      po.start_grid.depths_mm = {1.0, 2.5, 4.0};
    } else {
      po.start_grid.pitch_mm = std::max(model.design().size_u_mm, model.design().size_v_mm);
      po.start_grid.depths_mm = {2.0};
    }
  }
  auto e = PhysicsEstimator::create(model, po);
  if (!e.ok()) return e.error();
  std::optional<NetworkRuntime> proposer;
  if (!options.proposer.empty()) {
    auto rt = load_proposer(options.proposer, model.channel_count());
    if (!rt.ok()) return rt.error();
    proposer.emplace(std::move(*rt));
  }
  std::optional<BiasCorrection> correction;
  if (!options.correction.empty()) {
    auto c = BiasCorrection::read(options.correction);
    if (!c.ok()) return c.error();
    correction.emplace(std::move(*c));
  }
  return std::unique_ptr<ContactRefiner>(
      new PhysicsRefiner(std::move(*e), options, std::move(proposer), std::move(correction)));
}

Result<std::unique_ptr<ContactRefiner>> make_physics_refiner(const std::string& unit_path,
                                                             const std::string& design_path,
                                                             const RefinerOptions& options) {
  auto design = sim::read_design_or_builtin(design_path);
  if (!design.ok()) return design.error();
  auto unit = sim::read_unit_model(unit_path, *design);
  if (!unit.ok()) {
    return make_error(unit.error().code,
                      unit.error().message + " (design " +
                          (design_path.empty() ? std::string("built in") : design_path) + ")");
  }
  if (!unit->note.refused.empty()) {
    return make_error(ErrorCode::kInvalidArgument,
                      "unit file " + unit_path +
                          " is a fit identification refused, not for refinement (" +
                          unit->note.refused + ")");
  }
  RefinerOptions with_tip = options;
  with_tip.physics.tip_radius_mm = design->indenter_tip_radius_mm;
  with_tip.pressed_area = unit->note.pressed_area;
  return make_physics_refiner(unit->model, with_tip);
}

}  // namespace skinbus::estimators
