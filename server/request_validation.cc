#include "tandem/server/request_validation.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "tandem/common/wire.h"
#include "tandem/status_macros.h"

namespace tandem::server {
namespace {

std::string SliceShape(const VolumeInfo& g) {
  return absl::StrCat(g.nx, " x ", g.ny, " x ", std::string(DTypeName(g.dtype)), " = ",
                      g.slice_bytes(), " bytes");
}

absl::Status Prefixed(const std::string& prefix, const absl::Status& st) {
  if (st.ok()) return st;
  return absl::Status(st.code(), absl::StrCat(prefix, std::string(st.message())));
}

// SessionOptions' member names are SessionConfig's field names.
std::string ConfigFieldName(const std::string& field) {
  return absl::StrCat("config.", field, field == "error" ? " (E0)" : "");
}

// SessionConfig.labels into the options, with the refusals of what a label session cannot
// do on this server, each naming its field.
absl::Status ApplyLabels(const v1::SessionConfig& c, SessionOptions* o) {
  const v1::LabelConfig& l = c.labels();
  if (!l.enabled()) {
    if (l.background() != 0 || l.only_size() > 0 || l.close()) {
      return absl::InvalidArgumentError(
          "config.labels.background, .only and .close go with config.labels.enabled");
    }
    return absl::OkStatus();
  }
  const struct {
    bool set;
    const char *field, *why;
  } refused[] = {
      {!c.extra_isos().empty(), "config.extra_isos",
       "a label map's surfaces lie between its labels, not at iso-values"},
      {c.compute_distances(), "config.compute_distances",
       "the distances measure an iso-surface against its unsimplified self"},
  };
  for (const auto& r : refused) {
    if (r.set) {
      return absl::InvalidArgumentError(
          absl::StrCat(r.field, " does not go with config.labels: ", r.why));
    }
  }
  o->labels.enabled = true;
  o->labels.background = l.background();
  o->labels.only.assign(l.only().begin(), l.only().end());
  o->labels.close = l.close();
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<JobConfig> ValidateConfig(const v1::SessionConfig& c, const ServerLimits& limits) {
  JobConfig out;
  VolumeInfo& g = out.grid;
  // This server's limits come first (RESOURCE_EXHAUSTED); ValidateVolumeInfo below names any
  // other bad dimension. Divided so that nx * ny cannot overflow.
  if (c.nx() > 0 && c.ny() > 0 && c.nx() > limits.max_voxels_per_slice / c.ny()) {
    return absl::ResourceExhaustedError(absl::StrCat(
        "config.nx x config.ny = ", c.nx(), " x ", c.ny(), " voxels per slice exceeds this server's limit of ",
        limits.max_voxels_per_slice, " (tandem-server --max-voxels-per-slice)"));
  }
  if (c.nz() > limits.max_slices) {
    return absl::ResourceExhaustedError(absl::StrCat(
        "config.nz = ", c.nz(), " exceeds this server's limit of ", limits.max_slices,
        " slices (tandem-server --max-slices)"));
  }
  g.nx = c.nx();
  g.ny = c.ny();
  g.nz = c.nz();
  TANDEM_ASSIGN_OR_RETURN(DType dtype, common::DTypeFromProto(c.dtype(), "config.dtype"));
  g.dtype = dtype;
  for (auto [field, values, target] :
       {std::tuple{"config.spacing", &c.spacing(), &g.spacing},
        std::tuple{"config.origin", &c.origin(), &g.origin}}) {
    if (values->empty()) continue;
    if (values->size() != 3) {
      return absl::InvalidArgumentError(absl::StrCat(field, " has ", values->size(),
                                                     " values; give 3 (x, y, z) or none"));
    }
    for (int a = 0; a < 3; ++a) (*target)[a] = values->Get(a);
  }
  if (!c.directions().empty()) {
    if (c.directions_size() != 9) {
      return absl::InvalidArgumentError(
          absl::StrCat("config.directions has ", c.directions_size(),
                       " values; give 9 (unit vectors of the x, y and z axes) or none"));
    }
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) g.directions[a][b] = c.directions(3 * a + b);
    }
  }
  g.description = c.description();
  if (!c.frame().empty()) {
    absl::StatusOr<Space> space = ParseSpace(c.frame());
    if (!space.ok()) {
      return absl::InvalidArgumentError(
          "config.frame: expected \"LPS\", \"RAS\", \"voxel\", \"grid\" or none");
    }
    g.space = *space;
    g.frame = std::string(SpaceName(*space));
  }
  // The grid's rules are core's (ValidateVolumeInfo); the prefix says they are the config's.
  if (absl::Status st = ValidateVolumeInfo(g); !st.ok()) return Prefixed("config: ", st);

  SessionOptions& o = out.options;
  TANDEM_ASSIGN_OR_RETURN(Schedule schedule, common::ScheduleFromProto(c.schedule()));
  o.schedule = schedule;
  o.iso = c.iso();
  o.error = c.error();
  o.alpha = c.alpha();
  o.target_triangles = c.target_triangles();
  if (c.has_distance_guard()) o.distance_guard = c.distance_guard();
  if (c.has_sag_correction()) o.sag_correction = c.sag_correction();
  if (c.has_lockstep_error()) o.lockstep_error = c.lockstep_error();
  o.parts = c.parts();
  o.seal = c.sealed_chunks();
  if (c.has_seal_margin()) o.seal_margin = c.seal_margin();
  TANDEM_RETURN_IF_ERROR(ApplyLabels(c, &o));
  // The options' rules are core's (SessionOptions::ValidateFor); the message names the
  // request's field.
  if (absl::Status st = o.ValidateFor(g); !st.ok()) {
    return NameOptionError(st, ConfigFieldName, " = ");
  }
  out.isos = {o.iso};
  out.isos.insert(out.isos.end(), c.extra_isos().begin(), c.extra_isos().end());
  if (absl::Status st = ValidateIsoList(out.isos); !st.ok()) {
    return absl::InvalidArgumentError(
        absl::StrCat("config.iso and config.extra_isos: ", st.message()));
  }

