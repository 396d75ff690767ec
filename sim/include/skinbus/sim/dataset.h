// skinbus/sim/dataset.h: indentation datasets: press plans, generation from a simulated
// patch, and the one CSV format that simulator, lab recordings and the training tool share.
//
// The format (docs/dataset_format.md): `#` header lines `key: value` (format version, source,
// unit, sensor layout, units), then one CSV header line naming every column, then one row per
// sample. Standard columns: press, t_s, u_mm, v_mm, depth_mm, force_n, then per sensor i
// s<i>_bx_ut, s<i>_by_ut, s<i>_bz_ut (tared field, the sensor's own frame, uT). Any other
// column (a lab's robot pose, say) is kept by name. Any number of sensors.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/sim/pressed_area.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::sim {

struct DatasetSensor {
  double u_mm = 0, v_mm = 0, h_mm = 0;
};

struct Dataset {
  std::map<std::string, std::string> meta;  // header block (format, source, unit, plan, ...)
  std::vector<DatasetSensor> sensors;
  bool sensor_layout_known = false;        // the header gave the sensors' positions (`sensor <i>:`)
  std::vector<std::string> extra_columns;  // columns beyond the standard ones, in order
  // One entry per row (struct of arrays).
  std::vector<int64_t> press;  // press number (-1: not from a press)
  std::vector<double> t_s, u_mm, v_mm, depth_mm, force_n;
  std::vector<double> field_ut;  // rows x channels, row-major
  std::vector<double> extra;     // rows x extra_columns, row-major

  std::size_t rows() const { return u_mm.size(); }
  int channels() const { return 3 * static_cast<int>(sensors.size()); }
  const double* field(std::size_t row) const { return field_ut.data() + row * channels(); }
  void append(int64_t press_id, double t, double u, double v, double depth, double force,
              const double* field);
};

// The area a tool's --area names: "U0,U1,V0,V1" (mm, U0 < U1, V0 < V1), "surface" (`design`'s
// whole surface, centred, widened to hold `unit_area` if that reaches beyond) or "pressed"
// (`unit_area`: where a unit was pressed, its file's pressed_area_mm). Errors:
// kInvalidArgument naming the text, or "pressed" without a unit area.
Result<PressedArea> parse_press_area(std::string_view text, const PatchDesign& design,
                                     const std::optional<PressedArea>& unit_area = std::nullopt);

// The area of `d`'s rows whose u and v are finite; none when no row has both.
std::optional<PressedArea> pressed_area(const Dataset& d);

// The name of field channel `channel` in the CSV format: "s03_bx_ut" for channel 9.
std::string field_column_name(int channel);

// The channels of `d` stuck at one value: the same finite value in every row that has one, over
// at least kMinStuckRows such rows. A live Hall channel shows its noise from sample to sample;
// a chip that stopped converting repeats one reading (tared: 0). Ascending.
inline constexpr std::size_t kMinStuckRows = 16;
std::vector<int> stuck_channels(const Dataset& d);

// Sets the stuck channels of `d` to NaN in every row: the format's dead channel, which
// identification leaves out of its fit and evaluation fits without (docs/dataset_format.md).
// Returns a note naming them for the user ("" when none).
std::string leave_out_stuck_channels(Dataset* d);

// Removes the rows of `d` deeper than `max_depth_mm` (every column; the rows' order kept): the
// presses a model cannot explain when its lattice compresses no deeper (PatchModel::max_depth_mm
// plus its depth zero). Returns a note counting them for the user ("" when none). No row with a
// depth that is not finite is removed.
std::string leave_out_rows_deeper_than(Dataset* d, double max_depth_mm);

// leave_out_rows_deeper_than() at the deepest press `design`'s lattice takes in the model
// (PatchDesign::deepest_press_mm, plus a unit's `depth_zero_mm`), the note saying why ("" when
// no row is deeper): the one rule skinbus-identify and skinbus-evaluate apply to a recording.
std::string leave_out_presses_past_the_lattice(Dataset* d, const PatchDesign& design,
                                               double depth_zero_mm = 0);

