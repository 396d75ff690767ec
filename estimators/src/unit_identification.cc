#include "skinbus/estimators/unit_identification.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <type_traits>

#include "jet_traits.h"
#include "skinbus/common/error_format.h"
#include "skinbus/sim/dipole.h"

namespace skinbus::estimators {

namespace {

using sim::Vec3;

constexpr int kMagnetBlock = 6;  // u, v, h, moment x, y, z (in units of the nominal moment)
constexpr int kSensorBlock = 9;  // u, v, h, rotation vector (3), gain (3)
constexpr int kGlobalBlock = 2;  // spread, lateral
constexpr int kMagnetVars = kMagnetBlock + kGlobalBlock + 3;  // + sensor position
using JetM = ceres::Jet<double, kMagnetVars>;
constexpr int kOutVars = 12;  // rotation (3), gain (3), field in 3D (3), sensor position (3)
using JetO = ceres::Jet<double, kOutVars>;
constexpr std::size_t kMaxNear = 64;  // magnets with derivatives per sample

// One fitting sample.
struct Sample {
  double u, v, depth;
  const double* field;            // channels, tared uT
  std::vector<int> near;          // magnets with derivatives
  std::vector<Vec3<double>> far;  // per sensor: frozen field of the other magnets (3D, uT)
};

struct Context {
  const sim::PatchModel* shape;  // nominal model of the design: surface and depth limit only
  double moment_scale;           // nominal moment, A m^2
  double tip_mm;
  double anisotropy;                  // the lattice's, stage 1's (held in stage 2)
  std::vector<sim::Mat3> mounting0;   // per sensor: mounting at the start of the fit
  std::span<const double> inv_sigma;  // per channel
};

// One magnet's pose under a press and at rest. T is double or a jet whose variables are set by
// the caller.
template <typename T>
struct MagnetPose {
  bool moved = false;  // within the plate's reach of the press (else its field does not change)
  Vec3<T> pos, moment, rest_pos, rest_moment;
  double octupole_mm2 = 0;  // the magnet's shape (sim::PatchModel::octupole_mm2())
};

template <typename T>
MagnetPose<T> magnet_pose(const Context& ctx, const Sample& smp, const T* mag, const T& spread_u,
                          const T& spread_v, const T& lateral) {
  MagnetPose<T> out;
  out.octupole_mm2 = ctx.shape->octupole_mm2();
  const sim::ContactT<T> c{T(smp.u), T(smp.v), T(smp.depth), ctx.tip_mm};
  const Vec3<T> m_loc{mag[3] * ctx.moment_scale, mag[4] * ctx.moment_scale,
                      mag[5] * ctx.moment_scale};
  out.moved =
      ctx.shape->magnet_pose(mag[0], mag[1], mag[2], m_loc, spread_u, spread_v, lateral,
                             std::span<const sim::ContactT<T>>(&c, 1), &out.pos, &out.moment);
  if (out.moved) {
    ctx.shape->magnet_pose(mag[0], mag[1], mag[2], m_loc, spread_u, spread_v, lateral,
                           std::span<const sim::ContactT<T>>(), &out.rest_pos, &out.rest_moment);
  }
  return out;
}

// Field change (3D, patch frame, uT) at a sensor from one posed magnet.
template <typename T>
Vec3<T> magnet_term(const MagnetPose<T>& pose, const Vec3<T>& sensor_pos) {
  if (!pose.moved) return Vec3<T>{T(0.0), T(0.0), T(0.0)};
  return sim::magnet_field_ut(pose.moment, sensor_pos - pose.pos, pose.octupole_mm2) -
         sim::magnet_field_ut(pose.rest_moment, sensor_pos - pose.rest_pos, pose.octupole_mm2);
}

// What residual blocks share between evaluations, made anew when the parameters it depends on
// change (compared by value). Ceres runs one thread here (solver_options); the owners' locks keep
// it right if not.
template <typename T>
struct Kept {
  std::vector<double> at, asked;  // the parameters it was made at; those asked for now
  T made{};
  // With `asked` filled: true when `made` is for them; else `at` takes them (remake `made`).
  bool current() {
    if (asked == at) return true;
    at.swap(asked);
    return false;
  }
};

// The poses of one sample's near magnets. A pose depends on the lattice and its magnet, not on
// the sensor, so the sample's sensors (a residual block each) share one pose a magnet, made once
// an evaluation rather than once a sensor. Values and jets apart: Ceres evaluates a step's cost,
// then its Jacobian.
struct NearPoses {
  std::mutex mutex;
  Kept<std::vector<MagnetPose<double>>> values;
  Kept<std::vector<MagnetPose<JetM>>> jets;
};

// The rest field of every magnet at one sensor: it depends on the sensor's position, the magnet
// and the lattice, not on the sample, so the sensor's blocks (one a sample) share it.
struct RestFields {
  std::mutex mutex;
  std::vector<Kept<Vec3<double>>> values;  // by magnet
  std::vector<Kept<Vec3<JetM>>> jets;
};

// Parameter `x` as the SensorResidual's variable `j` (double: the value alone).
template <typename T>
T variable(double x, int j) {
  if constexpr (std::is_same_v<T, double>) {
    (void)j;
    return x;
  } else {
    return T(x, j);
  }
}

// The sample's near magnets posed at lattice `g` and magnet blocks `mags` (jets: variables 0-5
// the magnet's block, 6-7 the lattice).
template <typename T>
const std::vector<MagnetPose<T>>& near_poses(const Context& ctx, const Sample& smp, const double* g,
                                             double const* const* mags,
                                             Kept<std::vector<MagnetPose<T>>>* kept) {
  const std::size_t nm = smp.near.size();
  kept->asked.assign(g, g + kGlobalBlock);
  for (std::size_t i = 0; i < nm; ++i)
    kept->asked.insert(kept->asked.end(), mags[i], mags[i] + kMagnetBlock);
  if (kept->current()) return kept->made;
  kept->made.resize(nm);
  const T spread = variable<T>(g[0], kMagnetBlock), lateral = variable<T>(g[1], kMagnetBlock + 1);
  const T spread_u = spread * (1.0 + ctx.anisotropy), spread_v = spread * (1.0 - ctx.anisotropy);
  for (std::size_t i = 0; i < nm; ++i) {
    T mag[kMagnetBlock];
    for (int j = 0; j < kMagnetBlock; ++j) mag[j] = variable<T>(mags[i][j], j);
    kept->made[i] = magnet_pose<T>(ctx, smp, mag, spread_u, spread_v, lateral);
  }
  return kept->made;
}

// A near magnet's rest field at sensor position `spos` (the sensor's block `s`), from `rest`
// when made at the same sensor position, magnet block `mag` and lattice `g`.
template <typename T>
const Vec3<T>& rest_field(const MagnetPose<T>& pose, const Vec3<T>& spos, const double* s,
                          const double* mag, const double* g, Kept<Vec3<T>>* rest) {
  rest->asked.assign(s, s + 3);
  rest->asked.insert(rest->asked.end(), mag, mag + kMagnetBlock);
  rest->asked.insert(rest->asked.end(), g, g + kGlobalBlock);
  if (!rest->current()) {
    rest->made = sim::magnet_field_ut(pose.rest_moment, spos - pose.rest_pos, pose.octupole_mm2);
  }
  return rest->made;
}

// magnet_term() of a near magnet, its rest field from `rest` (rest_field()).
Vec3<double> near_term(const MagnetPose<double>& pose, const Vec3<double>& spos, const double* s,
                       const double* mag, const double* g, Kept<Vec3<double>>* rest) {
  if (!pose.moved) return Vec3<double>{};
  return sim::magnet_field_ut(pose.moment, spos - pose.pos, pose.octupole_mm2) -
         rest_field(pose, spos, s, mag, g, rest);
}

// near_term() with derivatives: its rest field as jets (made once a sensor and magnet), its
// field under the press in closed form (sim::magnet_field_gradient_ut, made once a block) and
// chained by hand. The pose's jets have their derivatives in variables 0-7 alone, the sensor
// position's in 8-10 alone (SensorResidual's variables).
Vec3<JetM> near_term(const MagnetPose<JetM>& pose, const Vec3<JetM>& spos, const double* s,
                     const double* mag, const double* g, Kept<Vec3<JetM>>* rest) {
  if (!pose.moved) return Vec3<JetM>{JetM(0.0), JetM(0.0), JetM(0.0)};
  constexpr int kPose = kMagnetBlock + kGlobalBlock;
  const JetM* sp[3] = {&spos.x, &spos.y, &spos.z};
  const JetM* pp[3] = {&pose.pos.x, &pose.pos.y, &pose.pos.z};
  const JetM* mp[3] = {&pose.moment.x, &pose.moment.y, &pose.moment.z};
  const Vec3<double> r{sp[0]->a - pp[0]->a, sp[1]->a - pp[1]->a, sp[2]->a - pp[2]->a};
  double d_dr[3][3], d_dm[3][3];
  const Vec3<double> b = sim::magnet_field_gradient_ut(Vec3<double>{mp[0]->a, mp[1]->a, mp[2]->a},
                                                       r, pose.octupole_mm2, d_dr, d_dm);
  const double bv[3] = {b.x, b.y, b.z};
  Vec3<JetM> out;
  JetM* o[3] = {&out.x, &out.y, &out.z};
  for (int i = 0; i < 3; ++i) {
    JetM& oi = *o[i];
    oi.a = bv[i];
    oi.v.setZero();
    for (int j = 0; j < 3; ++j) {
      // r = sensor position - magnet position.
      oi.v.head<kPose>() +=
          d_dm[i][j] * mp[j]->v.head<kPose>() - d_dr[i][j] * pp[j]->v.head<kPose>();
      oi.v.tail<3>() += d_dr[i][j] * sp[j]->v.tail<3>();
    }
  }
  return out - rest_field(pose, spos, s, mag, g, rest);
}

// The sensor's reading of a 3D field: gain * (R(rotation) mounting0 surface-frame) field.
template <typename T>
Vec3<T> sensor_reading(const Context& ctx, int k, const T* rot, const T* gain, const Vec3<T>& b,
                       const T* pos) {
  T r[9];
  ceres::AngleAxisToRotationMatrix(rot, ceres::RowMajorAdapter3x3(r));
  Vec3<T> tu, tv, n;
  ctx.shape->surface_point(pos[0], pos[1], pos[2], &tu, &tv, &n);
  const Vec3<T> ax[3] = {tu, tv, n};
  const sim::Mat3& e0 = ctx.mounting0[static_cast<std::size_t>(k)];
  T out[3];
  for (int row = 0; row < 3; ++row) {
    // Row `row` of R(rot) * mounting0, then of the frame.
    T e[3];
    for (int c = 0; c < 3; ++c) {
      const double m0[3] = {c == 0   ? e0.r[0].x
                            : c == 1 ? e0.r[0].y
                                     : e0.r[0].z,
                            c == 0   ? e0.r[1].x
                            : c == 1 ? e0.r[1].y
                                     : e0.r[1].z,
                            c == 0   ? e0.r[2].x
                            : c == 1 ? e0.r[2].y
                                     : e0.r[2].z};
      e[c] = r[3 * row + 0] * m0[0] + r[3 * row + 1] * m0[1] + r[3 * row + 2] * m0[2];
    }
    const Vec3<T> axis = ax[0] * e[0] + ax[1] * e[1] + ax[2] * e[2];
    out[row] = gain[row] * sim::dot(axis, b);
  }
  return {out[0], out[1], out[2]};
}

// Whitened residuals of one sensor's 3 channels for one sample. Parameter blocks: lattice (2),
// the sensor (9), the sample's near magnets (6 each).
class SensorResidual final : public ceres::CostFunction {
 public:
  SensorResidual(const Context& ctx, const Sample& smp, int sensor, NearPoses* poses,
                 RestFields* rest)
      : ctx_(ctx), smp_(smp), k_(sensor), poses_(poses), rest_(rest) {
    set_num_residuals(3);
    mutable_parameter_block_sizes()->push_back(kGlobalBlock);
    mutable_parameter_block_sizes()->push_back(kSensorBlock);
    for (std::size_t i = 0; i < smp.near.size(); ++i)
      mutable_parameter_block_sizes()->push_back(kMagnetBlock);
  }

