#include "skinbus/sim/patch_model.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>

#include <string>

#include "dipole_sum.h"
#include "skinbus/sim/rng.h"

namespace skinbus::sim {

namespace {

// What sensor `s` reads of the field `b` (patch frame, uT): in its own axes, times its gains,
// into out[0], out[stride], out[2 * stride].
void sensor_reading(const PatchModel::Sensor& s, const Vec3<double>& b, double* out,
                    std::size_t stride = 1) {
  const Vec3<double> local = s.frame.apply(b);
  out[0] = local.x * s.gain.x;
  out[stride] = local.y * s.gain.y;
  out[2 * stride] = local.z * s.gain.z;
}

// What of the model and of one press without shear is the same at every magnet, for
// single_press_pose(): the spreads' inverses (a magnet's pose then takes two divisions, not
// twenty), the press's place and its terms with their derivatives by its depth.
struct SinglePress {
  SinglePress(const PatchModel& model, const Contact& c, const PatchModel::PressTerms<Dual<3>>& t)
      : u(c.u_mm),
        v(c.v_mm),
        pressing(model.presses(c)),
        inv_lu(1 / model.spread_u_mm()),
        inv_lv(1 / model.spread_v_mm()),
        inv_lu2(inv_lu * inv_lu),
        inv_lv2(inv_lv * inv_lv),
        lateral(model.lateral_mm()),
        drag(model.design().inplane_drag),
        a2(pressing ? t.a2.v : 0),
        da2(pressing ? t.a2.d[2] : 0),
        amp(pressing ? t.amp_mm.v : 0),
        damp(pressing ? t.amp_mm.d[2] : 0),
        flat(model.design().surface == SurfaceKind::kFlat) {}
  double u, v;
  bool pressing;
  double inv_lu, inv_lv, inv_lu2, inv_lv2, lateral, drag;
  double a2, da2, amp, damp;  // PressTerms' a2 and amp_mm, and their derivatives by the depth
  bool flat;
};

// PatchModel::magnet_pose() for one press `p` without shear, with the derivatives of the
// magnet's position and moment by (c.u_mm, c.v_mm, c.depth_mm) by hand, into g (p, m, dp[0..2],
// dm[0..2]): the same formulas as the jets, term by term, at about a quarter of their
// instructions (the jets carry zero derivatives through every constant). False when the press
// does not reach the magnet (as magnet_pose(), by the reach test of contact_field_ut()). Equal
// to the jets to rounding (physics_test's FieldJacobianEqualsTheTemplatesJets).
bool single_press_pose(const PatchModel& model, const PatchModel::Magnet& m, const SinglePress& p,
                       detail::MagnetJet* g) {
  if (!p.pressing) return false;
  const double du = m.u - p.u, dv = m.v - p.v;
  const double s2 = du * du * p.inv_lu2 + dv * dv * p.inv_lv2;
  if (!(s2 < kPlateKernelCutoff * kPlateKernelCutoff)) return false;
  // The unknowns' index: 0 the press's u, 1 its v, 2 its depth. d(du)/du_c = -1, d(dv)/dv_c = -1.
  const double s_sq = s2 + p.a2;
  const double s = s_sq > 0 ? std::sqrt(s_sq) : 0.0;
  const double inv_s = s > 0 ? 1 / s : 0.0;
  const double ks = 0.5 * inv_s;  // d s / d s_sq (none at the point of a point load)
  const double ds[3] = {-2 * du * p.inv_lu2 * ks, -2 * dv * p.inv_lv2 * ks, p.da2 * ks};
  double gk, dg, d2g;
  plate_kernel(s, &gk, &dg, &d2g);
  const bool off_centre = s > 1e-6;
  const double q = off_centre ? dg * inv_s : 0.0;  // g'(s) / s, and its derivative by s
  const double dq = off_centre ? (d2g * s - dg) * (inv_s * inv_s) : 0.0;
  const double amp = p.amp;
  const double damp[3] = {0, 0, p.damp};
  const double ddu[3] = {-1, 0, 0}, ddv[3] = {0, -1, 0};
  const double w = amp * gk;
  const double pu = -(amp * q * du * p.inv_lu2), pv = -(amp * q * dv * p.inv_lv2);
  // Surface coordinates of the moved magnet (uu, vv, hh) and their derivatives: in-plane by the
  // slope (and the drag toward the press, PatchDesign::inplane_drag), down by the deflection.
  const double lateral = p.lateral, drag = p.drag;
  double uu = m.u - lateral * pu, vv = m.v - lateral * pv;
  if (drag != 0) {
    uu -= model.drag_toward(amp, gk, du, model.spread_u_mm());
    vv -= model.drag_toward(amp, gk, dv, model.spread_v_mm());
  }
  const double hh = m.h - w;
  double duu[3], dvv[3], dhh[3], dpu[3], dpv[3];
  for (int k = 0; k < 3; ++k) {
    const double dgk = dg * ds[k], dqk = dq * ds[k];
    dhh[k] = -(damp[k] * gk + amp * dgk);
    dpu[k] = -((damp[k] * q + amp * dqk) * du + amp * q * ddu[k]) * p.inv_lu2;
    dpv[k] = -((damp[k] * q + amp * dqk) * dv + amp * q * ddv[k]) * p.inv_lv2;
    duu[k] = -lateral * dpu[k];
    dvv[k] = -lateral * dpv[k];
  }
  if (drag != 0) {
    for (int k = 0; k < 3; ++k) {
      const double dagk = -dhh[k];  // d(amp g)
      duu[k] -= drag * (dagk * du + amp * gk * ddu[k]) * p.inv_lu;
      dvv[k] -= drag * (dagk * dv + amp * gk * ddv[k]) * p.inv_lv;
    }
  }
  // The moment follows the surface normal, its magnitude kept: (bu, bv, bz) in the local frame.
  const Vec3<double>& ml = m.m_loc;
  const double mu = ml.x - pu * ml.z, mv = ml.y - pv * ml.z, mz = ml.z;
  const double inv_n2 = 1 / (mu * mu + mv * mv + mz * mz);
  const double kk = std::sqrt(dot(ml, ml) * inv_n2);
  const double bu = mu * kk, bv = mv * kk, bz = mz * kk;
  // The derivatives of the local moment (bu, bv, bz).
  double dbu[3], dbv[3], dbz[3];
  for (int k = 0; k < 3; ++k) {
    const double dmu = -dpu[k] * ml.z, dmv = -dpv[k] * ml.z;
    const double dkk = kk > 0 ? -kk * (mu * dmu + mv * dmv) * inv_n2 : 0.0;
    dbu[k] = dmu * kk + mu * dkk;
    dbv[k] = dmv * kk + mv * dkk;
    dbz[k] = mz * dkk;
  }
  if (p.flat) {  // surface coordinates are 3D ones
    g->p[0] = uu, g->p[1] = vv, g->p[2] = hh;
    g->m[0] = bu, g->m[1] = bv, g->m[2] = bz;
    for (int k = 0; k < 3; ++k) {
      g->dp[k][0] = duu[k], g->dp[k][1] = dvv[k], g->dp[k][2] = dhh[k];
      g->dm[k][0] = dbu[k], g->dm[k][1] = dbv[k], g->dm[k][2] = dbz[k];
    }
    return true;
  }
  // A cylinder: the 3D pose by the surface's frame at (uu, vv, hh). Moving along u turns the
  // frame about the axis by du / radius (d t_u = -n, d n = t_u) and moves the point by
  // (radius + h) / radius along t_u.
  Vec3<double> tu, tv, nn;
  const Vec3<double> pos = model.surface_point(uu, vv, hh, &tu, &tv, &nn);
  const Vec3<double> mom = tu * bu + tv * bv + nn * bz;
  const double r = model.design().radius_mm;
  g->p[0] = pos.x, g->p[1] = pos.y, g->p[2] = pos.z;
  g->m[0] = mom.x, g->m[1] = mom.y, g->m[2] = mom.z;
  for (int k = 0; k < 3; ++k) {
    const double dth = duu[k] / r;
    const Vec3<double> dp = tu * (duu[k] * (r + hh) / r) + tv * dvv[k] + nn * dhh[k];
    const Vec3<double> dm = tu * (dbu[k] + dth * bz) + tv * dbv[k] + nn * (dbz[k] - dth * bu);
    g->dp[k][0] = dp.x, g->dp[k][1] = dp.y, g->dp[k][2] = dp.z;
    g->dm[k][0] = dm.x, g->dm[k][1] = dm.y, g->dm[k][2] = dm.z;
  }
  return true;
}

// Magnets [first, ...) of the model's rows (PatchModel::magnet_rows_, `nm` magnets) as the pose
// kernels read them.
detail::MagnetArrays magnets_from(const std::vector<double>& rows, std::size_t first) {
  const std::size_t nm = rows.size() / 6;
  const double* r = rows.data() + first;
  return {r, r + nm, r + 2 * nm, r + 3 * nm, r + 4 * nm, r + 5 * nm};
}

Error bad(const std::string& what) {
  return make_error(ErrorCode::kInvalidArgument, "patch design: " + what);
}

}  // namespace

Status validate(const PatchDesign& d) {
  auto positive = [](double x) { return std::isfinite(x) && x > 0; };
  if (!positive(d.size_u_mm) || !positive(d.size_v_mm))
    return bad("size_u_mm and size_v_mm must be > 0");
  if (!positive(d.thickness_mm)) return bad("thickness_mm must be > 0");
  if (d.magnets_u < 1 || d.magnets_v < 1 || d.magnets_u * d.magnets_v > 4096)
    return bad("magnets_u/v must be 1..64");
  if (d.sensors_u < 1 || d.sensors_v < 1 || d.sensors_u * d.sensors_v > kMaxSensors)
    return bad("sensors_u/v must give 1..256 sensors");
  if (!positive(d.magnet_pitch_mm) || !positive(d.sensor_pitch_mm))
    return bad("pitches must be > 0");
  if (!positive(d.magnet_diameter_mm) || !positive(d.magnet_height_mm) ||
      !positive(d.remanence_t)) {
    return bad("magnet_diameter_mm, magnet_height_mm and remanence_t must be > 0");
  }
  if (!positive(d.sensor_depth_mm) || d.sensor_depth_mm < d.thickness_mm)
    return bad("sensor_depth_mm must be >= thickness_mm");
  if (!positive(d.spread_mm)) return bad("spread_mm must be > 0");
  if (!std::isfinite(d.lateral_mm) || d.lateral_mm < 0) return bad("lateral_mm must be >= 0");
  if (!std::isfinite(d.anisotropy) || std::fabs(d.anisotropy) >= 0.5)
    return bad("anisotropy must be in (-0.5, 0.5)");
  if (!std::isfinite(d.tip_crush_mm) || d.tip_crush_mm < 0) return bad("tip_crush_mm must be >= 0");
  if (!std::isfinite(d.inplane_drag) || d.inplane_drag < 0 || d.inplane_drag > 1)
    return bad("inplane_drag must be in [0, 1]");
  if (!std::isfinite(d.creep_fraction) || d.creep_fraction < 0 || d.creep_fraction >= 1)
    return bad("creep_fraction must be in [0, 1)");
  if (!positive(d.creep_time_s) || d.creep_time_s > 3600)
    return bad("creep_time_s must be in (0, 3600]");
  if (!std::isfinite(d.creep_slow_fraction) || d.creep_slow_fraction < 0 ||
      d.creep_fraction + d.creep_slow_fraction >= 1)
    return bad("creep_slow_fraction must be >= 0, and creep_fraction + creep_slow_fraction < 1");
  if (!positive(d.creep_slow_time_s) || d.creep_slow_time_s > 3600)
    return bad("creep_slow_time_s must be in (0, 3600]");
  if (!std::isfinite(d.stiffness_n_per_mm) || d.stiffness_n_per_mm <= 0)
    return bad("stiffness_n_per_mm must be > 0");
  if (!positive(d.shear_stiffness_n_per_mm)) return bad("shear_stiffness_n_per_mm must be > 0");
  if (!positive(d.shear_spread_mm)) return bad("shear_spread_mm must be > 0");
  if (!std::isfinite(d.indenter_tip_radius_mm) || d.indenter_tip_radius_mm < 0 ||
      d.indenter_tip_radius_mm > kMaxIndenterTipRadiusMm) {
    return bad("indenter_tip_radius_mm must be in [0, 50]");
  }
  if (d.sensor_list.empty() && ((d.sensors_u - 1) * d.sensor_pitch_mm > d.size_u_mm ||
                                (d.sensors_v - 1) * d.sensor_pitch_mm > d.size_v_mm)) {
    return bad("the sensor grid does not fit inside the patch");
  }
  if (d.magnet_list.size() > 4096) return bad("at most 4096 magnets in magnet_list");
  if (d.sensor_list.size() > static_cast<std::size_t>(kMaxSensors))
    return bad("at most 256 sensors in sensor_list");
  for (std::size_t k = 0; k < d.magnet_list.size(); ++k) {
    const MagnetPlacement& m = d.magnet_list[k];
    const std::string at = "magnet_list[" + std::to_string(k) + "]";
    if (!std::isfinite(m.u_mm) || !std::isfinite(m.v_mm) || !std::isfinite(m.centre_height_mm))
      return bad(at + ": position must be finite");
    if (m.polarity != 1 && m.polarity != -1) return bad(at + ": polarity must be +1 or -1");
  }
  for (std::size_t k = 0; k < d.sensor_list.size(); ++k) {
    const SensorPlacement& c = d.sensor_list[k];
    const std::string at = "sensor_list[" + std::to_string(k) + "]";
    if (!std::isfinite(c.u_mm) || !std::isfinite(c.v_mm) || !std::isfinite(c.yaw_deg))
      return bad(at + ": position and yaw must be finite");
    if (std::fabs(c.u_mm) > d.size_u_mm / 2 || std::fabs(c.v_mm) > d.size_v_mm / 2)
      return bad(at + ": outside the patch");
    if (!positive(c.depth_mm) || c.depth_mm < d.thickness_mm)
      return bad(at + ": depth_mm must be >= thickness_mm");
    if (d.surface == SurfaceKind::kCylinder && d.radius_mm <= c.depth_mm + 1)
      return bad(at + ": cylinder radius_mm must exceed its depth_mm + 1");
  }
  if (d.surface == SurfaceKind::kCylinder) {
    if (!positive(d.radius_mm) || d.radius_mm <= d.sensor_depth_mm + 1)
      return bad("cylinder radius_mm must exceed sensor_depth_mm + 1");
    if (d.size_u_mm / d.radius_mm > 1.5 * M_PI)
      return bad("cylinder arc (size_u_mm / radius_mm) must be below 270 degrees");
  }
  if (!mlx90393::config_valid(d.sensor_config))
    return bad("sensor_config out of the MLX90393's ranges");
  return Status::Ok();
}

Result<PatchModel> PatchModel::nominal(const PatchDesign& design) {
  return build(design, 0, FabricationVariation::none());
}

Result<PatchModel> PatchModel::fabricated(const PatchDesign& design, uint64_t hardware_uid,
                                          const FabricationVariation& variation) {
  return build(design, hardware_uid, variation);
}

Result<PatchModel> PatchModel::build(const PatchDesign& d, uint64_t seed,
                                     const FabricationVariation& var) {
  if (Status s = validate(d); !s.ok()) return s.error();
  // Draws the unit's parameters (the order of the draws fixes every UID's unit), then
  // assembles the model from them.
  UnitParameters p;
  Rng rng(seed ^ 0x5EEDF00DCAFEull);
  p.spread_mm = d.spread_mm * (1 + var.spread_rel_sd * rng.normal());
  p.lateral_mm = std::fmax(0.0, d.lateral_mm * (1 + var.lateral_rel_sd * rng.normal()));

  const double moment =
      cylinder_moment_am2(d.remanence_t, d.magnet_diameter_mm, d.magnet_height_mm);
  // The magnets at rest as designed (grid or list), then each one's fabrication variation.
  std::vector<MagnetPlacement> magnets = d.magnet_list;
  if (magnets.empty()) {
    for (int j = 0; j < d.magnets_v; ++j) {
      for (int i = 0; i < d.magnets_u; ++i) {
        magnets.push_back({(i - (d.magnets_u - 1) / 2.0) * d.magnet_pitch_mm,
                           (j - (d.magnets_v - 1) / 2.0) * d.magnet_pitch_mm,
                           d.magnet_centre_height_mm,
                           d.polarity == Polarity::kCheckerboard && (i + j) % 2 ? -1 : 1});
      }
    }
  }
  for (const MagnetPlacement& at : magnets) {
    MagnetParameters m;
    m.u_mm = at.u_mm + var.magnet_position_sd_mm * rng.normal();
    m.v_mm = at.v_mm + var.magnet_position_sd_mm * rng.normal();
    m.h_mm = at.centre_height_mm + var.magnet_height_sd_mm * rng.normal();
    const double sign = at.polarity < 0 ? -1.0 : 1.0;
    const double mag = moment * (1 + var.magnet_moment_rel_sd * rng.normal());
    const double tu = var.magnet_tilt_sd_rad * rng.normal(),
                 tv = var.magnet_tilt_sd_rad * rng.normal();
    const double n = std::sqrt(1 + tu * tu + tv * tv);
    m.moment_am2 = Vec3<double>{tu / n, tv / n, 1 / n} * (sign * mag);
    p.magnets.push_back(m);
  }
  std::vector<SensorPlacement> sensors = d.sensor_list;
  if (sensors.empty()) {
    for (int j = 0; j < d.sensors_v; ++j) {
      for (int i = 0; i < d.sensors_u; ++i) {
        sensors.push_back({(i - (d.sensors_u - 1) / 2.0) * d.sensor_pitch_mm,
                           (j - (d.sensors_v - 1) / 2.0) * d.sensor_pitch_mm, d.sensor_depth_mm,
                           0});
      }
    }
  }
  for (const SensorPlacement& at : sensors) {
    SensorParameters s;
    s.u_mm = at.u_mm + var.sensor_position_sd_mm * rng.normal();
    s.v_mm = at.v_mm + var.sensor_position_sd_mm * rng.normal();
    s.h_mm = -at.depth_mm + var.sensor_position_sd_mm * rng.normal();
    // A small mounting error turns the chip against the local surface frame, after the turn
    // about the normal it was mounted with.
    s.mounting = rotation_from_vector(Vec3<double>{rng.normal(), rng.normal(), rng.normal()} *
                                      var.sensor_rotation_sd_rad);
    if (at.yaw_deg != 0) {
      const Mat3 yaw = rotation_from_vector({0, 0, at.yaw_deg * M_PI / 180});
      Mat3 both;
      for (int r = 0; r < 3; ++r) {
        const Vec3<double>& row = s.mounting.r[r];
        both.r[r] = yaw.r[0] * row.x + yaw.r[1] * row.y + yaw.r[2] * row.z;
      }
      s.mounting = both;
    }
    s.gain = {1 + var.sensor_gain_rel_sd * rng.normal(), 1 + var.sensor_gain_rel_sd * rng.normal(),
              1 + var.sensor_gain_rel_sd * rng.normal()};
    p.sensors.push_back(s);
  }
  return assemble(d, p);
}

PatchDesign class_design(const PatchDesign& design) {
  PatchDesign d = design;
  d.anisotropy = 0;      // the unit's own anisotropy in its parameters,
  d.tip_crush_mm = 0;    // the plate bent by the whole depth,
  d.inplane_drag = 0;    // in-plane motion by the slope alone,
  d.creep_fraction = 0;  // no lag
  d.creep_slow_fraction = 0;
  return d;
}

Result<PatchModel> PatchModel::of_unit_file(const PatchDesign& design,
                                            const UnitParameters& params) {
  PatchDesign d = class_design(design);
  d.creep_fraction = params.creep_fraction;
  d.creep_time_s = params.creep_time_s;
  d.creep_slow_fraction = params.creep_slow_fraction;
  d.creep_slow_time_s = params.creep_slow_time_s;
  return from_parameters(d, params);
}

Result<PatchModel> PatchModel::from_parameters(const PatchDesign& d, const UnitParameters& u) {
  if (Status s = validate(d); !s.ok()) return s.error();
  auto fail = [](const std::string& what) {
    return make_error(ErrorCode::kInvalidArgument, "unit parameters: " + what);
  };
  if (static_cast<int>(u.magnets.size()) != d.magnet_count() ||
      static_cast<int>(u.sensors.size()) != d.sensor_count()) {
    return fail("the design has " + std::to_string(d.magnet_count()) + " magnets and " +
                std::to_string(d.sensor_count()) + " sensors, the parameters " +
                std::to_string(u.magnets.size()) + " and " + std::to_string(u.sensors.size()));
  }
  auto finite3 = [](const Vec3<double>& v) {
    return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
  };
  if (!std::isfinite(u.spread_mm) || !(u.spread_mm > 0)) return fail("spread_mm must be > 0");
  if (!std::isfinite(u.lateral_mm) || !(u.lateral_mm >= 0)) return fail("lateral_mm must be >= 0");
  if (!std::isfinite(u.anisotropy) || !(std::fabs(u.anisotropy + d.anisotropy) < 0.5)) {
    return fail("anisotropy, with the design's, must be in (-0.5, 0.5)");
  }
  if (!(std::fabs(u.depth_zero_mm) <= 0.2 * d.thickness_mm)) {
    return fail("depth_zero_mm must be within +-20 % of the lattice's thickness (+-" +
                std::to_string(0.2 * d.thickness_mm) + " mm)");
  }
  for (std::size_t i = 0; i < u.magnets.size(); ++i) {
    const MagnetParameters& m = u.magnets[i];
    if (!std::isfinite(m.u_mm) || !std::isfinite(m.v_mm) || !std::isfinite(m.h_mm) ||
        !finite3(m.moment_am2) || !(dot(m.moment_am2, m.moment_am2) > 0)) {
      return fail("magnet " + std::to_string(i) + ": non-finite position or zero moment");
    }
  }
  for (std::size_t i = 0; i < u.sensors.size(); ++i) {
    const SensorParameters& s = u.sensors[i];
    bool ok = std::isfinite(s.u_mm) && std::isfinite(s.v_mm) && std::isfinite(s.h_mm) &&
              finite3(s.gain) && s.gain.x != 0 && s.gain.y != 0 && s.gain.z != 0;
    for (int r = 0; r < 3 && ok; ++r) {
      for (int c = 0; c < 3; ++c) {
        const double e = dot(s.mounting.r[r], s.mounting.r[c]) - (r == c ? 1.0 : 0.0);
        ok = ok && std::fabs(e) < 1e-6;
      }
    }
    if (!ok) {
      return fail("sensor " + std::to_string(i) +
                  ": non-finite position, zero gain or a mounting that is not a rotation");
    }
  }
  if (u.field_correction != nullptr && u.field_correction->channels() != d.channel_count()) {
    return fail("the field correction has " + std::to_string(u.field_correction->channels()) +
                " channels, the design " + std::to_string(d.channel_count()));
  }
  return assemble(d, u);
}

UnitParameters PatchModel::parameters() const {
  UnitParameters u;
  u.spread_mm = spread_;
  u.anisotropy = anisotropy_;
  u.depth_zero_mm = depth_zero_;
  u.lateral_mm = lateral_;
  u.field_correction = correction_;
  for (const Magnet& m : magnets_) u.magnets.push_back({m.u, m.v, m.h, m.m_loc});
  for (const Sensor& s : sensors_) u.sensors.push_back({s.u, s.v, s.h, s.mounting, s.gain});
  return u;
}

Result<PatchModel> PatchModel::assemble(const PatchDesign& d, const UnitParameters& u,
                                        bool point_magnets) {
  PatchModel p;
  p.design_ = d;
  p.spread_ = u.spread_mm;
  p.anisotropy_ = u.anisotropy;
  p.depth_zero_ = u.depth_zero_mm;
  p.spread_u_ = u.spread_mm * (1 + d.anisotropy + u.anisotropy);
  p.spread_v_ = u.spread_mm * (1 - d.anisotropy - u.anisotropy);
  p.lateral_ = u.lateral_mm;
  p.correction_ = u.field_correction;
  for (const MagnetParameters& m : u.magnets) {
    Magnet mg;
    mg.u = m.u_mm;
    mg.v = m.v_mm;
    mg.h = m.h_mm;
    mg.m_loc = m.moment_am2;
    p.magnets_.push_back(mg);
  }
  const std::size_t nm = p.magnets_.size();
  p.magnet_rows_.resize(6 * nm);
  for (std::size_t mi = 0; mi < nm; ++mi) {
    const Magnet& m = p.magnets_[mi];
    const double row[6] = {m.u, m.v, m.h, m.m_loc.x, m.m_loc.y, m.m_loc.z};
    for (std::size_t r = 0; r < 6; ++r) p.magnet_rows_[r * nm + mi] = row[r];
  }
  for (const SensorParameters& sp : u.sensors) {
    Sensor s;
    s.u = sp.u_mm;
    s.v = sp.v_mm;
    s.h = sp.h_mm;
    Vec3<double> tu, tv, n;
    s.pos = p.surface_point(s.u, s.v, s.h, &tu, &tv, &n);
    // The sensor's axes: the local surface frame, turned by the mounting rotation.
    const Vec3<double> ax[3] = {tu, tv, n};
    for (int r = 0; r < 3; ++r) {
      const Vec3<double>& e = sp.mounting.r[r];
      s.frame.r[r] = ax[0] * e.x + ax[1] * e.y + ax[2] * e.z;
    }
    s.mounting = sp.mounting;
    s.gain = sp.gain;
    p.sensors_.push_back(s);
  }
  p.octupole_mm2_ =
      point_magnets ? 0.0 : cylinder_octupole_mm2(d.magnet_diameter_mm, d.magnet_height_mm);
  // Rest field of every magnet at every sensor, in 3D.
  const std::size_t ns = p.sensors_.size();
  p.rest_.resize(p.magnets_.size() * ns);
  for (std::size_t mi = 0; mi < p.magnets_.size(); ++mi) {
    const Magnet& m = p.magnets_[mi];
    Vec3<double> pos, moment3;
    p.magnet_pose<double>(m.u, m.v, m.h, m.m_loc, p.spread_u_, p.spread_v_, p.lateral_, {}, &pos,
                          &moment3);
    for (std::size_t si = 0; si < ns; ++si)
      p.rest_[mi * ns + si] = magnet_field_ut(moment3, p.sensors_[si].pos - pos, p.octupole_mm2_);
  }
  for (const Sensor& s : p.sensors_) {
    p.sx_.push_back(s.pos.x);
    p.sy_.push_back(s.pos.y);
    p.sz_.push_back(s.pos.z);
  }
  for (const Vec3<double>& r : p.rest_) {
    p.rx_.push_back(r.x);
    p.ry_.push_back(r.y);
    p.rz_.push_back(r.z);
  }
  return p;
}

Result<PatchModel> PatchModel::with_disc_magnets(const PatchModel& unit) {
  const PatchDesign& d = unit.design_;
  const UnitParameters p = unit.parameters();
  const std::size_t n = p.magnets.size() * static_cast<std::size_t>(kDiscPoints);
  if (n > 4096) {
    return make_error(ErrorCode::kInvalidArgument,
                      "disc magnets: " + std::to_string(n) + " cubature points, at most 4096");
  }
  // Across the disc: squared radius at the 2 Gauss points of [0, r^2] (weights 1/2), 8 angles
  // (1/8 each); along the height: 3 Gauss points on [-h/2, h/2] (weights 5/18, 8/18, 5/18).
  const double r = 0.5 * d.magnet_diameter_mm, half_h = 0.5 * d.magnet_height_mm;
  struct Point {
    double du, dv, dh, w;
  };
  std::vector<Point> pts;
  const double heights[3][2] = {
      {-std::sqrt(0.6), 5.0 / 18}, {0.0, 8.0 / 18}, {std::sqrt(0.6), 5.0 / 18}};
  for (const auto& [zh, wz] : heights) {
    for (double t : {0.5 - 0.5 / std::sqrt(3.0), 0.5 + 0.5 / std::sqrt(3.0)}) {
      const double rho = r * std::sqrt(t);
      for (int k = 0; k < 8; ++k) {
        const double a = k * M_PI / 4;
        pts.push_back({rho * std::cos(a), rho * std::sin(a), zh * half_h, wz * 0.5 / 8});
      }
    }
  }
  PatchDesign discs = d;
  discs.magnet_list.clear();
  UnitParameters q = p;
  q.magnets.clear();
  for (const MagnetParameters& m : p.magnets) {
    for (const Point& t : pts) {
      discs.magnet_list.push_back(
          {m.u_mm + t.du, m.v_mm + t.dv, m.h_mm + t.dh, m.moment_am2.z >= 0 ? 1 : -1});
      q.magnets.push_back({m.u_mm + t.du, m.v_mm + t.dv, m.h_mm + t.dh, m.moment_am2 * t.w});
    }
  }
  return assemble(discs, q, /*point_magnets=*/true);  // the parameters are the unit's, checked
}

void PatchModel::rest_field_ut(std::span<double> out) const {
  const std::size_t ns = sensors_.size();
  for (std::size_t si = 0; si < ns; ++si) {
    Vec3<double> b{};
    for (std::size_t mi = 0; mi < magnets_.size(); ++mi) b = b + rest_[mi * ns + si];
    sensor_reading(sensors_[si], b, &out[3 * si]);
  }
}

void PatchModel::contact_jacobian(const Contact& c, std::span<double> jacobian,
                                  std::span<double> field) const {
  const Contact without_shear{c.u_mm, c.v_mm, c.depth_mm, c.tip_radius_mm};
  double scratch[3 * kMaxSensors];
  contact_field_jacobian_ut(std::span<const Contact>(&without_shear, 1), false,
                            field.empty() ? std::span<double>(scratch) : field, jacobian);
}

template <int K>
void PatchModel::field_jacobian(std::span<const Contact> contacts, int per_contact, double* field,
                                double* jacobian) const {
  using D = Dual<K>;
  const std::size_t ns = sensors_.size();
  const detail::DipoleSumJet sum = detail::dipole_sum_jet();  // AVX-512, AVX2 or baseline
  ContactT<D> cd[kMaxJetContacts];
  for (std::size_t j = 0; j < contacts.size(); ++j) {
    const Contact& c = contacts[j];
    const int o = static_cast<int>(j) * per_contact;
    cd[j].u_mm = D::variable(c.u_mm, o);
    cd[j].v_mm = D::variable(c.v_mm, o + 1);
    cd[j].depth_mm = D::variable(c.depth_mm, o + 2);
    cd[j].tip_radius_mm = c.tip_radius_mm;
    cd[j].shear_u_n = per_contact == 5 ? D::variable(c.shear_u_n, o + 3) : D(c.shear_u_n);
    cd[j].shear_v_n = per_contact == 5 ? D::variable(c.shear_v_n, o + 4) : D(c.shear_v_n);
  }
  const std::span<const ContactT<D>> jets(cd, contacts.size());
  double ax[kMaxSensors], ay[kMaxSensors], az[kMaxSensors];  // the first ns are read
  std::fill_n(ax, ns, 0.0);
  std::fill_n(ay, ns, 0.0);
  std::fill_n(az, ns, 0.0);
  double jx[K * kMaxSensors], jy[K * kMaxSensors], jz[K * kMaxSensors];
  std::fill_n(jx, K * ns, 0.0);
  std::fill_n(jy, K * ns, 0.0);
  std::fill_n(jz, K * ns, 0.0);
  const D lu(spread_u_), lv(spread_v_), lat(lateral_);
  PressTerms<D> terms[kMaxJetContacts];  // each press's terms once for every magnet
  for (std::size_t j = 0; j < contacts.size(); ++j) terms[j] = press_terms(cd[j], lu, lv);
  // One press without shear (a single-contact fit's every Jacobian): the deformation's
  // derivatives by hand (single_press_pose()); otherwise by the jets of magnet_pose().
  const bool single =
      K == 3 && contacts.size() == 1 && contacts[0].shear_u_n == 0 && contacts[0].shear_v_n == 0;
  std::optional<SinglePress> press;
  if constexpr (K == 3) {
    if (single) press.emplace(*this, contacts[0], terms[0]);
  }
  // The moved magnets' poses a few at a time, then their sums: poses of successive magnets
  // overlap in the CPU, which a sum between them would keep apart.
  constexpr int kPosesHeld = 8;
  detail::MagnetJet poses[kPosesHeld];
  std::size_t posed[kPosesHeld];
  int held = 0;
  auto flush = [&] {
    for (int i = 0; i < held; ++i) {
      const std::size_t at = posed[i] * ns;
      sum(ns, poses[i], sx_.data(), sy_.data(), sz_.data(), rx_.data() + at, ry_.data() + at,
          rz_.data() + at, ax, ay, az, jx, jy, jz);
    }
    held = 0;
  };
  for (std::size_t mi = 0; mi < magnets_.size(); ++mi) {
    const Magnet& m = magnets_[mi];
    detail::MagnetJet& g = poses[held];
    g.unknowns = K;
    g.octupole = 0.5 * kDipoleScale * octupole_mm2_;
    if (single) {
      if (!single_press_pose(*this, m, *press, &g)) continue;
    } else {
      bool reached = false;  // magnet_pose() would say so, after the magnet's rest pose in jets
      for (const Contact& c : contacts)
        reached = reached || (presses(c) && magnet_in_reach(m, c.u_mm, c.v_mm));
      if (!reached) continue;
      Vec3<D> pos, mom;
      if (!magnet_pose(D(m.u), D(m.v), D(m.h), lift<D>(m.m_loc), lu, lv, lat, jets, terms, &pos,
                       &mom)) {
        continue;
      }
      g.p[0] = pos.x.v, g.p[1] = pos.y.v, g.p[2] = pos.z.v;
      g.m[0] = mom.x.v, g.m[1] = mom.y.v, g.m[2] = mom.z.v;
      for (int k = 0; k < K; ++k) {
        g.dp[k][0] = pos.x.d[k], g.dp[k][1] = pos.y.d[k], g.dp[k][2] = pos.z.d[k];
        g.dm[k][0] = mom.x.d[k], g.dm[k][1] = mom.y.d[k], g.dm[k][2] = mom.z.d[k];
      }
    }
    posed[held] = mi;
    if (++held == kPosesHeld) flush();
  }
  flush();
  for (std::size_t si = 0; si < ns; ++si) {
    sensor_reading(sensors_[si], Vec3<double>{ax[si], ay[si], az[si]}, &field[3 * si]);
    for (int k = 0; k < K; ++k) {  // column k of rows 3 si .. 3 si + 2
      const std::size_t at = static_cast<std::size_t>(k) * ns + si;
      sensor_reading(sensors_[si], Vec3<double>{jx[at], jy[at], jz[at]},
                     &jacobian[3 * si * K + static_cast<std::size_t>(k)], K);
    }
  }
  if (correction_ != nullptr) {
    for (std::size_t j = 0; j < contacts.size(); ++j) {
      const Contact& c = contacts[j];
      correction_->add_with_jacobian(c.u_mm, c.v_mm, c.depth_mm, field, jacobian, K,
                                     static_cast<int>(j) * per_contact);
    }
  }
}

bool PatchModel::contact_field_jacobian_ut(std::span<const Contact> contacts, bool shear,
                                           std::span<double> field,
                                           std::span<double> jacobian) const {
  const int pc = shear ? 5 : 3;
  const int k = static_cast<int>(contacts.size()) * pc;
  const std::size_t nc = static_cast<std::size_t>(channel_count());
  if (contacts.empty() || contacts.size() > static_cast<std::size_t>(kMaxJetContacts) ||
      field.size() < nc || jacobian.size() < nc * static_cast<std::size_t>(k)) {
    return false;
  }
  switch (k) {
    case 3:
      field_jacobian<3>(contacts, pc, field.data(), jacobian.data());
      break;
    case 5:
      field_jacobian<5>(contacts, pc, field.data(), jacobian.data());
      break;
    case 6:
      field_jacobian<6>(contacts, pc, field.data(), jacobian.data());
      break;
    case 9:
      field_jacobian<9>(contacts, pc, field.data(), jacobian.data());
      break;
    case 10:
      field_jacobian<10>(contacts, pc, field.data(), jacobian.data());
      break;
    default:
      field_jacobian<15>(contacts, pc, field.data(), jacobian.data());
      break;
  }
  return true;
}

void PatchModel::contact_field_ut(std::span<const Contact> contacts, std::span<double> out) const {
  const std::size_t ns = sensors_.size();
  const detail::DipoleSum sum = detail::dipole_sum();  // AVX-512, AVX2 or baseline
  const double octupole = 0.5 * kDipoleScale * octupole_mm2_;
  double ax[kMaxSensors], ay[kMaxSensors], az[kMaxSensors];  // the first ns are read
  std::fill_n(ax, ns, 0.0);
  std::fill_n(ay, ns, 0.0);
  std::fill_n(az, ns, 0.0);
  const double lu = spread_u_, lv = spread_v_;
  const double inv_lu2 = 1 / (lu * lu), inv_lv2 = 1 / (lv * lv);
  const bool drag = design_.inplane_drag != 0, flat = design_.surface == SurfaceKind::kFlat;
  // The contacts that press, each with its terms once for every magnet, as many as fit here
  // (the rest, if any, take theirs at each magnet they reach).
  constexpr std::size_t kTermsHeld = 16;
  struct Press {
    const Contact* c;
    PressTerms<double> t;
    bool shear;
  };
  Press held[kTermsHeld];
  std::size_t n_held = 0, first_unheld = contacts.size();
  for (std::size_t j = 0; j < contacts.size(); ++j) {
    const Contact& c = contacts[j];
    if (!presses(c)) continue;
    if (n_held == kTermsHeld) {
      first_unheld = j;
      break;
    }
    held[n_held++] = {&c, press_terms(c, lu, lv), c.shear_u_n != 0 || c.shear_v_n != 0};
  }
  if (n_held == 0) {  // nothing presses: the rest field, which the sums leave out
    for (std::size_t si = 0; si < ns; ++si) {
      sensor_reading(sensors_[si], Vec3<double>{0, 0, 0}, &out[3 * si]);
    }
    return;
  }
  // The moved magnets' poses a few at a time, then their sums (as field_jacobian()).
  constexpr int kPosesHeld = 16;
  std::array<double, 6> pose[kPosesHeld];  // position (mm), moment (A m^2)
  std::size_t posed[kPosesHeld];
  int n_posed = 0;
  auto flush = [&] {
    for (int i = 0; i < n_posed; ++i) {
      const std::size_t at = posed[i] * ns;
      const std::array<double, 6>& q = pose[i];
      sum(ns, q[0], q[1], q[2], q[3], q[4], q[5], octupole, sx_.data(), sy_.data(), sz_.data(),
          rx_.data() + at, ry_.data() + at, rz_.data() + at, ax, ay, az);
    }
    n_posed = 0;
  };
  // Magnet `mi` moved to (uu, vv, hh) on the surface with local moment `mom`, into the poses.
  auto place = [&](std::size_t mi, double uu, double vv, double hh, Vec3<double> mom) {
    Vec3<double> pos{uu, vv, hh};  // a flat surface's frame
    if (!flat) {
      Vec3<double> tu, tv, nn;
      pos = surface_point(uu, vv, hh, &tu, &tv, &nn);
      mom = tu * mom.x + tv * mom.y + nn * mom.z;
    }
    pose[n_posed] = {pos.x, pos.y, pos.z, mom.x, mom.y, mom.z};
    posed[n_posed] = mi;
    if (++n_posed == kPosesHeld) flush();
  };
  const std::size_t nm = magnets_.size();
  const bool single = n_held == 1 && first_unheld == contacts.size() && !held[0].shear;
  if (single) {
    // One press without shear (every evaluation of a single-contact fit): the magnets posed in
    // the vector lanes a block at a time (detail::press_poses(), the formulas below), then
    // summed where they move.
    const detail::PressPoses poses = detail::press_poses();
    detail::PressPose p;
    p.u_mm = held[0].c->u_mm;
    p.v_mm = held[0].c->v_mm;
    p.a2 = held[0].t.a2;
    p.amp_mm = held[0].t.amp_mm;
    p.spread_u_mm = lu;
    p.spread_v_mm = lv;
    p.inv_lu2 = inv_lu2;
    p.inv_lv2 = inv_lv2;
    p.lateral_mm = lateral_;
    p.drag = design_.inplane_drag;
    constexpr std::size_t kBlock = 64;
    double s2[kBlock], uu[kBlock], vv[kBlock], hh[kBlock], bu[kBlock], bv[kBlock], bz[kBlock];
    const double* gd = detail::plate_table().gd;
    for (std::size_t m0 = 0; m0 < nm; m0 += kBlock) {
      const std::size_t n = std::min(kBlock, nm - m0);
      poses(p, n, magnets_from(magnet_rows_, m0), gd, s2, uu, vv, hh, bu, bv, bz);
      for (std::size_t i = 0; i < n; ++i) {
        if (s2[i] < kPlateKernelCutoff * kPlateKernelCutoff) {
          place(m0 + i, uu[i], vv[i], hh[i], Vec3<double>{bu[i], bv[i], bz[i]});
        }
      }
    }
  }
  for (std::size_t mi = 0; mi < nm && !single; ++mi) {
    const Magnet& m = magnets_[mi];
    double w = 0, pu = 0, pv = 0, su = 0, sv = 0;
    bool moved = false;
    // One press's deflection, slope and in-plane shift at this magnet, if it reaches it.
    auto add = [&](const Contact& c, const PressTerms<double>* terms, bool shear) {
      const double du = m.u - c.u_mm, dv = m.v - c.v_mm;
      const double s2 = du * du * inv_lu2 + dv * dv * inv_lv2;
      if (!(s2 < kPlateKernelCutoff * kPlateKernelCutoff)) return;
      moved = true;
      const PressTerms<double> t = terms != nullptr ? *terms : press_terms(c, lu, lv);
      const double amp = t.amp_mm;
      const double s = std::sqrt(s2 + t.a2);
      double g, dg;
      plate_kernel(s, &g, &dg);
      const double q = s > 1e-6 ? dg / s : 0.0;
      w += amp * g;
      pu -= amp * q * du * inv_lu2;
      pv -= amp * q * dv * inv_lv2;
      if (drag) {  // dragged toward the press (PatchDesign::inplane_drag)
        su -= drag_toward(amp, g, du, lu);
        sv -= drag_toward(amp, g, dv, lv);
      }
      if (shear) {
        const double shape = shear_shape(du * du + dv * dv, t.ac2_mm2);
        su += c.shear_u_n * shape;
        sv += c.shear_v_n * shape;
      }
    };
    for (std::size_t j = 0; j < n_held; ++j) add(*held[j].c, &held[j].t, held[j].shear);
    for (std::size_t j = first_unheld; j < contacts.size(); ++j) {
      const Contact& c = contacts[j];
      if (presses(c)) add(c, nullptr, c.shear_u_n != 0 || c.shear_v_n != 0);
    }
    if (!moved) continue;
    const double mu = m.m_loc.x - pu * m.m_loc.z, mv = m.m_loc.y - pv * m.m_loc.z, mz = m.m_loc.z;
    const double k = std::sqrt(dot(m.m_loc, m.m_loc) / (mu * mu + mv * mv + mz * mz));
    place(mi, m.u - lateral_ * pu + su, m.v - lateral_ * pv + sv, m.h - w,
          Vec3<double>{mu * k, mv * k, mz * k});
  }
  flush();
  for (std::size_t si = 0; si < ns; ++si) {
    sensor_reading(sensors_[si], Vec3<double>{ax[si], ay[si], az[si]}, &out[3 * si]);
  }
  if (correction_ != nullptr) {
    for (const Contact& c : contacts) correction_->add_ut(c.u_mm, c.v_mm, c.depth_mm, out.data());
  }
}

double PatchModel::force_n(double depth_mm) const {
  const double d = depth_mm - depth_zero_;  // into the lattice
  if (!(d > 0)) return 0;
  return design_.stiffness_n_per_mm * d + design_.stiffening_n_per_mm3 * d * d * d;
}

}  // namespace skinbus::sim