// An indentation robot's frame against the patch's: its origin and axes in the surface, and the
// depth it reads where its tip meets the surface.
struct PressFrame {
  double du_mm = 0, dv_mm = 0, yaw_deg = 0;
  double depth_zero_mm = 0;  // positive: the robot reads deep
};

// Writes the presses of `d` as a robot in frame `f` records them: each row's (u_mm, v_mm) turned
// by yaw_deg about the patch's origin (u toward v), then moved by (du_mm, dv_mm), and its
// depth_mm read depth_zero_mm deeper. The fields are untouched: where and how deep the unit was
// pressed does not change (identification finds such a frame, estimators::GlobalPhysics).
void record_in_press_frame(Dataset* d, const PressFrame& f);

// Where a robot presses. Positions in the patch frame, mm.
struct PressPoint {
  double u_mm = 0, v_mm = 0;
};
// An n_u x n_v grid at `pitch_mm`, centred, u fastest.
std::vector<PressPoint> plan_grid(int n_u, int n_v, double pitch_mm);
// The seed's protocol: an n x n grid at `pitch_mm`, centred (19 x 19 at 7.5 mm).
inline std::vector<PressPoint> plan_grid(int n, double pitch_mm) {
  return plan_grid(n, n, pitch_mm);
}
// The same grids, each point moved by up to +-jitter * pitch/2 (uniform), seeded.
std::vector<PressPoint> plan_jittered_grid(int n_u, int n_v, double pitch_mm, double jitter,
                                           uint64_t seed);
inline std::vector<PressPoint> plan_jittered_grid(int n, double pitch_mm, double jitter,
                                                  uint64_t seed) {
  return plan_jittered_grid(n, n, pitch_mm, jitter, seed);
}
// `count` points of the 2D Halton sequence (bases 2, 3) over `area`.
std::vector<PressPoint> plan_halton(int count, const PressedArea& area, uint64_t skip = 0);
// `count` uniformly random points over `area`.
std::vector<PressPoint> plan_random(int count, const PressedArea& area, uint64_t seed);
// The same over the square +-half_extent_mm.
inline std::vector<PressPoint> plan_halton(int count, double half_extent_mm, uint64_t skip = 0) {
  return plan_halton(count, PressedArea::square(half_extent_mm), skip);
}
inline std::vector<PressPoint> plan_random(int count, double half_extent_mm, uint64_t seed) {
  return plan_random(count, PressedArea::square(half_extent_mm), seed);
}
// A given list: a text file with one point per line, "u_mm,v_mm" (or separated by spaces);
// '#' lines and a header line naming the columns are skipped. Errors name the line.
Result<std::vector<PressPoint>> plan_from_file(const std::string& path);

// A press-and-release depth ramp, as an indentation robot runs it: down at speed_mm_per_s to
// max_depth_mm, held there hold_s, up at the same speed.
struct RampProtocol {
  double max_depth_mm = 4.0;
  double speed_mm_per_s = 2.0;  // down and up
  double hold_s = 0;            // at the deepest (a lattice that relaxes shows it there)
  double rate_hz = 41.7;        // sampling
  double tip_radius_mm = 5.0;   // the indenter\'s round tip (assumption: a 10 mm probe)
  double min_depth_mm = 1e-9;   // only samples deeper than this are kept ("contact samples")
  int tare_samples = 32;        // baseline averaged before the presses
};

// Runs `plan` on `patch`: a ramp at every point, keeping contact samples, tared. Fills meta,
// sensors and rows. Deterministic for the patch's noise seed. A design with creep
// (PatchDesign::creep_fraction) bends the plate by its lagged depth; the rows record the
// indenter's depth.
Dataset generate_ramp_dataset(SimulatedPatch& patch, const std::vector<PressPoint>& plan,
                              const RampProtocol& protocol, const Environment& env = {});

// The super-resolution test split: `count` static presses at random positions over `area`
// and random depths in (0, max_depth_mm], one sample each.
Dataset generate_random_test_set(SimulatedPatch& patch, int count, const PressedArea& area,
                                 double max_depth_mm, uint64_t seed, const Environment& env = {},
                                 int tare_samples = 32, double tip_radius_mm = 5.0);
