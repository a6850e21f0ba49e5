// tandem: the local command line of the library. Each subcommand has its own file:
//   tandem extract   volume -> (simplified) iso-surface mesh, with metrics
//   tandem generate  synthetic volume (raw + JSON sidecar, or OME-Zarr)
//   tandem measure   Metro-style distances between two meshes
//   tandem info      what a volume file holds
//   tandem simulate  an instrument writing a volume slice by slice
//   tandem view      a finished mesh in the browser viewer
#include <cstdio>
#include <exception>
#include <string>

#include "absl/status/status.h"
#include "apps/common/version.h"
#include "command.h"
#include "tandem/tandem.h"

namespace {

constexpr char kUsage[] =
    R"(tandem: extract and simplify iso-surfaces of volumes, one slice at a time
(Attali, Cohen-Steiner, Edelsbrunner, "Extraction and Simplification of Iso-surfaces in
Tandem", SGP 2005).

Usage:
  tandem extract  --input FILE --out MESH.{ply,obj,stl,glb} [--iso C0[,C1,...]] [flags]
  tandem generate {sphere,pillowbox,link,gyroid} --size N --out FILE [--series dicom|tiff]
  tandem measure  A.{ply,obj,stl} B.{ply,obj,stl} [--samples N] [--json]
  tandem info     --input FILE
  tandem simulate --input FILE --out DIR --as dicom|tiff|zarr --rate R   (an instrument)
  tandem view     MESH.{ply,obj,stl,glb,drc} | DIR_OF_CHUNKS [--view HOST:PORT]   (browser)
  tandem --version
Every subcommand's --help lists its flags with their defaults.

Volume files: .json (raw + JSON sidecar), .nrrd/.nhdr (raw or gzip), .nii/.nii.gz,
.tif/.tiff (multi-page stack), .mha/.mhd (ITK MetaImage), Zarr v2/v3 and OME-Zarr stores
(X.zarr; X.zarr#N reads
multiscale level N, X.zarr#PATH the array PATH inside the group), or a folder of one
file per slice: a DICOM series (any names and order; vertices in the patient frame) or
numbered single-page TIFFs. Voxel types uint8, int8, uint16, int16, uint32, int32, uint64,
int64, float32; `extract --labels` meshes an integer volume as a label map (one surface per
label).
)";

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h" ||
      std::string(argv[1]) == "help") {
    std::fputs(kUsage, argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  const std::string cmd = argv[1];
  if (cmd == "--version" || cmd == "version") {
    std::fputs(TANDEM_VERSION_LINE("tandem"), stdout);
    return 0;
  }
  try {  // no input may abort the process: report and exit 1
    if (cmd == "extract") return tandem::app::ExtractCommand(argc, argv);
    if (cmd == "generate") return tandem::app::GenerateCommand(argc, argv);
    if (cmd == "measure") return tandem::app::MeasureCommand(argc, argv);
    if (cmd == "info") return tandem::app::InfoCommand(argc, argv);
    if (cmd == "simulate") return tandem::app::SimulateCommand(argc, argv);
    if (cmd == "view") return tandem::app::ViewCommand(argc, argv);
  } catch (...) {
    const absl::Status st = tandem::StatusOfException(std::current_exception());
    std::fprintf(stderr, "tandem %s: %s\n", cmd.c_str(), std::string(st.message()).c_str());
    return 1;
  }
  std::fprintf(stderr, "tandem: unknown command '%s'\n\n%s", cmd.c_str(), kUsage);
  return 2;
}
