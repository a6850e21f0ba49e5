// The client side of tandem.v1.Tandem/Extract: streams a volume read through core's
// OpenVolume slice by slice (never the whole volume in memory) and collects previews, the
// final mesh and the final metrics.
#ifndef TANDEM_CLIENT_STREAM_CLIENT_H_
#define TANDEM_CLIENT_STREAM_CLIENT_H_

#include <algorithm>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/client/chunk_store.h"
#include "tandem/client/connection.h"
#include "tandem/mesh.h"
#include "tandem/v1/tandem.pb.h"
#include "tandem/volume.h"

namespace tandem::client {

struct StreamOptions {
  ConnectionOptions connection;
  v1::SessionConfig config;  // grid fields are filled from the volume
  double rate = 0;           // slices per second, 0 = as fast as the server takes them
  size_t chunk_bytes = 0;    // SliceChunk payload, > 0
  double timeout_s = 0;      // gRPC deadline for the whole stream, 0 = none
  // Resume a session whose client vanished (tandem.proto: Resume) instead of starting one:
  // its id and token (the first Progress of the stream that started it). The source is
  // read from its start; the slices the session already consumed are skipped.
  std::string resume_session_id, resume_token;
  // Sealed chunks are saved here as they arrive (before the callbacks see them) and
  // acknowledged to the server (SessionConfig.chunk_acks), which then keeps every chunk not
  // saved yet until the session ends; a resume starts from the chunks already in it (they go
  // through the callbacks and into the result first). Null: none kept.
  ChunkStore* chunk_store = nullptr;
  // Puts the source back at its first slice (opens the volume again), for a resume that
  // needs slices the source has passed (sent before the connection broke, not consumed).
  // Unset: such a resume fails.
  std::function<absl::Status()> rewind;
};

// What the stream delivered. Callbacks run on the calling thread, in message order.
struct StreamCallbacks {
  std::function<void(const v1::Progress&, int64_t slices_sent)> on_progress;
  std::function<void(const v1::Preview&, int64_t slices_sent)> on_preview;
  // A sealed chunk (config.sealed_chunks), as received; StreamResult::sealed gets it decoded.
  std::function<void(const v1::SealedChunk&)> on_chunk;
  // A refused attempt about to be sent again (retry 1.., after `seconds`).
  std::function<void(const absl::Status& refusal, int retry, double seconds)> on_retry;
  // The stream broke after the session started (`cause`): resuming it at `slice` after
  // `seconds` (attempt 1.. since the last one that got through).
  std::function<void(const absl::Status& cause, int64_t slice, int attempt, double seconds)>
      on_resume;
  // A resume with StreamOptions::chunk_store: how many chunks it holds already (they come
  // through on_chunk next).
  std::function<void(int64_t kept)> on_chunks_kept;
};

// One surface's final mesh and metrics.
struct SurfaceResult {
  std::string draco;  // the final mesh, chunks concatenated and checked (empty when sealed)
  // config.sealed_chunks: every chunk decoded, in order; WeldChunks gives the final mesh,
  // whose counts were checked against the final metrics.
  std::vector<SealedChunk> sealed;
  int64_t triangles = 0, vertices = 0;
  v1::FinalMetrics metrics;
};

// What the stream delivered: its own fields are surface 0's (config.iso); with
// config.extra_isos, extra_surfaces holds the others, in order.
struct StreamResult : SurfaceResult {
  std::vector<SurfaceResult> extra_surfaces;
  // A label session (config.labels): the surfaces are its labels' (metrics.label() the id,
  // num_labels() of them, none when only the background was found), and session_metrics
  // the whole session's figures.
  bool labels = false;
  v1::FinalMetrics session_metrics;
  size_t num_labels() const {
    return static_cast<size_t>(std::max<int64_t>(0, session_metrics.labels()));
  }
  bool sealed_session = false;  // the mesh came as sealed chunks
  std::string session_id;       // the session's id (first Progress)
  int resumes = 0;              // times the stream was resumed after a drop
  int64_t chunks_received = 0;  // sealed chunks, all surfaces together
  int64_t slices_sent = 0;
  double seconds = 0;  // wall time of the whole stream

  size_t num_surfaces() const { return 1 + extra_surfaces.size(); }
  SurfaceResult& surface(size_t i) { return i == 0 ? *this : extra_surfaces[i - 1]; }
  const SurfaceResult& surface(size_t i) const { return i == 0 ? *this : extra_surfaces[i - 1]; }
};

// Whether a failed StreamVolume's status is a local one (reading the volume, saving the
// chunks), not the server's: it carries a payload that says so.
bool IsLocalError(const absl::Status& status);

// Runs one Extract stream. The client sends the config, then waits for the server's first
// message (a Progress as soon as it took the session) before it reads and sends slices: a
// stream refused at the door (RESOURCE_EXHAUSTED: every session slot taken; UNAVAILABLE:
// the server is going away) has used nothing of the volume and is sent again, up to
// `connection.retries` times with backoff. The error is the server's status (code and
// message kept), or a local one (reading the volume, a malformed reply) with the file or
// message named.
// Once the session has started, a stream that breaks (UNAVAILABLE: connection lost, server
// restarting) is resumed (tandem.proto: Resume) with the same backoff and budget, from the
// first slice the server has not consumed, read again through options.rewind (the client
// holds no copy of what it sent). A resume the server answers with NOT_FOUND (it restarted,
// or the session's window is over) fails with NOT_FOUND "the server no longer has session
// ID ...; send the scan again".
absl::StatusOr<StreamResult> StreamVolume(SliceSource& source, const StreamOptions& options,
                                          const StreamCallbacks& callbacks);

// Watches another stream's session (tandem.proto: Watch) by its id and watch key (or, with
// a bearer token, as its creator): its sealed chunks, from the first, then its progress,
// previews and final metrics, as StreamVolume collects them (slices_sent = the session's
// slices). A label session's come per label, as its own client gets them (result.labels).
absl::StatusOr<StreamResult> WatchSession(const ConnectionOptions& connection,
                                          const std::string& session_id,
                                          const std::string& watch_key, double timeout_s,
                                          const StreamCallbacks& callbacks);

}  // namespace tandem::client

#endif  // TANDEM_CLIENT_STREAM_CLIENT_H_