  out.preview_every_slices = c.preview().every_slices();
  out.preview_min_interval_ms = c.preview().min_interval_ms();
  out.draco.quantization_bits =
      c.draco().quantization_bits() == 0 ? codec::kDefaultQuantizationBits
                                      : static_cast<int>(c.draco().quantization_bits());
  if (c.draco().has_compression_level()) out.draco.compression_level = c.draco().compression_level();
  if (absl::Status st = codec::ValidateDracoOptions(out.draco); !st.ok()) {
    return Prefixed("config.draco.", st);
  }
  out.compute_distances = c.compute_distances();
  out.description = c.description();
  return out;
}

absl::Status ValidateChunk(const v1::SliceChunk& chunk, const JobConfig& config,
                           const SliceCursor& cursor, const ServerLimits& limits) {
  const VolumeInfo& g = config.grid;
  const uint64_t slice_bytes = g.slice_bytes();
  const int64_t z = chunk.slice();
  if (chunk.dtype() != v1::DTYPE_UNSPECIFIED && chunk.dtype() != common::DTypeToProto(g.dtype)) {
    return absl::InvalidArgumentError(absl::StrCat(
        "slice ", z, ": chunk.dtype ", v1::DType_Name(chunk.dtype()),
        " does not match config.dtype ", v1::DType_Name(common::DTypeToProto(g.dtype))));
  }
  if (chunk.slice_size() != 0 && chunk.slice_size() != slice_bytes) {
    return absl::InvalidArgumentError(absl::StrCat(
        "slice ", z, ": wrong slice size: chunk.slice_size = ", chunk.slice_size(),
        " bytes, but the config's grid needs ", SliceShape(g)));
  }
  if (z < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("chunk.slice = ", z, ": slice indices start at 0"));
  }
  if (z < cursor.slice) {
    return absl::InvalidArgumentError(absl::StrCat(
        "slice ", z, " repeated: slices 0..", cursor.slice - 1, " are complete; expected slice ",
        cursor.slice));
  }
  if (z > cursor.slice) {
    if (cursor.bytes_so_far > 0) {
      return absl::InvalidArgumentError(absl::StrCat(
          "slice ", z, " started before slice ", cursor.slice, " was complete (got ",
          cursor.bytes_so_far, " of ", SliceShape(g), "): wrong slice size?"));
    }
    return absl::InvalidArgumentError(
        absl::StrCat("slice ", z, " out of order: expected slice ", cursor.slice));
  }
  if (g.nz > 0 && z >= g.nz) {
    return absl::InvalidArgumentError(
        absl::StrCat("slice ", z, " is past the declared config.nz = ", g.nz));
  }
  if (z >= limits.max_slices) {
    return absl::ResourceExhaustedError(absl::StrCat(
        "slice ", z, " exceeds this server's limit of ", limits.max_slices,
        " slices (tandem-server --max-slices)"));
  }
  if (chunk.offset() >= slice_bytes) {
    return absl::InvalidArgumentError(absl::StrCat(
        "slice ", z, ": chunk.offset = ", chunk.offset(), " is past the end of the slice (",
        SliceShape(g), ")"));
  }
  if (chunk.offset() != cursor.bytes_so_far) {
    return absl::InvalidArgumentError(absl::StrCat(
        "slice ", z, ": chunk.offset = ", chunk.offset(), ", expected ", cursor.bytes_so_far,
        " (chunks of a slice must be sent in order, without gaps or overlaps)"));
  }
  if (chunk.offset() + chunk.data().size() > slice_bytes) {
    return absl::InvalidArgumentError(absl::StrCat(
        "slice ", z, ": wrong slice size: a chunk of ", chunk.data().size(), " bytes at offset ",
        chunk.offset(), " runs past the end of the slice (", SliceShape(g), ")"));
  }
  return absl::OkStatus();
}

absl::Status ValidateEnd(const v1::End& end, const JobConfig& config, const SliceCursor& cursor) {
  if (cursor.bytes_so_far > 0) {
    return absl::InvalidArgumentError(absl::StrCat(
        "End arrived inside slice ", cursor.slice, " (got ", cursor.bytes_so_far, " of ",
        SliceShape(config.grid), ")"));
  }
  if (end.slices() > 0 && end.slices() != cursor.slice) {
    return absl::InvalidArgumentError(absl::StrCat(
        "End.slices = ", end.slices(), " but the server received ", cursor.slice, " slices"));
  }
  if (config.grid.nz > 0 && cursor.slice != config.grid.nz) {
    return absl::InvalidArgumentError(absl::StrCat("End after ", cursor.slice,
                                                   " slices but config.nz = ", config.grid.nz));
  }
  if (cursor.slice < 2) {
    return absl::InvalidArgumentError(
        absl::StrCat("End after ", cursor.slice, " slice(s): at least 2 are needed"));
  }
  return absl::OkStatus();
}

}  // namespace tandem::server
