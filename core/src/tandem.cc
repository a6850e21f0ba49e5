// TandemSession (tandem.h): the contract, forwarded to its Impl (session_impl.h), with the
// barrier that turns every exception inside a session into the status of the call.
#include "tandem/tandem.h"

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <mutex>
#include <new>
#include <stdexcept>

#include "absl/strings/str_cat.h"
#include "session_impl.h"
#include "tandem/status_macros.h"

namespace tandem {

absl::Status StatusOfException(std::exception_ptr e) {
  try {
    std::rethrow_exception(e);
  } catch (const SessionStop& stop) {
    return stop.status();
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError("out of memory while processing this volume");
  } catch (const std::length_error& ex) {
    return absl::ResourceExhaustedError(
        absl::StrCat("a buffer of this session would exceed its maximum size (", ex.what(), ")"));
  } catch (const std::exception& ex) {
    return absl::InternalError(absl::StrCat("internal error in the session: ", ex.what()));
  } catch (...) {
    return absl::InternalError("internal error in the session (unknown exception)");
  }
}

// ---- TandemSession: the contract, forwarded to Impl ----

TandemSession::TandemSession(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
TandemSession::~TandemSession() = default;

absl::StatusOr<std::unique_ptr<TandemSession>> TandemSession::Create(
    const VolumeInfo& grid, const SessionOptions& options, Executor* executor,
    std::shared_ptr<MemoryBudget> budget) {
  VolumeInfo g = grid;
  TANDEM_RETURN_IF_ERROR(ValidateVolumeInfo(g));
  TANDEM_RETURN_IF_ERROR(options.ValidateFor(g));
  try {
    if (executor == nullptr) executor = &Executor::Shared();
    const int slabs = SlabCount(g, options);
    return std::unique_ptr<TandemSession>(
        new TandemSession(std::make_unique<Impl>(g, options, slabs, executor, std::move(budget))));
  } catch (const std::bad_alloc&) {
    // The extractor's plane caches are O(nx*ny); the only allocation that can be large here.
    return absl::ResourceExhaustedError(absl::StrCat(
        "not enough memory for a ", g.nx, "x", g.ny, " grid (about ",
        LayerExtractor::PlaneCacheBytes(g.nx, g.ny, g.dtype) >> 20,
        " MiB of plane caches); use smaller slices"));
  }
}

namespace {

absl::Status FloatLabelsError() {
  return absl::InvalidArgumentError(
      "a label volume needs integer voxels (uint8, uint16, int16, ...) given through "
      "AddSliceBytes; float32 values are not labels");
}

}  // namespace

absl::Status TandemSession::AddSlice(const float* values) {
  if (impl_->options.labels.enabled) return FloatLabelsError();
  return impl_->Guarded([&] { return impl_->AddSlice(values, DType::kFloat32, nullptr); });
}

absl::Status TandemSession::AddSliceBytes(DType dtype, const uint8_t* bytes) {
  Impl& s = *impl_;
  if (s.options.labels.enabled && dtype == DType::kFloat32) return FloatLabelsError();
  return s.Guarded([&] {
    // An intensity volume of int8, 32- or 64-bit integers: as float32 (a label session reads
    // every integer type as it is).
    if (!s.options.labels.enabled && !SliceValues::ScannedAsIs(dtype)) {
      s.convert.resize(static_cast<size_t>(s.grid.nx * s.grid.ny));
      ConvertToFloat(dtype, bytes, s.convert.size(), s.convert.data());
      return s.AddSlice(s.convert.data(), DType::kFloat32, nullptr);
    }
    if (dtype == DType::kFloat32 && reinterpret_cast<uintptr_t>(bytes) % alignof(float) == 0) {
      // host-order floats as they are
      return s.AddSlice(reinterpret_cast<const float*>(bytes), DType::kFloat32, nullptr);
    }
    // Integers are read as they are (copied into the ring when queued); so are float32
    // bytes on their way into the ring, which aligns them.
    if (s.queued || dtype != DType::kFloat32) return s.AddSlice(nullptr, dtype, bytes);
    s.convert.resize(static_cast<size_t>(s.grid.nx * s.grid.ny));
    std::memcpy(s.convert.data(), bytes, s.convert.size() * sizeof(float));
    return s.AddSlice(s.convert.data(), dtype, nullptr);
  });
}

absl::Status TandemSession::Finish() {
  return impl_->Guarded([&] { return impl_->Finish(); });
}

IndexedMesh TandemSession::Snapshot() const {
  Impl& s = *impl_;
  (void)s.Sync();  // a failure is reported by AddSlice or Finish
  IndexedMesh out;
  if (s.slabs.size() == 1) {
    out = s.slabs[0]->store.Snapshot();
  } else {
    AppendWeldedSnapshot(s.slabs, s.seams, &out);
  }
  s.ToWorld(&out.positions, &out.indices);
  return out;
}

LabeledMesh TandemSession::SnapshotLabeled() const {
  Impl& s = *impl_;
  LabeledMesh out;
  if (!s.options.labels.enabled) return out;
  (void)s.Sync();  // a failure is reported by AddSlice or Finish
  if (s.slabs.size() == 1) {
    const MeshStore& store = s.slabs[0]->store;
    out.mesh = store.Snapshot();
    out.patch = store.SnapshotPatches();
    out.pairs = store.pairs();
  } else {
    AppendWeldedSnapshot(s.slabs, s.seams, &out.mesh);
    AppendWeldedPatches(s.slabs, &out.patch, &out.pairs);
  }
  s.ToWorld(&out.mesh.positions, &out.mesh.indices);
  return out;
}

bool TandemSession::TakeSealed(SealedChunk* out) {
  Impl& s = *impl_;
  (void)s.Sync();
  // Every step's share cut so far, then what the sealers sealed outside the steps (Finish).
  std::vector<SealedChunk> pieces;
  {
    std::lock_guard<std::mutex> lock(s.mu);
    s.TakeCuts(s.CutThrough(), &pieces);
  }
  for (const auto& slab : s.slabs) {
    SealedChunk piece;
    if (slab->sealer != nullptr && slab->sealer->TakeChunk(&piece)) {
      pieces.push_back(std::move(piece));
    }
  }
  return s.JoinTaken(std::move(pieces), out);
}

bool TandemSession::TakeSealedThrough(int64_t slice, SealedChunk* out) {
  Impl& s = *impl_;
  if (s.cuts.empty()) return false;  // not sealing
  // A slice never stepped has no share; a refused one neither.
  const int64_t through = std::min(slice, s.slices_added - 1);
  if (s.queued) {
    s.steps->WaitUntil(
        [&] {
          std::lock_guard<std::mutex> lock(s.mu);
          return s.CutThrough() >= through || s.meter.stopped();
        },
        /*help=*/false);
    if (s.meter.stopped()) return false;  // the session fails at its next call
  }
  std::vector<SealedChunk> pieces;
  {
    std::lock_guard<std::mutex> lock(s.mu);
    s.TakeCuts(std::min(through, s.CutThrough()), &pieces);
  }
  return s.JoinTaken(std::move(pieces), out);
}

int64_t TandemSession::sealed_pending() const {
  (void)impl_->Sync();
  int64_t n = 0;
  {
    std::lock_guard<std::mutex> lock(impl_->mu);
    n = impl_->CutTriangles(impl_->CutThrough());  // every step has finished: all of them
  }
  for (const auto& slab : impl_->slabs) {
    if (slab->sealer) n += slab->sealer->pending_triangles();
  }
  return n;
}

int64_t TandemSession::num_triangles() const {
  (void)impl_->Sync();
  int64_t n = 0;
  for (const auto& slab : impl_->slabs) n += static_cast<int64_t>(slab->store.num_triangles());
  return n;
}

int TandemSession::num_parts() const { return static_cast<int>(impl_->slabs.size()); }
const SessionStats& TandemSession::stats() const { return impl_->Stats(); }
size_t TandemSession::MemoryBytes() const { return impl_->MemoryBytes(); }
TandemSession::Gauge TandemSession::Peek() const { return impl_->Peek(); }
const VolumeInfo& TandemSession::grid() const { return impl_->grid; }
const SessionOptions& TandemSession::options() const { return impl_->options; }
bool TandemSession::finished() const { return impl_->finished; }

TandemSession::Finishing TandemSession::FinishProgress() const { return impl_->FinishProgress(); }

double TandemSession::MaxShapeError() const {
  Impl& s = *impl_;
  if (s.options.schedule == Schedule::kNone) return 0.0;
  (void)s.Sync();
  double worst = 0.0;
  for (const auto& slab : s.slabs) {
    worst = std::max(worst, slab->simplifier.MaxShapeError());
    if (slab->sealer) worst = std::max(worst, slab->sealer->max_shape_error());
  }
  return worst * s.scale;
}

template <typename F>
absl::Status TandemSession::Impl::Guarded(F&& f) {
  if (failed.ok() && meter.stopped()) failed = meter.status();  // cancelled, or over budget
  if (!failed.ok()) return failed;
  try {
    absl::Status st = f();
    if (!st.ok() && queued) {
      // A queued step's failure leaves its slab mid-step: the session is done for.
      std::lock_guard<std::mutex> lock(mu);
      if (!QueuedFailure().ok()) failed = st;
    }
    return st;
  } catch (...) {
    failed = StatusOfException(std::current_exception());
    return failed;
  }
}

}  // namespace tandem