  bool Evaluate(double const* const* p, double* residuals, double** jacobians) const override {
    const double* g = p[0];
    const double* s = p[1];
    const std::size_t nm = smp_.near.size();
    const Vec3<double>& far = smp_.far[static_cast<std::size_t>(k_)];
    // A channel without a finite value (a dead channel in a recording) is left out: weight 0.
    const double* yraw = smp_.field + 3 * k_;
    const double* sigma = ctx_.inv_sigma.data() + 3 * k_;
    double y[3], w[3];
    for (int i = 0; i < 3; ++i) {
      const bool known = std::isfinite(yraw[i]);
      y[i] = known ? yraw[i] : 0.0;
      w[i] = known ? sigma[i] : 0.0;
    }
    const std::scoped_lock lock(poses_->mutex, rest_->mutex);
    if (jacobians == nullptr) {
      const Vec3<double> pos3 =
          ctx_.shape->surface_point<double>(s[0], s[1], s[2], nullptr, nullptr, nullptr);
      const std::vector<MagnetPose<double>>& poses =
          near_poses(ctx_, smp_, g, p + 2, &poses_->values);
      Vec3<double> b = far;
      for (std::size_t i = 0; i < nm; ++i)
        b = b + near_term(poses[i], pos3, s, p[2 + i], g, &rest_->values[near(i)]);
      const Vec3<double> out = sensor_reading<double>(ctx_, k_, s + 3, s + 6, b, s);
      residuals[0] = (out.x - y[0]) * w[0];
      residuals[1] = (out.y - y[1]) * w[1];
      residuals[2] = (out.z - y[2]) * w[2];
      return std::isfinite(residuals[0]) && std::isfinite(residuals[1]) &&
             std::isfinite(residuals[2]);
    }
    // Field in 3D with its derivatives: lattice (2), sensor position (3), magnets (6 each).
    if (nm > kMaxNear) return false;
    // Summed: the lattice's and the sensor position's; set below: each near magnet's.
    double dacc[3][kGlobalBlock + 3 + kMagnetBlock * kMaxNear];
    for (auto& row : dacc) std::fill(row, row + kGlobalBlock + 3, 0.0);
    Vec3<double> acc = far;
    JetM spos_in[3];
    for (int j = 0; j < 3; ++j) spos_in[j] = JetM(s[j], kMagnetBlock + kGlobalBlock + j);
    const Vec3<JetM> spos = ctx_.shape->surface_point<JetM>(spos_in[0], spos_in[1], spos_in[2],
                                                            nullptr, nullptr, nullptr);
    const std::vector<MagnetPose<JetM>>& poses = near_poses(ctx_, smp_, g, p + 2, &poses_->jets);
    for (std::size_t i = 0; i < nm; ++i) {
      const Vec3<JetM> b = near_term(poses[i], spos, s, p[2 + i], g, &rest_->jets[near(i)]);
      const JetM* comp[3] = {&b.x, &b.y, &b.z};
      for (int a = 0; a < 3; ++a) {
        const JetM& c = *comp[a];
        (a == 0 ? acc.x : a == 1 ? acc.y : acc.z) += c.a;
        for (int j = 0; j < kGlobalBlock; ++j) dacc[a][j] += c.v[kMagnetBlock + j];
        for (int j = 0; j < 3; ++j)
          dacc[a][kGlobalBlock + j] += c.v[kMagnetBlock + kGlobalBlock + j];
        for (int j = 0; j < kMagnetBlock; ++j)
          dacc[a][kGlobalBlock + 3 + kMagnetBlock * i + static_cast<std::size_t>(j)] = c.v[j];
      }
    }
    // The reading and its derivatives with respect to rotation, gain, field and position.
    JetO rot[3], gain[3], pos[3];
    for (int j = 0; j < 3; ++j) {
      rot[j] = JetO(s[3 + j], j);
      gain[j] = JetO(s[6 + j], 3 + j);
      pos[j] = JetO(s[j], 9 + j);
    }
    const Vec3<JetO> bj{JetO(acc.x, 6), JetO(acc.y, 7), JetO(acc.z, 8)};
    const Vec3<JetO> out = sensor_reading<JetO>(ctx_, k_, rot, gain, bj, pos);
    const JetO* o[3] = {&out.x, &out.y, &out.z};
    for (int r = 0; r < 3; ++r) {
      residuals[r] = (o[r]->a - y[r]) * w[r];
      const Eigen::Matrix<double, kOutVars, 1>& d = o[r]->v;
      // d reading / d x = sum_a d reading / d field_a * d field_a / d x (+ direct terms).
      auto chain = [&](std::size_t var) {
        return d[6] * dacc[0][var] + d[7] * dacc[1][var] + d[8] * dacc[2][var];
      };
      if (jacobians[0] != nullptr) {
        for (int j = 0; j < kGlobalBlock; ++j)
          jacobians[0][r * kGlobalBlock + j] = chain(static_cast<std::size_t>(j)) * w[r];
      }
      if (jacobians[1] != nullptr) {
        double* js = jacobians[1] + r * kSensorBlock;
        for (int j = 0; j < 3; ++j)
          js[j] = (d[9 + j] + chain(kGlobalBlock + static_cast<std::size_t>(j))) * w[r];
        for (int j = 0; j < 3; ++j) js[3 + j] = d[j] * w[r];
        for (int j = 0; j < 3; ++j) js[6 + j] = d[3 + j] * w[r];
      }
      for (std::size_t i = 0; i < nm; ++i) {
        if (jacobians[2 + i] == nullptr) continue;
        for (int j = 0; j < kMagnetBlock; ++j) {
          jacobians[2 + i][r * kMagnetBlock + j] =
              chain(kGlobalBlock + 3 + kMagnetBlock * i + static_cast<std::size_t>(j)) * w[r];
        }
      }
    }
    return std::isfinite(residuals[0]) && std::isfinite(residuals[1]) &&
           std::isfinite(residuals[2]);
  }

 private:
  // The sample's `i`th near magnet's index.
  std::size_t near(std::size_t i) const { return static_cast<std::size_t>(smp_.near[i]); }

