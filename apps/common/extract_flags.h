// The flags `tandem extract` and `tandem-client stream` share: registered by one function,
// so that both programs have the same names, defaults and help for the same meaning (the
// input, following a growing acquisition, the session's options, the outputs). Each
// program adds its own flags after these (the client: the server, pacing, previews).
#ifndef TANDEM_APPS_COMMON_EXTRACT_FLAGS_H_
#define TANDEM_APPS_COMMON_EXTRACT_FLAGS_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "apps/common/cli_util.h"
#include "apps/common/flags.h"
#include "tandem/io/follow.h"
#include "tandem/io/open_volume.h"
#include "tandem/labels.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"

namespace tandem::cli {

struct ExtractFlags {
  std::string input, zarr_array, series, out, iso, schedule = "tandem-lag", metrics, done_file,
      spacing, frame;
  double error = 0, alpha = 0, distance_guard = SessionOptions{}.distance_guard;
  double sag_correction = SessionOptions{}.sag_correction, seal_margin = SessionOptions{}.seal_margin;
  double lockstep_error = SessionOptions{}.lockstep_error;
  double settle = 10;
  int64_t target_triangles = 0, expect_slices = 0, parts = 0;
  int64_t quantization_bits = 0, compression_level = 0;  // Draco: Add() sets the codec's defaults
  bool follow = false, seal = false, no_simplify = false, reference = false, strict = false;
  bool quiet = false, glb_draco = false;
  // Label volumes (segmentations): --labels and the flags that go with it.
  bool labels = false, close = false;
  std::string background = "0", label_ids, label_names, format = "ply";

  // Registers the shared flags; `out_help` says which mesh formats --out takes.
  void Add(FlagSet* flags, const std::string& out_help);
  // --input with --zarr-array SEL appended as the "#SEL" selector OpenVolume understands.
  std::string InputPath() const;
  // How to open --input (--series) and follow it (--follow's flags); notes go to `note`.
  io::OpenOptions Open(std::function<void(const std::string&)> note) const;
  io::FollowOptions Follow(std::function<void(const std::string&)> note) const;
  // --spacing, then --frame: `source` delivers that spacing, in that frame. Returns "" or a
  // warning naming the spacing the file carries and --spacing replaces. A refusal (a
  // spacing or frame the volume cannot take) names the flag.
  absl::StatusOr<std::string> ApplyGeometry(std::unique_ptr<SliceSource>* source) const;
  // After parsing: the checks that need no volume (follow-only flags, the iso list, the
  // output names, the schedule).
  absl::Status Check(const FlagSet& flags) const;
  // With the volume's header: the iso-values (--iso, else the file's first suggested one)
  // and the session options (E0 defaults to 0.2 x the smallest spacing).
  absl::StatusOr<std::vector<IsoValue>> Isos(const FlagSet& flags, const VolumeInfo& info) const;
  // --labels' folder output: --out ends in '/' or names an existing folder (else the one
  // GLB --out X.glb names).
  bool LabelsToFolder() const;
  // --labels, --background, --label-ids and --close (held to their rules by Check).
  absl::StatusOr<LabelOptions> Labels() const;
  // --labels with the volume's header: its voxels must be integers (the refusal names the
  // input and its type).
  absl::Status CheckLabelInput(const VolumeInfo& info) const;
  // SessionOptions::ValidateFor(info) applied; a refusal names the flag ("--alpha 2:
  // isotropy alpha must lie in [0, 1]").
  absl::StatusOr<SessionOptions> Options(const FlagSet& flags, const VolumeInfo& info) const;
};

// Empty, or why valid options will keep most of the surface: with --alpha A the isotropy term
// of a triangle a spacing wide alone costs more than E0 once E0 < A × spacing / 5, so little
// is contracted (the paper's normalisation makes that term grow as E0 × a length).
std::string OptionsWarning(const SessionOptions& o, const VolumeInfo& info);

#ifdef TANDEM_HAVE_DRACO
// --quantization-bits and --compression-level held to the codec's ranges
// (ValidateDracoOptions), the refusal naming the flag ("--quantization-bits must be in ...").
absl::Status CheckDracoFlags(int64_t bits, int64_t level);
#endif

// A refusal of SessionOptions::Validate() / ValidateFor() worded with the flag's name
// ("--parts 99: ..."); any other status unchanged.
absl::Status NameOptionFlag(const absl::Status& status);

}  // namespace tandem::cli

#endif  // TANDEM_APPS_COMMON_EXTRACT_FLAGS_H_
