// RunSession: the driver that reads a SliceSource (volume.h) slice by slice, reading ahead on
// another thread, and feeds the slices to TandemSessions.
#ifndef TANDEM_RUN_SESSION_H_
#define TANDEM_RUN_SESSION_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "tandem/executor.h"
#include "tandem/mesh.h"
#include "tandem/options.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"

namespace tandem::io {

// Runs a session over every slice of `source`. With sealing (SessionOptions::seal), the
// sealed chunks are taken after every slice and handed to on_chunk (required then); a
// non-OK status from it ends the run. `executor`: the sessions' threads (null: the shared one).
absl::StatusOr<std::unique_ptr<TandemSession>> RunSession(
    SliceSource& source, const SessionOptions& options,
    const std::function<void(int64_t, int64_t)>& progress = nullptr,
    const std::function<absl::Status(SealedChunk)>& on_chunk = nullptr,
    Executor* executor = nullptr);

// Several surfaces in one pass (e.g. skin and bone, one iso-value each): one session per
// options entry, all fed from a single read of each slice and run side by side. Each
// session's mesh is the one RunSession would give with its options alone. on_chunk gets the
// index of the options entry the chunk belongs to. `finishing`, once the last slice is in,
// is called every kFinishingEvery seconds from another thread while the sessions finish, with
// each session's TandemSession::FinishProgress (for a status line).
using FinishingFn = std::function<void(const std::vector<TandemSession::Finishing>&)>;
absl::StatusOr<std::vector<std::unique_ptr<TandemSession>>> RunSessions(
    SliceSource& source, const std::vector<SessionOptions>& options,
    const std::function<void(int64_t, int64_t)>& progress = nullptr,
    const std::function<absl::Status(size_t, SealedChunk)>& on_chunk = nullptr,
    Executor* executor = nullptr, const FinishingFn& finishing = nullptr);

}  // namespace tandem::io

#endif  // TANDEM_RUN_SESSION_H_