  const Context& ctx_;
  const Sample& smp_;
  int k_;
  NearPoses* poses_;  // the sample's, shared by its sensors' blocks
  RestFields* rest_;  // the sensor's, shared by its samples' blocks
};

// A Gaussian prior on one parameter block: (x - centre) / sd per entry.
class PriorResidual final : public ceres::CostFunction {
 public:
  PriorResidual(std::vector<double> centre, std::vector<double> inv_sd)
      : centre_(std::move(centre)), inv_sd_(std::move(inv_sd)) {
    set_num_residuals(static_cast<int>(centre_.size()));
    mutable_parameter_block_sizes()->push_back(static_cast<int>(centre_.size()));
  }
  bool Evaluate(double const* const* p, double* residuals, double** jacobians) const override {
    const std::size_t n = centre_.size();
    for (std::size_t i = 0; i < n; ++i) residuals[i] = (p[0][i] - centre_[i]) * inv_sd_[i];
    if (jacobians != nullptr && jacobians[0] != nullptr) {
      for (std::size_t i = 0; i < n * n; ++i) jacobians[0][i] = 0;
      for (std::size_t i = 0; i < n; ++i) jacobians[0][i * n + i] = inv_sd_[i];
    }
    return true;
  }

 private:
  std::vector<double> centre_, inv_sd_;
};

// Stage 2's progress: a line at the start of each pass and every kEvery iterations, with the
// RMS of every whitened residual (the priors' included), in noise units.
class StageProgress final : public ceres::IterationCallback {
 public:
  static constexpr int kEvery = 5;
  StageProgress(const std::function<void(const std::string&)>& progress, int residuals, int passes)
      : progress_(progress), residuals_(residuals), passes_(passes) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& it) override {
    if (it.iteration % kEvery == 0) {
      char line[160];
      std::snprintf(line, sizeof line,
                    "fitting every magnet and sensor: pass %d of %d, iteration %d, residual "
                    "%.2f noise units (priors included)",
                    pass, passes_, it.iteration, std::sqrt(2 * it.cost / std::max(residuals_, 1)));
      progress_(line);
    }
    return ceres::SOLVER_CONTINUE;
  }
  int pass = 1;

 private:
  const std::function<void(const std::string&)>& progress_;
  int residuals_, passes_;
};

// Stage 2 stops when it has stalled: the cost fell by less than kStallShare of itself over the
// last kOver iterations (a fit the class cannot explain creeps on for tens of iterations, each
// a second or more, moving nothing a residual shows).
class StallStop final : public ceres::IterationCallback {
 public:
  static constexpr int kOver = 5;
  static constexpr double kStallShare = 1e-4;
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& it) override {
    if (it.iteration == 0) costs_.clear();
    costs_.push_back(it.cost);
    const std::size_t n = costs_.size();
    if (n > kOver && costs_[n - 1 - kOver] - it.cost < kStallShare * it.cost) {
      return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    }
    return ceres::SOLVER_CONTINUE;
  }

 private:
  std::vector<double> costs_;
};

// ---- Stage 1: the design's global physics --------------------------------------------------
// Ten numbers that a design file may have wrong for a whole unit and that the per-magnet and
// per-sensor parameters, held to the fabrication spread, cannot absorb: the spread length, the
// lateral coupling, a height offset common to every magnet, a height offset common to every
// sensor (negative: deeper), a scale of every moment, the lattice's anisotropy, the frame the
// presses were made in against the design's (u and v shift, mm; turn, rad), and the depth they
// read at the surface (mm).
constexpr int kGlobals = 10;
constexpr double kRadPerDeg = M_PI / 180;
using JetG = ceres::Jet<double, kGlobals>;

// sim::magnet_field_ut() for stage 1's residuals: doubles as they are; jets through the field's
// closed-form derivatives (sim::magnet_field_gradient_ut) chained with the jets of the offset and
// the moment, rather than every one of the field's operations carried on ten derivatives.
Vec3<double> stage1_field(const Vec3<double>& m, const Vec3<double>& r, double octupole_mm2) {
  return sim::magnet_field_ut(m, r, octupole_mm2);
}
Vec3<JetG> stage1_field(const Vec3<JetG>& m, const Vec3<JetG>& r, double octupole_mm2) {
  double d_dr[3][3], d_dm[3][3];
  const Vec3<double> b =
      sim::magnet_field_gradient_ut(Vec3<double>{m.x.a, m.y.a, m.z.a},
                                    Vec3<double>{r.x.a, r.y.a, r.z.a}, octupole_mm2, d_dr, d_dm);
  const JetG* mj[3] = {&m.x, &m.y, &m.z};
  const JetG* rj[3] = {&r.x, &r.y, &r.z};
  const double bv[3] = {b.x, b.y, b.z};
  Vec3<JetG> out;
  JetG* o[3] = {&out.x, &out.y, &out.z};
  for (int i = 0; i < 3; ++i) {
    o[i]->a = bv[i];
    o[i]->v = d_dm[i][0] * mj[0]->v + d_dm[i][1] * mj[1]->v + d_dm[i][2] * mj[2]->v +
              d_dr[i][0] * rj[0]->v + d_dr[i][1] * rj[1]->v + d_dr[i][2] * rj[2]->v;
  }
  return out;
}

// What every sample's residuals share under the globals: each sensor's position and local
// surface frame, each magnet's place, height and moment, and the rest field of every magnet at
// every sensor (magnet-major). The samples' blocks share it (GlobalShared), made once an
// evaluation rather than once a sample.
template <typename T>
struct GlobalTerms {
  std::vector<Vec3<T>> spos, tu, tv, n;  // by sensor
  std::vector<T> mu, mv, mh;             // by magnet (magnet_globals)
  std::vector<Vec3<T>> m_loc;            // by magnet
  std::vector<Vec3<T>> rest;             // magnet m at sensor k: [m * sensors + k]
};

struct GlobalShared {
  std::mutex mutex;
  Kept<GlobalTerms<double>> values;
  Kept<GlobalTerms<JetG>> jets;
};

struct GlobalContext {
  const sim::PatchModel* shape;
  const sim::UnitParameters* design;  // the design's nominal unit
  double tip_mm;
  std::span<const double> inv_sigma;  // per channel
  GlobalShared* shared;
};

// A part's (u, v) in the presses' frame under globals `g` (GlobalPhysics::frame_*).
template <typename T>
void in_press_frame(const T* g, double u, double v, T* pu, T* pv) {
  using std::cos;
  using std::sin;
  const T c = cos(g[8]), s = sin(g[8]);
  *pu = c * u - s * v + g[6];
  *pv = s * u + c * v + g[7];
}

// Magnet `mp`'s place, height and moment under globals `g` (the moment turned with the frame).
template <typename T>
void magnet_globals(const sim::MagnetParameters& mp, const T* g, T* u, T* v, T* h, Vec3<T>* m_loc) {
  using std::cos;
  using std::sin;
  in_press_frame(g, mp.u_mm, mp.v_mm, u, v);
  *h = T(mp.h_mm) + g[2];
  const T c = cos(g[8]), s = sin(g[8]);
  *m_loc = Vec3<T>{g[4] * (c * mp.moment_am2.x - s * mp.moment_am2.y),
                   g[4] * (s * mp.moment_am2.x + c * mp.moment_am2.y), g[4] * mp.moment_am2.z};
}

// The shared terms under globals `g` (values `gv`), from `kept` when made at the same.
template <typename T>
const GlobalTerms<T>& global_terms(const GlobalContext& ctx, const double* gv, const T* g,
                                   Kept<GlobalTerms<T>>* kept) {
  kept->asked.assign(gv, gv + kGlobals);
  if (kept->current()) return kept->made;
  const sim::UnitParameters& d = *ctx.design;
  const std::size_t ns = d.sensors.size();
  GlobalTerms<T>& t = kept->made;
  for (auto* v : {&t.spos, &t.tu, &t.tv, &t.n}) v->resize(ns);
  using std::cos;
  using std::sin;
  const T c = cos(g[8]), s = sin(g[8]);
  for (std::size_t k = 0; k < ns; ++k) {
    const sim::SensorParameters& sp = d.sensors[k];
    T u, v;
    in_press_frame(g, sp.u_mm, sp.v_mm, &u, &v);
    Vec3<T> tu, tv;
    t.spos[k] = ctx.shape->surface_point<T>(u, v, T(sp.h_mm) + g[3], &tu, &tv, &t.n[k]);
    // The chip turned with the frame: its axes' surface components turned about the normal.
    t.tu[k] = tu * c + tv * s;
    t.tv[k] = tv * c - tu * s;
  }
  const std::size_t nm = d.magnets.size();
  t.rest.resize(nm * ns);
  for (auto* v : {&t.mu, &t.mv, &t.mh}) v->resize(nm);
  t.m_loc.resize(nm);
  for (std::size_t m = 0; m < nm; ++m) {
    magnet_globals(d.magnets[m], g, &t.mu[m], &t.mv[m], &t.mh[m], &t.m_loc[m]);
    Vec3<T> rest_pos, rest_moment;
    ctx.shape->magnet_pose(t.mu[m], t.mv[m], t.mh[m], t.m_loc[m], g[0] * (1.0 + g[5]),
                           g[0] * (1.0 - g[5]), g[1], std::span<const sim::ContactT<T>>(),
                           &rest_pos, &rest_moment);
    for (std::size_t k = 0; k < ns; ++k)
      t.rest[m * ns + k] =
          stage1_field(rest_moment, t.spos[k] - rest_pos, ctx.shape->octupole_mm2());
  }
  return t;
}