// The same over the square +-half_extent_mm.
inline Dataset generate_random_test_set(SimulatedPatch& patch, int count, double half_extent_mm,
                                        double max_depth_mm, uint64_t seed,
                                        const Environment& env = {}, int tare_samples = 32,
                                        double tip_radius_mm = 5.0) {
  return generate_random_test_set(patch, count, PressedArea::square(half_extent_mm), max_depth_mm,
                                  seed, env, tare_samples, tip_radius_mm);
}

// Static presses at given points: `per_point` presses at each point of `points`, random depths
// in (0, max_depth_mm], one sample each (e.g. the test split at the training grid's points).
Dataset generate_static_test_set(SimulatedPatch& patch, const std::vector<PressPoint>& points,
                                 int per_point, double max_depth_mm, uint64_t seed,
                                 const Environment& env = {}, int tare_samples = 32,
                                 double tip_radius_mm = 5.0);

// Bounds of what read_dataset_csv takes: a line (256 sensors of 3 numbers and a lab's extra
// columns fit many times over), the columns, and the values of the whole file (rows x columns:
// 2^27, 1 GiB of doubles).
inline constexpr std::size_t kMaxDatasetLineBytes = 1 << 20;
inline constexpr std::size_t kMaxDatasetColumns = 4096;
inline constexpr std::size_t kMaxDatasetCells = std::size_t{1} << 27;

// Writes / reads the CSV format. Errors name the file and line. The writer replaces `path` at
// once (a temporary file, synced and renamed): a reader never sees half a dataset. The reader
// refuses a directory, a line or a file beyond the bounds above, and a column named twice (also
// u_mm with x_mm, v_mm with y_mm); a UTF-8 byte-order mark before the header is skipped.
Status write_dataset_csv(const Dataset& d, const std::string& path);
Result<Dataset> read_dataset_csv(const std::string& path);

// A fingerprint of the rows (FNV-1a over the numbers), for model metadata.
uint64_t dataset_fingerprint(const Dataset& d);

// Checks that a recording's sensors sit where `model`'s do, in the same order: each sensor's
// position (u, v) in the recording's header within `tolerance_mm` of the model's sensor of the
// same index. kInvalidArgument naming the first that is not (a recording whose sensors are
// listed in another order than the design file's, or of another patch); Ok when the recording
// gives no positions. The depths are not compared (identification fits the sensors' height).
// First, the surface its `geometry:` header names, when it has one: a cylinder against a flat
// design or the reverse, or a cylinder whose radius is more than 2 % off the design's, is named
// (surface coordinates read the same on both; the fields do not).
// Cost: one pass over the sensors.
Status check_sensor_layout(const Dataset& d, const PatchModel& model, double tolerance_mm = 3.0);

// The text of field `key` (`key=value`, fields apart by white space, the key starting the line or
// following white space) in header `meta_key` of `d`; nullopt when the header or the field is
// absent. The view is into d.meta. Cost: one scan of the header line.
std::optional<std::string_view> header_field(const Dataset& d, std::string_view meta_key,
                                             std::string_view key);

// The indenter tip a recording says its presses were made with: the `tip_radius_mm=` field of its
// `protocol:` header (every generator above writes it; a lab's recording may). nullopt when the
// header does not say; kParse naming the header when the value is not a number in
// [0, kMaxIndenterTipRadiusMm] mm. Cost: one scan of the header line.
Result<std::optional<double>> recorded_tip_radius_mm(const Dataset& d);

// The tip the presses of `d` were made with: the recording's (above) when it says, else the
// design's indenter (PatchDesign::indenter_tip_radius_mm). `from`, when not null, receives where
// it came from ("the recording's protocol header" or "the design's indenter") for a tool's log.
Result<double> presses_tip_radius_mm(const Dataset& d, const PatchDesign& design,
                                     std::string* from = nullptr);

}  // namespace skinbus::sim
