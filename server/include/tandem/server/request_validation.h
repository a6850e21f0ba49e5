// Turns untrusted tandem.v1 requests into core options, or into a Status a person can act
// on. Pure functions of the messages and the server's limits: no gRPC, no threads.
//
// Codes: INVALID_ARGUMENT for malformed or inconsistent input, RESOURCE_EXHAUSTED when a
// well-formed request exceeds this server's limits (the message names the flag to raise).
// Field names in messages are the proto's ("config.error", "chunk.offset").
#ifndef TANDEM_SERVER_REQUEST_VALIDATION_H_
#define TANDEM_SERVER_REQUEST_VALIDATION_H_

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/tandem.h"
#include "tandem/v1/tandem.pb.h"
#include "tandem/volume.h"

namespace tandem::server {

// Operator-set limits (tandem-server flags of the same names; GetInfo reports them all).
struct ServerLimits {
  int64_t max_voxels_per_slice = int64_t{4096} * 4096;  // --max-voxels-per-slice
  int64_t max_slices = 16384;                           // --max-slices
  int max_sessions = 8;                                 // --max-sessions
  int64_t max_message_bytes = int64_t{16} << 20;        // --max-message-bytes
  double idle_timeout_s = 300;                          // --idle-timeout-seconds
  int64_t session_memory_bytes = int64_t{1024} << 20;   // --session-memory-mb (in MiB)
  int64_t max_inflight_bytes = int64_t{16} << 20;       // --max-inflight-bytes
  // Watch: sealed chunks kept per session for late watchers, and how long a finished
  // session stays watchable.
  int64_t watch_retain_bytes = int64_t{64} << 20;  // --watch-retain-mb
  double watch_linger_s = 60;                      // --watch-linger-seconds
  // Where the kept chunks go (empty: memory); not reported by GetInfo, a path on the server.
  std::string watch_spill_dir;  // --watch-spill-dir
  // A stream whose client vanished before End keeps its session this long for a resume.
  double resume_window_s = 60;  // --resume-window-seconds
  // Previews are never closer than this, whatever the client asks (each one snapshots and
  // encodes the whole partial mesh): --min-preview-interval-ms.
  int64_t min_preview_interval_ms = 250;
  // And previews take at most this share of the stream's wall time: one is skipped while
  // the time spent encoding previews exceeds it (a stream with a preview every slice then
  // costs at most about 1 / (1 - share) of one without). <= 0: no bound.
  double max_preview_share = 0.2;
  // Sealed streams: band previews resend the unsealed band each time; their bytes stay under
  // this share of the chunks' bytes (the first one always goes). <= 0: no bound.
  double max_band_bytes_share = 0.25;
  // HTTP/2 transport (grpc::ServerBuilder channel arguments).
  int64_t keepalive_time_ms = 60000;            // --keepalive-time-ms (0 = no pings)
  int64_t keepalive_timeout_ms = 20000;         // --keepalive-timeout-ms
  int64_t min_ping_interval_ms = 10000;         // --keepalive-min-ping-interval-ms
  bool permit_keepalive_without_calls = false;  // --keepalive-permit-without-calls
  // Threads that all sessions share for their computing (each session's own worker thread
  // feeds it and runs its steps too): --compute-threads; 0 = one per core.
  int compute_threads = 0;
};

// Everything a job needs, checked.
struct JobConfig {
  VolumeInfo grid;  // nz = 0 when unknown
  SessionOptions options;
  codec::DracoOptions draco;
  int64_t preview_every_slices = 0;  // 0 = no previews
  int64_t preview_min_interval_ms = 0;
  bool compute_distances = false;
  std::string description;
  std::vector<double> isos;  // the surfaces: options.iso, then SessionConfig.extra_isos
};

// Checks every field of the first message (see tandem.proto for the rules and defaults).
absl::StatusOr<JobConfig> ValidateConfig(const v1::SessionConfig& config,
                                         const ServerLimits& limits);

// Where the assembly of the current slice stands.
struct SliceCursor {
  int64_t slice = 0;          // index of the slice being assembled (= complete slices)
  uint64_t bytes_so_far = 0;  // bytes of it received
};

// Checks one chunk against the cursor: dtype and slice_size when given, slice index (no
// repeat, no gap, not past nz or --max-slices), offset contiguous, end within the slice.
absl::Status ValidateChunk(const v1::SliceChunk& chunk, const JobConfig& config,
                           const SliceCursor& cursor, const ServerLimits& limits);

// Checks the End marker: no partial slice, End.slices (when > 0) and the declared nz
// match the slices received, at least 2 slices.
absl::Status ValidateEnd(const v1::End& end, const JobConfig& config, const SliceCursor& cursor);

}  // namespace tandem::server

#endif  // TANDEM_SERVER_REQUEST_VALIDATION_H_