// Whitened residuals of every channel of one sample under globals `g`, with the shared terms
// `t` (global_terms()); T is double or JetG.
template <typename T>
void global_residuals(const GlobalContext& ctx, const Sample& smp, const T* g,
                      const GlobalTerms<T>& t, T* out) {
  const sim::UnitParameters& d = *ctx.design;
  const std::size_t ns = d.sensors.size();
  Vec3<T> acc[sim::kMaxSensors];
  for (std::size_t k = 0; k < ns; ++k) acc[k] = Vec3<T>{T(0.0), T(0.0), T(0.0)};
  const sim::ContactT<T> c{T(smp.u), T(smp.v), T(smp.depth) - g[9], ctx.tip_mm};
  for (std::size_t m = 0; m < d.magnets.size(); ++m) {
    Vec3<T> pos, moment;
    if (!ctx.shape->magnet_pose(t.mu[m], t.mv[m], t.mh[m], t.m_loc[m], g[0] * (1.0 + g[5]),
                                g[0] * (1.0 - g[5]), g[1], std::span<const sim::ContactT<T>>(&c, 1),
                                &pos, &moment)) {
      continue;  // beyond the plate's reach: this magnet does not move
    }
    for (std::size_t k = 0; k < ns; ++k)
      acc[k] = acc[k] + stage1_field(moment, t.spos[k] - pos, ctx.shape->octupole_mm2()) -
               t.rest[m * ns + k];
  }
  for (std::size_t k = 0; k < ns; ++k) {
    const sim::SensorParameters& sp = d.sensors[k];
    const double gk[3] = {sp.gain.x, sp.gain.y, sp.gain.z};
    for (int row = 0; row < 3; ++row) {
      const Vec3<double>& e = sp.mounting.r[row];
      const Vec3<T> axis = t.tu[k] * T(e.x) + t.tv[k] * T(e.y) + t.n[k] * T(e.z);
      const std::size_t ch = 3 * k + static_cast<std::size_t>(row);
      const double y = smp.field[ch];
      out[ch] = std::isfinite(y) ? (T(gk[row]) * sim::dot(axis, acc[k]) - T(y)) * ctx.inv_sigma[ch]
                                 : T(0.0);
    }
  }
}

class GlobalResidual final : public ceres::CostFunction {
 public:
  GlobalResidual(const GlobalContext& ctx, const Sample& smp, int channels)
      : ctx_(ctx), smp_(smp), nc_(channels) {
    set_num_residuals(channels);
    mutable_parameter_block_sizes()->push_back(kGlobals);
  }
  bool Evaluate(double const* const* p, double* residuals, double** jacobians) const override {
    const std::size_t nc = static_cast<std::size_t>(nc_);
    const std::lock_guard<std::mutex> lock(ctx_.shared->mutex);
    if (jacobians == nullptr || jacobians[0] == nullptr) {
      global_residuals<double>(ctx_, smp_, p[0],
                               global_terms(ctx_, p[0], p[0], &ctx_.shared->values), residuals);
    } else {
      JetG g[kGlobals];
      for (int j = 0; j < kGlobals; ++j) g[j] = JetG(p[0][j], j);
      JetG out[3 * sim::kMaxSensors];
      global_residuals<JetG>(ctx_, smp_, g, global_terms(ctx_, p[0], g, &ctx_.shared->jets), out);
      for (std::size_t i = 0; i < nc; ++i) {
        residuals[i] = out[i].a;
        for (int j = 0; j < kGlobals; ++j)
          jacobians[0][i * kGlobals + static_cast<std::size_t>(j)] = out[i].v[j];
      }
    }
    for (std::size_t i = 0; i < nc; ++i) {
      if (!std::isfinite(residuals[i])) return false;
    }
    return true;
  }

 private:
  const GlobalContext& ctx_;
  const Sample& smp_;
  int nc_;
};

double inv(double sd, double scale) {
  // A zero spread holds the parameter (a very stiff prior) rather than dividing by zero.
  return 1 / std::fmax(sd * scale, 1e-9 * std::fmax(scale, 1e-3));
}

// Levenberg-Marquardt on one thread, silent, with the options' limits. Sparse problems use
// Eigen's sparse Cholesky: the normal matrix is small (parameters^2), and the alternative's
// multithreaded BLAS would spin on the cores it does not need.
ceres::Solver::Options solver_options(const IdentificationOptions& opt,
                                      ceres::LinearSolverType linear_solver) {
  ceres::Solver::Options so;
  so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  so.linear_solver_type = linear_solver;
  so.sparse_linear_algebra_library_type = ceres::EIGEN_SPARSE;
  so.max_num_iterations = opt.max_iterations;
  so.function_tolerance = opt.function_tolerance;
  so.parameter_tolerance = 1e-9;
  so.num_threads = 1;
  so.logging_type = ceres::SILENT;
  so.minimizer_progress_to_stdout = false;
  return so;
}

// `g` as stage 1's unknowns (the turn in radians).
std::array<double, kGlobals> global_vector(const GlobalPhysics& g) {
  return {g.spread_mm,
          g.lateral_mm,
          g.magnet_height_offset_mm,
          g.sensor_height_offset_mm,
          g.moment_scale,
          g.anisotropy,
          g.frame_du_mm,
          g.frame_dv_mm,
          g.frame_yaw_deg * kRadPerDeg,
          g.depth_zero_mm};
}

std::string describe(const GlobalPhysics& g) {
  char buf[256];
  std::snprintf(
      buf, sizeof buf,
      "spread %.2f mm, anisotropy %.3f, lateral %.2f mm, magnets %.2f mm, sensors %.2f mm, "
      "moments x%.3f, presses' frame (%+.2f, %+.2f) mm %+.2f deg, depth zero %+.3f mm",
      g.spread_mm, g.anisotropy, g.lateral_mm, g.magnet_height_offset_mm, g.sensor_height_offset_mm,
      g.moment_scale, g.frame_du_mm, g.frame_dv_mm, g.frame_yaw_deg, g.depth_zero_mm);
  return buf;
}

// Stage 1 (see the header): the ten globals by Levenberg-Marquardt from each spread start,
// under broad priors about the design; the lowest cost wins. Refuses a fit that ends at a bound.
Result<GlobalPhysics> fit_globals(const sim::PatchModel& nominal, const sim::UnitParameters& design,
                                  std::span<const Sample> samples,
                                  std::span<const double> inv_sigma,
                                  const IdentificationOptions& opt, int* iterations) {
  const int nc = nominal.channel_count();
  GlobalShared shared;
  const GlobalContext ctx{&nominal, &design, opt.tip_radius_mm, inv_sigma, &shared};
  double top_sensor_mm = -1e9;
  for (const sim::SensorParameters& sp : design.sensors)
    top_sensor_mm = std::fmax(top_sensor_mm, sp.h_mm);
  const GlobalPriors& pr = opt.global_priors;
  const double l0 = design.spread_mm, lat0 = design.lateral_mm, a0 = design.anisotropy;
  const double yaw_max = pr.frame_yaw_max_deg * kRadPerDeg;
  const double centre[kGlobals] = {l0, lat0, 0, 0, 1, a0, 0, 0, 0, 0};
  const double lo[kGlobals] = {pr.spread_min_rel * l0,
                               0,
                               -pr.height_max_mm,
                               -pr.height_max_mm,
                               pr.moment_min,
                               -pr.anisotropy_max,
                               -pr.frame_shift_max_mm,
                               -pr.frame_shift_max_mm,
                               -yaw_max,
                               -pr.depth_zero_max_mm};
  const double hi[kGlobals] = {pr.spread_max_rel * l0,
                               pr.lateral_max_mm,
                               pr.height_max_mm,
                               std::fmin(pr.height_max_mm, -top_sensor_mm - 0.5),
                               pr.moment_max,
                               pr.anisotropy_max,
                               pr.frame_shift_max_mm,
                               pr.frame_shift_max_mm,
                               yaw_max,
                               pr.depth_zero_max_mm};
  const double inv_sd[kGlobals] = {
      inv(pr.spread_rel_sd, l0),  1 / pr.lateral_sd_mm,     1 / pr.height_sd_mm,
      1 / pr.height_sd_mm,        1 / pr.moment_rel_sd,     1 / pr.anisotropy_sd,
      1 / pr.frame_shift_sd_mm,   1 / pr.frame_shift_sd_mm, 1 / (pr.frame_yaw_sd_deg * kRadPerDeg),
      inv(pr.depth_zero_sd_mm, 1)};
  const char* names[kGlobals] = {"the spread length",
                                 "the lateral coupling",
                                 "the magnets' height",
                                 "the sensors' height",
                                 "the moments' scale",
                                 "the anisotropy",
                                 "the presses' frame's u shift",
                                 "the presses' frame's v shift",
                                 "the presses' frame's turn",
                                 "the presses' depth zero"};

  const ceres::Solver::Options so = solver_options(opt, ceres::DENSE_NORMAL_CHOLESKY);

  GlobalPhysics best{};
  double best_cost = std::numeric_limits<double>::infinity();
  std::array<double, kGlobals> best_x{};
  int starts = 0;
  for (double f : opt.spread_starts) {
    std::array<double, kGlobals> x = {std::clamp(f * l0, lo[0], hi[0]), lat0, 0, 0, 1,
                                      std::clamp(a0, lo[5], hi[5]),     0,    0, 0, 0};
    ceres::Problem::Options po;
    po.cost_function_ownership = ceres::TAKE_OWNERSHIP;
    ceres::Problem problem(po);
    for (const Sample& smp : samples) {
      problem.AddResidualBlock(new GlobalResidual(ctx, smp, nc), nullptr, x.data());
    }
    problem.AddResidualBlock(new PriorResidual(std::vector<double>(centre, centre + kGlobals),
                                               std::vector<double>(inv_sd, inv_sd + kGlobals)),
                             nullptr, x.data());
    for (int j = 0; j < kGlobals; ++j) {
      problem.SetParameterLowerBound(x.data(), j, lo[j]);
      problem.SetParameterUpperBound(x.data(), j, hi[j]);
    }
    if (!(pr.depth_zero_sd_mm > 0)) {  // held: the presses read 0 at the surface
      problem.SetManifold(x.data(), new ceres::SubsetManifold(kGlobals, {9}));
    }
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    *iterations += static_cast<int>(summary.iterations.size()) - 1;
    ++starts;
    const bool ok = summary.termination_type == ceres::CONVERGENCE ||
                    summary.termination_type == ceres::NO_CONVERGENCE;
    const double rms =
        std::sqrt(2 * summary.final_cost /
                  static_cast<double>(samples.size() * static_cast<std::size_t>(nc)));
    const GlobalPhysics found{x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8] / kRadPerDeg,
                              x[9], rms,  0};
    if (opt.progress) {
      char head[64], tail[64];
      std::snprintf(head, sizeof head, "globals from spread %.1f mm: ", f * l0);
      std::snprintf(tail, sizeof tail, ", residual %.2f noise units", rms);
      opt.progress(head + (ok ? describe(found) + tail : "failed: " + summary.message));
    }
    if (ok && summary.final_cost < best_cost) {
      best_cost = summary.final_cost;
      best_x = x;
      best = found;
    }
  }
  if (!std::isfinite(best_cost)) {
    return errorf(ErrorCode::kNotConverged,
                  "identification: the design's global physics could not be fitted from any of "
                  "%d starts",
                  starts);
  }
  best.starts = starts;
  for (int j = 0; j < kGlobals; ++j) {
    const double tol = 1e-3 * std::fmax(hi[j] - lo[j], 1e-6);
    if (j != 1 && (best_x[static_cast<std::size_t>(j)] <= lo[j] + tol ||
                   best_x[static_cast<std::size_t>(j)] >= hi[j] - tol)) {
      return errorf(ErrorCode::kNotConverged,
                    "identification: %s ran to its bound (%s): the unit is too far from its "
                    "design file to start from it, or the presses do not deform the lattice as "
                    "the design says",
                    names[j], describe(best).c_str());
    }
  }
  return best;
}

}  // namespace

