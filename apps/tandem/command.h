// The subcommands of `tandem` (one file each; main.cc dispatches) and how each reports a
// mistake in its command line or a failure while running.
#ifndef TANDEM_APPS_TANDEM_COMMAND_H_
#define TANDEM_APPS_TANDEM_COMMAND_H_

#include <string>

#include "absl/status/status.h"
#include "apps/common/extract_flags.h"
#include "apps/common/flags.h"
#include "tandem/io/mesh_io.h"
#include "tandem/volume.h"

namespace tandem::app {

// Each takes the whole command line (argv[1] is the subcommand) and returns the exit status.
int ExtractCommand(int argc, char** argv);
int GenerateCommand(int argc, char** argv);
int MeasureCommand(int argc, char** argv);
int InfoCommand(int argc, char** argv);
int SimulateCommand(int argc, char** argv);
int ViewCommand(int argc, char** argv);

// `tandem extract --neuroglancer DIR` as parsed (extract.cc): levels of detail and nanometres
// per unit of the spacing (0: the grid's default, DefaultNmPerUnit).
struct NeuroglancerRequest {
  std::string dir;  // empty: no export
  int lods = 3;
  double nm_per_unit = 0;
  int chunk_voxels = 32;
  double skirt_voxels = -1;  // negative: the default
};

// `tandem extract --labels` once the volume is open (extract.cc hands over to
// extract_labels.cc): the session (and its coarser sweeps for --neuroglancer), the per-label
// outputs and figures.
int ExtractLabels(const cli::ExtractFlags& f, const cli::FlagSet& flags, SliceSource& source,
                  const io::MeshWriteOptions& write, const NeuroglancerRequest& neuroglancer);

// A failure met while running (a file, a device, a session): "tandem: MESSAGE" on stderr,
// exit status 1 (apps/common/cli_util.h).
int Fail(const absl::Status& st);

// A mistake in the command line itself: exit status 2.
int Usage(const absl::Status& st);

// A writer's refusal of what the flags ask for (a format that cannot hold it: Invalid
// argument or Unimplemented) is the command line's; anything else happened while writing.
int FailWriting(const absl::Status& st);

// Parses a subcommand's flags (argv[2..]): -1 to go on, else the exit status (0 after
// printing --help).
int ParseOrExit(cli::FlagSet& flags, int argc, char** argv);

// Writes `text` to `path`; an error names the path.
absl::Status WriteText(const std::string& path, const std::string& text);

}  // namespace tandem::app

#endif  // TANDEM_APPS_TANDEM_COMMAND_H_
