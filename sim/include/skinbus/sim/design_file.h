// skinbus/sim/design_file.h: a patch design (PatchDesign) as a YAML file, so that the tools model
// a user's patch instead of the built-in one (docs/design_file.md gives the format).
//
//   format: skinbus-patch-design
//   version: 1
//   surface:   {kind: flat, size_u_mm: 140, size_v_mm: 140, thickness_mm: 15}
//   magnets:   {grid: {u: 7, v: 7, pitch_mm: 20}, polarity: checkerboard, diameter_mm: 3, ...}
//   sensors:   {grid: {u: 4, v: 4, pitch_mm: 30}, depth_mm: 17, chip: {gain_sel: 7, ...}}
//   lattice:   {spread_mm: 10, lateral_mm: 2, anisotropy: 0}
//   force_law: {stiffness_n_per_mm: 2, stiffening_n_per_mm3: 0.05}
//   indenter:  {tip_radius_mm: 5}   (the lab probe's tip, and the tip the host refines with)
//
// Every setting is optional and defaults to the built-in design's (PatchDesign{}); the built-in
// design ships as sim/designs/nominal.yaml. Unknown settings, settings given twice, values that
// are not numbers or are out of range, and designs that validate() refuses are errors naming the
// file, the setting and its line. Reading costs one parse of a small file; nothing is cached.
#pragma once

#include <string>

#include "skinbus/common/result.h"
#include "skinbus/sim/patch_model.h"

namespace skinbus::sim {

// The design in YAML `text`; `source` (a file name) starts every error message.
Result<PatchDesign> parse_design(const std::string& text, const std::string& source);

// The design in the file at `path` (kNotFound / kIo when it cannot be read).
Result<PatchDesign> read_design_file(const std::string& path);

// read_design_file(path), or the built-in design (PatchDesign{}) when `path` is empty: what a
// tool's optional --design gives.
Result<PatchDesign> read_design_or_builtin(const std::string& path);

// The design as a complete design file (every setting written); parse_design() of it gives back
// `design` exactly (doubles written with 17 significant digits where needed).
std::string design_to_yaml(const PatchDesign& design);

// design_to_yaml() written to `path` atomically (the file is whole or absent).
Status write_design_file(const PatchDesign& design, const std::string& path);

}  // namespace skinbus::sim