double RecordedNoise::residual(const ChannelNoise& design) const {
  const double xy = xy_ratio(design), z = z_ratio(design);
  return std::sqrt((2 * xy * xy + z * z) / 3);
}

RecordedNoise recorded_noise(const sim::Dataset& d) {
  // Sixth differences: binomial weights, of variance 924 sigma^2 for noise alone.
  constexpr int kSpan = 7;
  constexpr double kWeight[kSpan] = {1, -6, 15, -20, 15, -6, 1};
  constexpr double kVariance = 924;
  const int nc = d.channels();
  double sum[2] = {0, 0};  // squared differences: x and y, z
  int64_t count[2] = {0, 0};
  RecordedNoise out;
  if (d.press.size() != d.rows()) return out;
  for (std::size_t r = 0; r + kSpan <= d.rows(); ++r) {
    // Rows of one press, over which the depth moves one way (not the turn, not a hold, every
    // depth finite).
    const double step = d.depth_mm[r + 1] - d.depth_mm[r];
    bool one_way = d.press[r] >= 0;
    for (std::size_t k = r; k + 1 < r + kSpan && one_way; ++k) {
      one_way = d.press[k + 1] == d.press[r] && (d.depth_mm[k + 1] - d.depth_mm[k]) * step > 0;
    }
    if (!one_way) continue;
    for (int ch = 0; ch < nc; ++ch) {
      double dk = 0;
      for (int k = 0; k < kSpan; ++k)
        dk += kWeight[k] * d.field(r + static_cast<std::size_t>(k))[ch];
      if (!std::isfinite(dk)) continue;
      const int kind = ch % 3 == 2 ? 1 : 0;
      sum[kind] += dk * dk;
      ++count[kind];
    }
    ++out.windows;
  }
  if (count[0] == 0 || count[1] == 0) return RecordedNoise{};
  out.noise.xy_ut = std::sqrt(sum[0] / (kVariance * static_cast<double>(count[0])));
  out.noise.z_ut = std::sqrt(sum[1] / (kVariance * static_cast<double>(count[1])));
  return out;
}

FitQuality fit_quality(const sim::PatchModel& model, const sim::Dataset& data, double tip_radius_mm,
                       const ChannelNoise& noise, std::span<const double> edges,
                       std::span<const std::size_t> rows) {
  FitQuality q;
  const int nc = model.channel_count();
  if (data.channels() != nc) return q;
  const std::size_t nb = edges.size() > 1 ? edges.size() - 1 : 0;
  std::vector<double> sum(nb, 0.0);
  std::vector<int> count(nb, 0);
  std::vector<int64_t> bin_values(nb, 0);
  int64_t values = 0;
  for (std::size_t b = 0; b < nb; ++b) q.bins.push_back({edges[b], edges[b + 1], 0, 0});
  std::vector<double> f(static_cast<std::size_t>(nc));
  double total = 0;
  const std::size_t n = rows.empty() ? data.rows() : rows.size();
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t r = rows.empty() ? i : rows[i];
    if (r >= data.rows() || !(data.depth_mm[r] > 0) || !std::isfinite(data.depth_mm[r]) ||
        !std::isfinite(data.u_mm[r]) || !std::isfinite(data.v_mm[r])) {
      continue;
    }
    // Channels without a finite value are left out (a dead channel in a recording).
    const double* y = data.field(r);
    int known = 0;
    for (int c = 0; c < nc; ++c) known += std::isfinite(y[c]) ? 1 : 0;
    if (known == 0) continue;
    const sim::Contact c{data.u_mm[r], data.v_mm[r], data.depth_mm[r], tip_radius_mm};
    model.contact_field_ut(std::span<const sim::Contact>(&c, 1), f);
    double s = 0;
    for (int k = 0; k < nc; ++k) {
      if (!std::isfinite(y[k])) continue;
      const double e = (y[k] - f[static_cast<std::size_t>(k)]) / noise.sigma(k);
      s += e * e;
    }
    total += s;
    values += known;
    ++q.rows;
    for (std::size_t b = 0; b < nb; ++b) {
      if (c.depth_mm >= edges[b] && c.depth_mm < edges[b + 1]) {
        sum[b] += s;
        bin_values[b] += known;
        ++count[b];
      }
    }
  }
  q.rms = values > 0 ? std::sqrt(total / static_cast<double>(values)) : 0.0;
  for (std::size_t b = 0; b < nb; ++b) {
    q.bins[b].rows = count[b];
    q.bins[b].rms = bin_values[b] > 0 ? std::sqrt(sum[b] / static_cast<double>(bin_values[b])) : 0;
  }
  return q;
}

