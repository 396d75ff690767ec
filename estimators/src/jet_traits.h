// jet_traits.h (internal): lets sim's forward-model templates run on Ceres' jets.
//
// sim's templates (skinbus/sim/dual.h) read a scalar's value part through ScalarTraits; this
// teaches them ceres::Jet, so the estimators differentiate the simulator's own code.
#pragma once

#include <ceres/jet.h>

#include "skinbus/sim/dual.h"

namespace skinbus::sim {
template <typename S, int N>
struct ScalarTraits<ceres::Jet<S, N>> {
  static double value(const ceres::Jet<S, N>& x) { return x.a; }
  static bool zero(const ceres::Jet<S, N>& x) { return x.a == 0 && x.v.isZero(0); }
};
}  // namespace skinbus::sim
