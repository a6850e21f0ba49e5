// tandem measure: Metro-style distances between two meshes.
#include <cstdio>
#include <filesystem>
#include <string>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "apps/common/flags.h"
#include "command.h"
#include "tandem/eval/distance.h"
#include "tandem/io/mesh_io.h"
#include "tandem/eval/report.h"

namespace tandem::app {

namespace {

std::string DistanceTable(const eval::Distances& d) {
  std::string s =
      absl::StrFormat("%-6s %14s %14s %14s\n", "", "forward(A->B)", "backward(B->A)", "max");
  absl::StrAppend(&s, absl::StrFormat("%-6s %14.6g %14.6g %14.6g\n", "L1", d.forward.l1,
                                      d.backward.l1, d.l1_max));
  absl::StrAppend(&s, absl::StrFormat("%-6s %14.6g %14.6g %14.6g\n", "L2", d.forward.l2,
                                      d.backward.l2, d.l2_max));
  absl::StrAppend(&s, absl::StrFormat("%-6s %14.6g %14.6g %14.6g\n", "Linf", d.forward.linf,
                                      d.backward.linf, d.linf_max));
  return s;
}

}  // namespace

int MeasureCommand(int argc, char** argv) {
  int64_t samples = 0;
  bool json = false;
  cli::FlagSet flags(
      "usage: tandem measure A.{ply,obj,stl} B.{ply,obj,stl} [flags]\n"
      "Metro-style distances between two meshes by area-uniform sampling and exact\n"
      "point-to-triangle distance: L1 (mean), L2 (RMS) and Linf (Hausdorff), A->B (forward),\n"
      "B->A (backward) and the larger of the two (max). Units are the meshes' own.");
  flags.AddInt("samples", &samples, "surface samples per direction (0 = automatic)");
  flags.AddBool("json", &json, "print the distances as JSON instead of a table");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  if (flags.positional().size() != 2)
    return Usage(absl::InvalidArgumentError("expected two meshes: A B"));
  for (const std::string& path : flags.positional()) {
    const std::string ext = absl::AsciiStrToLower(std::filesystem::path(path).extension().string());
    if (ext != ".ply" && ext != ".obj" && ext != ".stl") {
      return Usage(
          absl::InvalidArgumentError(absl::StrCat(path, ": expected a .ply, .obj or .stl mesh")));
    }
  }
  auto a = io::ReadMesh(flags.positional()[0]);
  if (!a.ok()) return Fail(a.status());
  auto b = io::ReadMesh(flags.positional()[1]);
  if (!b.ok()) return Fail(b.status());
  if (a->num_triangles() == 0 || b->num_triangles() == 0) {
    return Fail(absl::InvalidArgumentError("both meshes need at least one triangle"));
  }
  eval::DistanceOptions dopt;
  dopt.samples = static_cast<size_t>(samples);
  const eval::Distances d = eval::MeasureDistances(*a, *b, dopt);
  if (json) {
    std::fputs(eval::DistancesToJson(d).c_str(), stdout);
  } else {
    std::fputs(DistanceTable(d).c_str(), stdout);
  }
  return 0;
}

}  // namespace tandem::app