namespace {

// Every turn's text (ChipTurn::text), for a refusal's message.
std::string turns_text(const std::vector<ChipTurn>& turns) {
  std::string out;
  for (const ChipTurn& t : turns) out += (out.empty() ? "" : "; ") + t.text();
  return out;
}

// Row-major product a b of two 3x3 matrices.
sim::Mat3 mat_product(const sim::Mat3& a, const sim::Mat3& b) {
  sim::Mat3 out;
  for (int i = 0; i < 3; ++i) out.r[i] = b.apply_transposed(a.r[i]);
  return out;
}

// The turns find_chip_turns tries, in the surface frame: about the normal by 90 n degrees, then
// (upside down) over about u.
sim::Mat3 chip_turn(int quarter_turns, bool upside_down) {
  const sim::Mat3 yaw = sim::rotation_from_vector({0, 0, quarter_turns * M_PI / 2});
  if (!upside_down) return yaw;
  const sim::Mat3 over = sim::rotation_from_vector({M_PI, 0, 0});
  return mat_product(yaw, over);
}

// IdentificationOptions::find_chip_turns: per sensor (`drawn`: the nominal model's parameters,
// their mountings as the design file draws them), the nominal model's readings at the
// fitting rows against the recorded ones, whitened, under each turn C of the chip: its mounting
// M C reads T p with T = M C M^T (p: the reading as drawn). Each turn's residual at its best
// scale s >= 0 is |y|^2 - s^2 |p|^2 with s = max(0, y.Tp) / |p|^2, so the design's globals
// being off costs every turn alike.
std::vector<ChipTurn> find_chip_turns(const sim::PatchModel& nominal,
                                      const sim::UnitParameters& drawn,
                                      const std::vector<Sample>& samples, double tip_mm,
                                      const std::vector<double>& inv_sigma) {
  const std::size_t ns = drawn.sensors.size();
  const std::size_t nc = 3 * ns;
  std::vector<double> p(nc);
  std::vector<std::array<double, 9>> yp(ns);  // sum over rows of y p^T
  std::vector<double> yy(ns, 0.0), pp(ns, 0.0);
  std::vector<int> rows(ns, 0);
  for (const Sample& smp : samples) {
    const sim::Contact c{smp.u, smp.v, smp.depth, tip_mm};
    nominal.contact_field_ut(std::span<const sim::Contact>(&c, 1), p);
    for (std::size_t k = 0; k < ns; ++k) {
      double y[3], q[3];
      bool known = true;
      for (std::size_t a = 0; a < 3; ++a) {
        const std::size_t ch = 3 * k + a;
        y[a] = smp.field[ch] * inv_sigma[ch];
        q[a] = p[ch] * inv_sigma[ch];
        known = known && std::isfinite(y[a]) && std::isfinite(q[a]);
      }
      if (!known) continue;
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) yp[k][static_cast<std::size_t>(3 * i + j)] += y[i] * q[j];
        yy[k] += y[i] * y[i];
        pp[k] += q[i] * q[i];
      }
      ++rows[k];
    }
  }
  std::vector<ChipTurn> turns;
  for (std::size_t k = 0; k < ns; ++k) {
    if (rows[k] == 0 || !(pp[k] > 0)) continue;
    const sim::Mat3& m = drawn.sensors[k].mounting;
    auto rms = [&](const sim::Mat3& c) {
      // T = M C M^T, and y.Tp = sum_ij T_ij (y p^T)_ij.
      const sim::Mat3 mc = mat_product(m, c);
      double ip = 0;
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j)
          ip += sim::dot(mc.r[i], m.r[j]) * yp[k][static_cast<std::size_t>(3 * i + j)];
      }
      const double s = std::fmax(0.0, ip) / pp[k];
      return std::sqrt(std::fmax(0.0, yy[k] - s * s * pp[k]) / (3.0 * rows[k]));
    };
    const double as_drawn = rms(sim::Mat3{});
    ChipTurn best{static_cast<int>(k), 0, false, as_drawn, as_drawn};
    for (int q = 0; q < 4; ++q) {
      for (bool over : {false, true}) {
        if (q == 0 && !over) continue;
        const double r = rms(chip_turn(q, over));
        if (r < best.rms) best = {static_cast<int>(k), 90.0 * q, over, r, as_drawn};
      }
    }
    if ((best.yaw_deg != 0 || best.upside_down) && as_drawn > 2 && best.rms < 0.25 * as_drawn) {
      turns.push_back(best);
    }
  }
  return turns;
}

}  // namespace

std::string ChipTurn::text() const {
  char buf[200];
  std::snprintf(buf, sizeof buf,
                "sensor %d reads as its chip turned %g degrees about the normal%s from the design "
                "file (residual %.1f noise units so, %.1f as drawn): fitted so turned",
                sensor, yaw_deg, upside_down ? " and upside down" : "", rms, rms_as_drawn);
  return buf;
}

