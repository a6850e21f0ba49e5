// SessionOptions: what a session is asked to do (TandemSession::Create), and the one set of
// rules those options must satisfy.
#ifndef TANDEM_OPTIONS_H_
#define TANDEM_OPTIONS_H_

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/labels.h"
#include "tandem/volume.h"

namespace tandem {

enum class Schedule : uint8_t { kNone, kClassical, kTandem, kTandemLag };
std::string_view ScheduleName(Schedule s);  // "none", "classical", "tandem", "tandem-lag"
absl::StatusOr<Schedule> ParseSchedule(std::string_view name);

struct SessionOptions {
  double iso = 0;
  Schedule schedule = Schedule::kTandemLag;  // kNone = full resolution, no simplification
  double error = 0;             // E0 (physical units); required > 0 unless kNone
  double alpha = 0;             // isotropy parameter in [0, 1]
  // Distance guard K (not in the paper; 0 turns it off): a contraction is refused when the
  // new vertex would lie farther than K·E0 from the plane of a triangle it reshapes (one of
  // the triangles around a or b that survive, as they are now). ε0 <= E0 bounds a root mean
  // square over every plane a vertex has absorbed, so one thin feature can end up far from
  // the surface while the average stays small; the guard bounds each step instead (what it
  // buys and costs: docs/decisions.md). Not applied to the last contractions toward
  // target_triangles when E0 cannot reach the count (those go past E0).
  double distance_guard = 2;
  // Sag correction F (not in the paper; 0 turns it off): after the last SIMPLIFY, every
  // vertex not on the grid's box moves along its normal by F times the mean chordal sag of
  // its triangles (sag_correction.h), never so far that its ε0 exceeds E0 or a
  // triangle turns over. The quadric minimiser leaves a coarse mesh biased toward the
  // concave side of the surface; F = 0.3 removes most of that bias.
  double sag_correction = 0.3;
  // The finishing pass (not in the paper; 1 turns it off). Without target_triangles and
  // unsealed, the lock-step (tandem, tandem-lag) simplifies to lockstep_error x E0, but not
  // below kDefaultErrorVoxels x the smallest spacing, and when the stream ends the whole
  // mesh comes down to E0 in one cost order, as the classical algorithm's last contractions
  // would. With a coarse E0 itself in lock-step, each region is taken down to E0 before the
  // next arrives, so the coarsest contractions go in the sweep's order rather than by cost
  // (RMS distance above classical's at a few hundred triangles). At E0 up to the default
  // the lock-step's order is already close to the cost order, and the pass would cost time
  // and memory on dense streams (docs/decisions.md 25): E0 runs there are the paper's. The
  // session holds the mesh at the lock-step's E0 meanwhile, and the pass runs after the
  // last slice.
  double lockstep_error = 0.5;
  // > 0: simplify to this many triangles. E0 starts at min(error, smallest spacing / 1000)
  // and rises as the mesh grows (schedule.h: TargetControl), so the count is reached whatever
  // error is, unless the surface's components and handles need more; the parts share E0.
  // SessionStats::error_reached is where it ended.
  int64_t target_triangles = 0;
  bool pipeline = true;         // use the session's executor (identical results either
                                // way): the slabs side by side, AddSlice queuing up to 4
                                // slices; with one slab, EXTRACT(k) while layer k-1 is
                                // simplified (tandem schedules) and half of every large
                                // batch of edge evaluations (DELAY, ACTIVATE)
  int parts = 0;                // slabs along x (see above); 0 = automatic: 4 when the grid
                                // is at least 256 wide, 2 when at least 81, else 1. At
                                // most one part per 16 columns (fewer are used on narrow
                                // grids).
  static constexpr int kMaxParts = 64;
  // Sealing: behind the sweep, vertices whose reach lies seal_margin slices below
  // the front freeze, and the triangles they complete leave the session as sealed chunks
  // (TakeSealed): the session then holds the front, not the mesh, and the chunks together
  // are the result (WeldChunks; Snapshot() is only what is not sealed yet). With several
  // parts, the triangles at a seam wait for the merge at the end, up to seam_settle_slices
  // behind the front, where the seam is coarsened in both parts at once and sealed
  // (slabs.h); no target triangle count (that needs the whole mesh at the end).
  bool seal = false;
  double seal_margin = 2;
  // What a sealed split session holds at its seams grows with the depth up to this many
  // slices, then follows the front: deeper, the seams wait longer for the merge's
  // contractions across them; shallower, less is held (the settled part is coarsened along
  // the seam only). Checked only with seal; at least 1.
  int64_t seam_settle_slices = 512;
  // And up to this many vertices a seam: past them, its oldest vertices settle too, down to
  // this many, except those within kSeamSettleFloor slices of the front (slabs.h). So a
  // dense seam (the seams' full-resolution fans cost about a KiB a vertex) is held for fewer
  // slices, and a sparse one, whose settling would cost triangles for little memory, waits
  // as long as seam_settle_slices says. Checked only with seal; at least 1.
  int64_t seam_hold_vertices = 2048;
  // Tests: the simplifier also keeps every vertex's quadric in full, as the layers and the
  // contractions sum it, and counts the quadrics it reads that differ (SessionStats::
  // quadric_mismatches; 0: every vertex kept its quadric in full before it moved). Slower.
  bool check_quadrics = false;
  // Label mode (labels.enabled): the slices are a label map (integer dtypes through
  // AddSliceBytes; float input is refused), every label's surface comes out of one sweep as
  // the interface complex (SnapshotLabeled), `iso` is not used. One part. With seal, each
  // chunk carries its triangles' label pairs (SealedChunk::patch, pairs; WeldLabeledChunks).
  LabelOptions labels{};
  // The rules the options must satisfy, here and nowhere else. A refusal is
  // InvalidArgument "<field> = <value>: <rule>" (e.g. "alpha = 1.5: isotropy alpha must lie
  // in [0, 1]") and carries an OptionError, so that a front end can name the field in its
  // own terms (NameOptionError).
  absl::Status Validate() const;
  // Validate() plus the rules that need the grid: E0 within [kMinErrorVoxels,
  // kMaxErrorVoxels] times the grid's smallest / largest spacing (far below, nothing could
  // ever be contracted; far above, E0 is certainly a unit error). TandemSession::Create
  // applies it; callers that want their own field names call it first.
  absl::Status ValidateFor(const VolumeInfo& grid) const;
  static constexpr double kMinErrorVoxels = 1e-6, kMaxErrorVoxels = 1e6;
  // The command lines' default E0, in smallest spacings (a fifth of a voxel); the finishing
  // pass's lock-step never runs below it.
  static constexpr double kDefaultErrorVoxels = 0.2;
};

// What Validate() / ValidateFor() refused.
struct OptionError {
  std::string field;  // the SessionOptions member: "iso", "error", "alpha", "parts", ...
  std::string value;  // its value, as text
  std::string rule;   // what it must satisfy
};
// The OptionError a status of Validate() / ValidateFor() carries; nullopt for any other.
std::optional<OptionError> OptionErrorOf(const absl::Status& status);
// The same refusal worded "<label(field)><separator><value>: <rule>", e.g. the server's
// "config.alpha = 1.5: ..." or the command line's "--alpha 1.5: ..."; any other status
// unchanged.
absl::Status NameOptionError(const absl::Status& status,
                             std::string (*label)(const std::string& field),
                             const std::string& separator);

// Several surfaces from one read of the slices: each runs its own session side by side.
inline constexpr int kMaxIsoValues = 8;
// The rule on such a list: at most kMaxIsoValues values, each finite, none twice.
// InvalidArgument ("iso-value 60 is given twice"), for a front end to prefix with its
// flag or field.
absl::Status ValidateIsoList(std::span<const double> isos);

}  // namespace tandem

#endif  // TANDEM_OPTIONS_H_
