// body_map throughput on one core: forward kinematics of every link of the Unitree G1 and of the
// project's skinbot, the pose of one deep link alone, and one patch pose calibration (flat
// patch, N touches with 0.5 mm noise and 10% outliers). Accuracy is measured by
// `skinbus-bench calibration` on the same kind of data (docs/benchmarks/body_map.md).
//
//   SKINBUS_SOURCE_DIR=. build/body_map/body_map_benchmark --benchmark_min_time=0.2
//
// Robot files are found from SKINBUS_SOURCE_DIR (the repository root; default: the current
// directory): the G1 at $SKINBUS_SOURCE_DIR/../shared/robots/unitree_g1/g1_29dof.urdf, skinbot at
// $SKINBUS_SOURCE_DIR/body_map/robots/skinbot.urdf. A missing file skips its benchmarks.
#include <benchmark/benchmark.h>

#include <cstdlib>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "skinbus/body_map/calibration.h"
#include "skinbus/body_map/robot_model.h"

namespace skinbus::body_map {
namespace {

// ---- Robots and joint positions shared by the benchmarks ----

std::string source_dir() {
  const char* env = std::getenv("SKINBUS_SOURCE_DIR");
  return env ? env : ".";
}

std::string g1_path() {
  return source_dir() + "/../shared/robots/unitree_g1/g1_29dof.urdf";
}
std::string skinbot_path() {
  return source_dir() + "/body_map/robots/skinbot.urdf";
}

// Loads `path` once per process. Returns nullptr (and the reason in `error`) if it cannot.
const RobotModel* load_once(const std::string& path, std::optional<Result<RobotModel>>& cache,
                            std::string& error) {
  if (!cache) cache.emplace(RobotModel::from_urdf_file(path));
  if (!cache->ok()) {
    error = cache->error().to_string();
    return nullptr;
  }
  return &cache->value();
}

const RobotModel* g1(std::string& error) {
  static std::optional<Result<RobotModel>> cache;
  return load_once(g1_path(), cache, error);
}

const RobotModel* skinbot(std::string& error) {
  static std::optional<Result<RobotModel>> cache;
  return load_once(skinbot_path(), cache, error);
}

// `count` joint vectors drawn within the model's limits (+-pi for unbounded joints), seed fixed.
std::vector<std::vector<double>> random_joint_sets(const RobotModel& model, int count) {
  std::mt19937 rng(7);
  std::vector<std::vector<double>> sets(count, std::vector<double>(model.joint_count()));
  for (std::vector<double>& q : sets) {
    for (int j = 0; j < model.joint_count(); ++j) {
      const JointLimits& l = model.joint_limits(j);
      q[j] = std::uniform_real_distribution<double>(l.bounded ? l.lower : -3.14159,
                                                    l.bounded ? l.upper : 3.14159)(rng);
    }
  }
  return sets;
}

// ---- Forward kinematics ----

// Poses of every link for one joint vector; items are links.
void run_all_links(benchmark::State& state, const RobotModel& model) {
  const auto qs = random_joint_sets(model, 64);
  std::vector<Pose> poses(model.link_count());
  std::size_t i = 0;
  for (auto _ : state) {
    const Status s = model.forward_kinematics(qs[i++ & 63], poses);
    benchmark::DoNotOptimize(s);
    benchmark::DoNotOptimize(poses.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * model.link_count());
  state.SetLabel(model.name() + ", " + std::to_string(model.link_count()) + " links, " +
                 std::to_string(model.joint_count()) + " joints");
}

void BM_ForwardKinematicsG1(benchmark::State& state) {
  std::string error;
  const RobotModel* model = g1(error);
  if (!model) {
    state.SkipWithError(error.c_str());
    return;
  }
  run_all_links(state, *model);
}
BENCHMARK(BM_ForwardKinematicsG1);

void BM_ForwardKinematicsSkinbot(benchmark::State& state) {
  std::string error;
  const RobotModel* model = skinbot(error);
  if (!model) {
    state.SkipWithError(error.c_str());
    return;
  }
  run_all_links(state, *model);
}
BENCHMARK(BM_ForwardKinematicsSkinbot);

// The pose of the G1's left hand alone (waist and arm: 10 movable joints, 11 links deep); items are
// poses.
void BM_LinkPoseG1Hand(benchmark::State& state) {
  std::string error;
  const RobotModel* model = g1(error);
  if (!model) {
    state.SkipWithError(error.c_str());
    return;
  }
  const int link = model->find_link("left_rubber_hand");
  if (link < 0) {
    state.SkipWithError("the G1 has no link 'left_rubber_hand'");
    return;
  }
  const auto qs = random_joint_sets(*model, 64);
  std::size_t i = 0;
  for (auto _ : state) {
    Result<Pose> pose = model->link_pose(qs[i++ & 63], link);
    benchmark::DoNotOptimize(pose);
  }
  state.SetItemsProcessed(state.iterations());
  int depth = 0;
  for (int k = link; k > 0; k = model->link(k).parent) ++depth;
  state.SetLabel("left_rubber_hand, " + std::to_string(depth) + " joints from the root");
}
BENCHMARK(BM_LinkPoseG1Hand);

// ---- Calibration ----

static void BM_CalibratePatch(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  PatchPlacement truth;
  truth.node_id = 1;
  truth.link = "torso_link";
  truth.pose_on_link = {rotation_from_rpy(0.3, -0.2, 1.1), Eigen::Vector3d(110, -40, 250)};
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> pos(-60, 60), depth(1, 3);
  std::normal_distribution<double> noise(0, 0.5);
  std::vector<CalibrationTouch> touches;
  for (int i = 0; i < n; ++i) {
    const double u = pos(rng), v = pos(rng), d = depth(rng);
    CalibrationTouch t;
    t.probe_mm = link_surface_point(truth, u, v, d).point_mm +
                 Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    t.u_mm = i % 10 == 0 ? pos(rng) : u + noise(rng);  // every tenth an outlier
    t.v_mm = v + noise(rng);
    t.depth_mm = d;
    touches.push_back(t);
  }
  PatchPlacement start = truth;
  start.pose_on_link.translation_mm += Eigen::Vector3d(15, -10, 5);
  start.pose_on_link.rotation = rotation_from_rpy(0.2, 0.1, 0.3) * start.pose_on_link.rotation;
  for (auto _ : state) {
    Result<PatchCalibration> c = calibrate_patch(start, touches);
    if (!c.ok()) state.SkipWithError(c.error().message.c_str());
    benchmark::DoNotOptimize(c);
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_CalibratePatch)->Arg(10)->Arg(30)->Arg(60)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace skinbus::body_map

BENCHMARK_MAIN();