namespace {

// identify_unit() without the creep: the static model class alone.
Result<IdentifiedUnit> identify_in_class(const sim::PatchDesign& design_in,
                                         const sim::Dataset& presses,
                                         const IdentificationOptions& opt,
                                         const sim::Dataset* held_out,
                                         sim::UnitParameters* refused) {
  const auto t0 = std::chrono::steady_clock::now();
  const sim::PatchDesign design = sim::class_design(design_in);
  if (Status s = sim::validate(design); !s.ok()) return s.error();
  const int nc = design.channel_count();
  if (presses.channels() != nc || (held_out != nullptr && held_out->channels() != nc)) {
    return make_error(ErrorCode::kInvalidArgument,
                      "identification: the dataset's channel count differs from the design's (" +
                          std::to_string(nc) + ")");
  }
  if (opt.depths_per_press < 1 || opt.max_iterations < 1 || opt.outer_iterations < 1 ||
      !(opt.derivative_reach > 0) || !(opt.tip_radius_mm >= 0)) {
    return make_error(ErrorCode::kInvalidArgument,
                      "identification: depths_per_press, max_iterations, outer_iterations >= 1 "
                      "and derivative_reach > 0 required");
  }
  const ChannelNoise noise =
      opt.noise.xy_ut > 0 && opt.noise.z_ut > 0 ? opt.noise : ChannelNoise::of(design);
  Result<sim::PatchModel> nominal_r = sim::PatchModel::nominal(design);
  if (!nominal_r.ok()) return nominal_r.error();
  const sim::PatchModel& nominal = nominal_r.value();

  // Rows to fit: per press, the samples nearest to evenly spaced fractions of its deepest one,
  // and for stage 1 the one nearest half the first fraction (the onset, where the depth the
  // presses read at the surface shows best against what the lattice's physics do deeper down).
  // A ramp passes each fraction twice, pressing and releasing; a lattice that creeps or has
  // hysteresis bends differently on the two ways, and rows all from one way would let the fit
  // absorb that way's lag as the unit's static physics. So the fractions below the deepest are
  // taken in turn from the samples before the deepest (its rows in dataset order) and after it,
  // the turn alternating from press to press: each depth is fitted on both ways equally. A press
  // whose rows have no sample on one side (a staircase of static presses) gives every fraction
  // from all of them.
  std::map<int64_t, std::vector<std::size_t>> by_press;
  int64_t lone = -1;
  int64_t masked_values = 0;
  for (std::size_t r = 0; r < presses.rows(); ++r) {
    if (!(presses.depth_mm[r] >= opt.min_depth_mm) || !std::isfinite(presses.depth_mm[r]) ||
        !std::isfinite(presses.u_mm[r]) || !std::isfinite(presses.v_mm[r])) {
      continue;
    }
    // Channels without a finite value are left out of the fit (their residuals weigh 0); a row
    // needs most of its channels.
    const double* y = presses.field(r);
    int known = 0;
    for (int c = 0; c < nc; ++c) known += std::isfinite(y[c]) ? 1 : 0;
    if (2 * known < nc) continue;
    masked_values += nc - known;
    const int64_t id = presses.press.empty() || presses.press[r] < 0 ? lone-- : presses.press[r];
    by_press[id].push_back(r);
  }
  std::vector<std::size_t> rows, onset_rows;
  std::vector<std::pair<double, double>> press_uv;
  for (const auto& [id, rs] : by_press) {
    std::size_t peak = 0;  // the deepest row's place in rs (the first of equals)
    for (std::size_t i = 1; i < rs.size(); ++i) {
      if (presses.depth_mm[rs[i]] > presses.depth_mm[rs[peak]]) peak = i;
    }
    const double deepest = presses.depth_mm[rs[peak]];
    const bool both_ways = peak > 0 && peak + 1 < rs.size();
    std::vector<std::size_t> picked;
    std::size_t onset = 0;
    // k = 0: half the first fraction, the press's onset, for stage 1 alone (onset_rows).
    for (int k = 0; k <= opt.depths_per_press; ++k) {
      const double target = deepest * std::fmax(k, 0.5) / opt.depths_per_press;
      std::size_t from = 0, to = rs.size();  // the rows [from, to) of rs to pick from
      if (both_ways && k < opt.depths_per_press) {
        const bool releasing = (k + press_uv.size()) % 2 == 0;
        from = releasing ? peak + 1 : 0;
        to = releasing ? rs.size() : peak;
      }
      std::size_t best = rs[from];
      for (std::size_t i = from; i < to; ++i) {
        const std::size_t r = rs[i];
        if (std::fabs(presses.depth_mm[r] - target) < std::fabs(presses.depth_mm[best] - target))
          best = r;
      }
      if (k == 0) {
        onset = best;
      } else if (std::find(picked.begin(), picked.end(), best) == picked.end()) {
        picked.push_back(best);
      }
    }
    // The onset row, unless a fraction's too (a press too shallow to tell them apart).
    if (std::find(picked.begin(), picked.end(), onset) == picked.end()) onset_rows.push_back(onset);
    rows.insert(rows.end(), picked.begin(), picked.end());
    press_uv.emplace_back(presses.u_mm[rs.front()], presses.v_mm[rs.front()]);
  }
  const int n_presses = static_cast<int>(press_uv.size());
  if (n_presses < opt.min_presses) {
    return make_error(ErrorCode::kDegenerate, "identification: " + std::to_string(n_presses) +
                                                  " usable presses (deeper "
                                                  "than " +
                                                  std::to_string(opt.min_depth_mm) +
                                                  " mm), need at least " +
                                                  std::to_string(opt.min_presses));
  }
  // Magnets too few presses reach are held at the design (with the globals found).
  std::vector<int> uncovered;
  std::string uncovered_text;
  for (std::size_t m = 0; m < nominal.magnets().size(); ++m) {
    const auto& mg = nominal.magnets()[m];
    int near = 0;
    for (const auto& [u, v] : press_uv) {
      if (std::hypot(u - mg.u, v - mg.v) <= opt.coverage_radius_mm) ++near;
    }
    if (near >= opt.min_presses_per_magnet) continue;
    uncovered.push_back(static_cast<int>(m));
    if (uncovered.size() <= 4) {
      char buf[96];
      std::snprintf(buf, sizeof buf, "%smagnet %zu at (%.1f, %.1f) mm has %d",
                    uncovered_text.empty() ? "" : "; ", m, mg.u, mg.v, near);
      uncovered_text += buf;
    }
  }
  if (static_cast<double>(uncovered.size()) >
      opt.max_uncovered_share * static_cast<double>(nominal.magnets().size())) {
    return errorf(
        ErrorCode::kDegenerate,
        "identification: the presses do not cover the patch: %zu of %zu magnets have "
        "fewer than %d presses within %g mm (%s%s): more than the %g %% that may be held at "
        "the design",
        uncovered.size(), nominal.magnets().size(), opt.min_presses_per_magnet,
        opt.coverage_radius_mm, uncovered_text.c_str(), uncovered.size() > 4 ? "; ..." : "",
        100 * opt.max_uncovered_share);
  }

  // The fitting samples (their near magnets are found in stage 2), stage 1's with the onsets
  // too, and the channels' weights.
  auto samples_of = [&](std::span<const std::size_t> rs, std::vector<Sample>* out) {
    for (std::size_t r : rs) {
      out->push_back(
          {presses.u_mm[r], presses.v_mm[r], presses.depth_mm[r], presses.field(r), {}, {}});
    }
  };
  std::vector<Sample> samples;
  samples_of(rows, &samples);
  std::vector<Sample> with_onsets = samples;
  samples_of(onset_rows, &with_onsets);
  std::vector<double> inv_sigma;
  for (int c = 0; c < nc; ++c) inv_sigma.push_back(1 / noise.sigma(c));

  // A chip mounted turned from the design file (find_chip_turns) is fitted so turned.
  sim::UnitParameters start = nominal.parameters();
  std::vector<ChipTurn> chip_turns;
  if (opt.find_chip_turns) {
    chip_turns = find_chip_turns(nominal, start, samples, opt.tip_radius_mm, inv_sigma);
    for (const ChipTurn& t : chip_turns) {
      sim::SensorParameters& sp = start.sensors[static_cast<std::size_t>(t.sensor)];
      sp.mounting =
          mat_product(sp.mounting, chip_turn(static_cast<int>(t.yaw_deg / 90), t.upside_down));
      if (opt.progress) opt.progress(t.text());
    }
  }

  // Stage 1: the design's global physics, from several spread lengths; the best start wins.
  start.anisotropy = design_in.anisotropy;  // the design's, the fit's start
  GlobalPhysics globals;
  globals.spread_mm = start.spread_mm;
  globals.lateral_mm = start.lateral_mm;
  globals.anisotropy = start.anisotropy;
  int iterations = 0;
  if (opt.fit_globals) {
    Result<GlobalPhysics> g = fit_globals(nominal, start, with_onsets, inv_sigma, opt, &iterations);
    if (!g.ok()) return g.error();
    globals = g.value();
    start.spread_mm = globals.spread_mm;
    start.lateral_mm = globals.lateral_mm;
    start.anisotropy = globals.anisotropy;
    // Stage 2 fits the parts to how far each sample pressed into the lattice; the unit reads
    // depth as the presses did (sim::UnitParameters::depth_zero_mm).
    start.depth_zero_mm = globals.depth_zero_mm;
    for (Sample& smp : samples) smp.depth -= globals.depth_zero_mm;
    // Every part as stage 1 placed it: in the presses' frame, at the heights and moments found.
    const std::array<double, kGlobals> found = global_vector(globals);
    for (sim::MagnetParameters& mp : start.magnets) {
      sim::MagnetParameters placed;
      magnet_globals(mp, found.data(), &placed.u_mm, &placed.v_mm, &placed.h_mm,
                     &placed.moment_am2);
      mp = placed;
    }
    const double cy = std::cos(found[8]), sy = std::sin(found[8]);
    for (sim::SensorParameters& sp : start.sensors) {
      in_press_frame(found.data(), sp.u_mm, sp.v_mm, &sp.u_mm, &sp.v_mm);
      sp.h_mm += found[3];
      for (Vec3<double>& e : sp.mounting.r) {  // the chip turned with the frame
        e = Vec3<double>{cy * e.x - sy * e.y, sy * e.x + cy * e.y, e.z};
      }
    }
  }
  if (opt.progress) opt.progress("fitting every magnet and sensor");

  // Stage 2: every parameter, starting at the design with the globals found, held to the
  // fabrication spread about it.
  const double moment_scale = sim::cylinder_moment_am2(
      design.remanence_t, design.magnet_diameter_mm, design.magnet_height_mm);
  const std::size_t nm = start.magnets.size(), ns = start.sensors.size();
  std::vector<double> global = {start.spread_mm, start.lateral_mm};
  std::vector<double> mags(nm * kMagnetBlock), sens(ns * kSensorBlock);
  for (std::size_t m = 0; m < nm; ++m) {
    const sim::MagnetParameters& mp = start.magnets[m];
    double* x = &mags[m * kMagnetBlock];
    x[0] = mp.u_mm;
    x[1] = mp.v_mm;
    x[2] = mp.h_mm;
    x[3] = mp.moment_am2.x / moment_scale;
    x[4] = mp.moment_am2.y / moment_scale;
    x[5] = mp.moment_am2.z / moment_scale;
  }
  Context ctx{&nominal, moment_scale, opt.tip_radius_mm, start.anisotropy, {}, inv_sigma};
  for (std::size_t k = 0; k < ns; ++k) {
    const sim::SensorParameters& sp = start.sensors[k];
    double* x = &sens[k * kSensorBlock];
    x[0] = sp.u_mm;
    x[1] = sp.v_mm;
    x[2] = sp.h_mm;
    x[3] = x[4] = x[5] = 0;
    x[6] = sp.gain.x;
    x[7] = sp.gain.y;
    x[8] = sp.gain.z;
    ctx.mounting0.push_back(sp.mounting);
  }

  // Each sample's near magnets.
  const double reach = opt.derivative_reach * start.spread_mm * (1 + std::fabs(start.anisotropy));
  for (Sample& s : samples) {
    for (std::size_t m = 0; m < nm; ++m) {
      if (std::hypot(mags[m * kMagnetBlock] - s.u, mags[m * kMagnetBlock + 1] - s.v) < reach)
        s.near.push_back(static_cast<int>(m));
    }
    if (s.near.size() > kMaxNear) {
      return make_error(ErrorCode::kInvalidArgument,
                        "identification: derivative_reach takes " + std::to_string(s.near.size()) +
                            " magnets into one sample, at most " + std::to_string(kMaxNear) +
                            " are supported");
    }
    s.far.assign(ns, Vec3<double>{});
  }

  ceres::Problem::Options po;
  po.cost_function_ownership = ceres::TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  std::vector<double*> blocks;
  std::vector<NearPoses> sample_poses(samples.size());
  std::vector<RestFields> rest_fields(ns);
  for (RestFields& r : rest_fields) {
    r.values.resize(nm);
    r.jets.resize(nm);
  }
  for (std::size_t si = 0; si < samples.size(); ++si) {
    const Sample& s = samples[si];
    for (std::size_t k = 0; k < ns; ++k) {
      if (!std::isfinite(s.field[3 * k]) && !std::isfinite(s.field[3 * k + 1]) &&
          !std::isfinite(s.field[3 * k + 2])) {
        continue;  // nothing known of this sensor in this sample
      }
      blocks.assign({global.data(), &sens[k * kSensorBlock]});
      for (int m : s.near) blocks.push_back(&mags[static_cast<std::size_t>(m) * kMagnetBlock]);
      problem.AddResidualBlock(
          new SensorResidual(ctx, s, static_cast<int>(k), &sample_poses[si], &rest_fields[k]),
          nullptr, blocks);
    }
  }
  // Priors: the fabrication spread about nominal.
  const sim::FabricationVariation& pv = opt.prior;
  problem.AddResidualBlock(
      new PriorResidual(global, {inv(pv.spread_rel_sd, start.spread_mm),
                                 inv(pv.lateral_rel_sd, std::fmax(start.lateral_mm, 1e-3))}),
      nullptr, global.data());
  for (std::size_t m = 0; m < nm; ++m) {
    double* x = &mags[m * kMagnetBlock];
    problem.AddResidualBlock(
        new PriorResidual(std::vector<double>(x, x + kMagnetBlock),
                          {inv(pv.magnet_position_sd_mm, 1), inv(pv.magnet_position_sd_mm, 1),
                           inv(pv.magnet_height_sd_mm, 1), inv(pv.magnet_tilt_sd_rad, 1),
                           inv(pv.magnet_tilt_sd_rad, 1), inv(pv.magnet_moment_rel_sd, 1)}),
        nullptr, x);
  }
  for (std::size_t k = 0; k < ns; ++k) {
    double* x = &sens[k * kSensorBlock];
    const double sp = inv(pv.sensor_position_sd_mm, 1), sr = inv(pv.sensor_rotation_sd_rad, 1),
                 sg = inv(pv.sensor_gain_rel_sd, 1);
    problem.AddResidualBlock(new PriorResidual(std::vector<double>(x, x + kSensorBlock),
                                               {sp, sp, sp, sr, sr, sr, sg, sg, sg}),
                             nullptr, x);
  }
  for (int m : uncovered) {
    problem.SetParameterBlockConstant(&mags[static_cast<std::size_t>(m) * kMagnetBlock]);
  }
  problem.SetParameterLowerBound(global.data(), 0, 0.2 * start.spread_mm);
  problem.SetParameterLowerBound(global.data(), 1, 0.0);

  ceres::Solver::Options so = solver_options(opt, ceres::SPARSE_NORMAL_CHOLESKY);
  StageProgress shown(opt.progress, problem.NumResiduals(), opt.outer_iterations);
  if (opt.progress) so.callbacks.push_back(&shown);
  StallStop stall;
  so.callbacks.push_back(&stall);

  for (int outer = 0; outer < opt.outer_iterations; ++outer) {
    shown.pass = outer + 1;
    // Frozen field of the magnets beyond derivative reach, at the current parameters: each far
    // magnet posed once a sample, its field summed at every sensor in magnet order.
    Vec3<double> sensor_pos[sim::kMaxSensors];
    for (std::size_t k = 0; k < ns; ++k) {
      const double* sp = &sens[k * kSensorBlock];
      sensor_pos[k] = nominal.surface_point<double>(sp[0], sp[1], sp[2], nullptr, nullptr, nullptr);
    }
    for (Sample& s : samples) {
      s.far.assign(ns, Vec3<double>{});
      std::size_t ni = 0;
      for (std::size_t m = 0; m < nm; ++m) {
        if (ni < s.near.size() && static_cast<std::size_t>(s.near[ni]) == m) {
          ++ni;
          continue;
        }
        const MagnetPose<double> pose =
            magnet_pose<double>(ctx, s, &mags[m * kMagnetBlock], global[0] * (1 + ctx.anisotropy),
                                global[0] * (1 - ctx.anisotropy), global[1]);
        if (!pose.moved) continue;
        for (std::size_t k = 0; k < ns; ++k) s.far[k] = s.far[k] + magnet_term(pose, sensor_pos[k]);
      }
    }
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    iterations += static_cast<int>(summary.iterations.size()) - 1;
    if (summary.termination_type == ceres::FAILURE ||
        summary.termination_type == ceres::USER_FAILURE ||
        (summary.termination_type == ceres::NO_CONVERGENCE && outer + 1 == opt.outer_iterations)) {
      return make_error(ErrorCode::kNotConverged,
                        "identification: the solver stopped without converging after " +
                            std::to_string(iterations) + " iterations: " + summary.message);
    }
  }

  // The fitted unit.
  sim::UnitParameters fitted = start;
  fitted.spread_mm = global[0];
  fitted.lateral_mm = global[1];
  fitted.anisotropy = start.anisotropy;
  for (std::size_t m = 0; m < nm; ++m) {
    const double* x = &mags[m * kMagnetBlock];
    fitted.magnets[m] = {x[0], x[1], x[2], Vec3<double>{x[3], x[4], x[5]} * moment_scale};
  }
  for (std::size_t k = 0; k < ns; ++k) {
    const double* x = &sens[k * kSensorBlock];
    double r[9];
    ceres::AngleAxisToRotationMatrix(x + 3, ceres::RowMajorAdapter3x3(r));
    const sim::Mat3& e0 = ctx.mounting0[k];
    sim::Mat3 mount;
    for (int row = 0; row < 3; ++row) {
      mount.r[row] = e0.r[0] * r[3 * row + 0] + e0.r[1] * r[3 * row + 1] + e0.r[2] * r[3 * row + 2];
    }
    fitted.sensors[k] = {x[0], x[1], x[2], mount, Vec3<double>{x[6], x[7], x[8]}};
  }
  Result<sim::PatchModel> model = sim::PatchModel::from_parameters(design, fitted);
  if (!model.ok()) {
    return make_error(ErrorCode::kNotConverged,
                      "identification: the fit left invalid parameters: " + model.error().message);
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  IdentifiedUnit out{std::move(model).value(),
                     fitted,
                     {},
                     {},
                     {},
                     {},
                     n_presses,
                     static_cast<int>(rows.size()),
                     iterations,
                     seconds,
                     static_cast<int>(masked_values),
                     globals,
                     {},
                     {},
                     {}};
  out.chip_turns = chip_turns;
  out.uncovered_magnets = uncovered;
  out.fit = fit_quality(out.model, presses, opt.tip_radius_mm, noise, opt.depth_bin_edges_mm, rows);
  if (!(out.fit.rms <= opt.max_residual)) {
    if (refused != nullptr) *refused = out.parameters;
    std::string bins;
    for (const DepthBinResidual& b : out.fit.bins) {
      if (b.rows == 0) continue;
      char buf[96];
      std::snprintf(buf, sizeof buf, "%s%g-%g mm: %.2f", bins.empty() ? "" : ", ", b.depth_lo_mm,
                    b.depth_hi_mm, b.rms);
      bins += buf;
    }
    return errorf(ErrorCode::kNotConverged,
                  "identification: the design's model class does not explain these presses: "
                  "residual %.2f noise units (limit %.2f; by depth %s) with the globals %s%s; "
                  "check the design file's magnets, sensors and lattice",
                  out.fit.rms, opt.max_residual, bins.c_str(), describe(globals).c_str(),
                  chip_turns.empty() ? "" : (", and " + turns_text(chip_turns)).c_str());
  }
  out.nominal_fit =
      fit_quality(nominal, presses, opt.tip_radius_mm, noise, opt.depth_bin_edges_mm, rows);
  if (held_out != nullptr) {
    out.held_out =
        fit_quality(out.model, *held_out, opt.tip_radius_mm, noise, opt.depth_bin_edges_mm);
    out.nominal_held_out =
        fit_quality(nominal, *held_out, opt.tip_radius_mm, noise, opt.depth_bin_edges_mm);
  }
  return out;
}

}  // namespace

CreepFitOptions creep_fit_options(const IdentificationOptions& options) {
  CreepFitOptions co;
  co.tip_radius_mm = options.tip_radius_mm;
  co.noise = options.noise;
  co.min_depth_mm = options.min_depth_mm;
  return co;
}

Result<IdentifiedUnit> identify_unit(const sim::PatchDesign& design, const sim::Dataset& presses,
                                     const IdentificationOptions& opt, const sim::Dataset* held_out,
                                     sim::UnitParameters* refused) {
  sim::UnitParameters first_refused;
  Result<IdentifiedUnit> id = identify_in_class(design, presses, opt, held_out, &first_refused);
  const bool was_refused = !id.ok() && !first_refused.magnets.empty();
  if (was_refused && refused != nullptr) *refused = first_refused;
  if (!opt.fit_creep || (!id.ok() && (!was_refused || refused == nullptr))) return id;
  // The creep, on the fit's model, or on the refused fit's (the class's nearest model of a unit
  // with physics outside it, which may creep as well).
  if (opt.progress) opt.progress("fitting the lattice's creep to the ramps");
  const auto t0 = std::chrono::steady_clock::now();
  std::optional<sim::PatchModel> refused_model;
  if (!id.ok()) {
    Result<sim::PatchModel> m = sim::PatchModel::of_unit_file(design, first_refused);
    if (!m.ok()) return id;
    refused_model.emplace(std::move(*m));
  }
  const sim::PatchModel& static_model = id.ok() ? id->model : *refused_model;
  Result<CreepFit> creep = fit_creep(static_model, presses, creep_fit_options(opt));
  if (!creep.ok()) return creep.error();
  if (opt.progress) opt.progress(creep->summary_text());
  if (!id.ok()) {
    // A refused fit carries the law (for its field correction and the presses simulated from
    // it); the static fit is not made again: it would be refused again, for what is not creep.
    if (creep->kept) creep->law.write_to(refused);
    return id;
  }
  const double creep_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  id->creep = *creep;
  id->solve_seconds += creep_s;
  if (!creep->kept) return id;
  // The static physics again, fitted to the bends the law gives rather than the press's depths
  // (the lag no longer taken for static physics), and judged on the held-out presses likewise.
  if (opt.progress) opt.progress("fitting every part again, to the bends the creep gives");
  const sim::Dataset bent = bent_dataset(creep->law, presses);
  std::optional<sim::Dataset> bent_held;
  if (held_out != nullptr) bent_held = bent_dataset(creep->law, *held_out);
  // Its globals start from the spread the first fit found (the bends move them little).
  IdentificationOptions again_opt = opt;
  again_opt.start_from_spread(design, id->globals.spread_mm);
  sim::UnitParameters again_refused;
  Result<IdentifiedUnit> again =
      identify_in_class(design, bent, again_opt, bent_held ? &*bent_held : nullptr, &again_refused);
  if (!again.ok()) {
    if (refused != nullptr && !again_refused.magnets.empty()) {
      creep->law.write_to(&again_refused);
      *refused = again_refused;
    }
    return again.error();
  }
  creep->law.write_to(&again->parameters);
  Result<sim::PatchModel> model = sim::PatchModel::of_unit_file(design, again->parameters);
  if (!model.ok()) return model.error();
  again->model = std::move(*model);
  again->creep = *creep;
  again->iterations += id->iterations;
  again->solve_seconds += id->solve_seconds;
  return again;
}

}  // namespace skinbus::estimators
