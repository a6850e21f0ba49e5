// The pipeline of a split session (slab_pipeline.h): slices copied once into a ring and
// queued for every slab, each slab stepped by one task at a time, and the shares of the
// sealed mesh each step cuts.
#include "slab_pipeline.h"

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <limits>
#include <mutex>

#include "session_impl.h"
#include "tandem/status_macros.h"

namespace tandem {
namespace {

// What a sealed chunk's arrays take.
size_t ChunkBytes(const SealedChunk& c) {
  return c.positions.capacity() * sizeof(Vec3) +
         (c.ids.capacity() + c.indices.capacity() + c.retired.capacity() + c.patch.capacity()) *
             sizeof(uint32_t) +
         c.pairs.capacity() * sizeof(LabelPair);
}

// Copies n values to dst and says whether all are finite (volume.h's rule), in one pass
// that the compiler vectorises.
bool CopyFinite(const float* src, size_t n, float* dst) {
  uint32_t bad = 0;
  for (size_t i = 0; i < n; ++i) {
    uint32_t bits;
    std::memcpy(&bits, src + i, sizeof bits);
    std::memcpy(dst + i, &bits, sizeof bits);
    bad |= static_cast<uint32_t>(NonFiniteBits(bits));
  }
  return bad == 0;
}

}  // namespace

bool TandemSession::Impl::JoinTaken(std::vector<SealedChunk> pieces, SealedChunk* out) {
  std::erase_if(pieces,
                [](const SealedChunk& p) { return p.indices.empty() && p.retired.empty(); });
  if (pieces.empty()) return false;
  *out = JoinChunks(std::move(pieces));
  out->index = chunks_taken++;
  if (cuts.size() > 1) {  // a settled seam vertex's id is retired with its second copy
    const uint32_t stride = SealerIdStride(static_cast<int>(cuts.size()));
    const auto seam = static_cast<uint32_t>(cuts.size());
    std::erase_if(out->retired, [&](uint32_t id) {
      return id % stride == seam && half_retired.insert(id).second;
    });
    for (uint32_t id : out->retired) {
      if (id % stride == seam) half_retired.erase(id);
    }
  }
  ToWorld(&out->positions, &out->indices);
  return true;
}

void TandemSession::Impl::CutSealed(Slab& slab) {
  if (slab.sealer == nullptr) return;
  SealedChunk piece;  // empty if nothing was sealed: every step has its share
  slab.sealer->TakeChunk(&piece);
  const size_t bytes = ChunkBytes(piece);
  std::lock_guard<std::mutex> lock(mu);
  cuts[static_cast<size_t>(slab.index)].push_back(std::move(piece));
  cut_bytes += bytes;
  cut_account.Hold(cut_bytes, "sealing slice", slab.extractor.slices_done() - 1);
}

int64_t TandemSession::Impl::CutThrough() const {
  size_t n = std::numeric_limits<size_t>::max();
  for (const auto& c : cuts) n = std::min(n, c.size());
  return cuts.empty() ? -1 : cut_taken + static_cast<int64_t>(n) - 1;
}

void TandemSession::Impl::TakeCuts(int64_t through, std::vector<SealedChunk>* pieces) {
  for (; cut_taken <= through; ++cut_taken) {
    for (auto& c : cuts) {
      cut_bytes -= std::min(cut_bytes, ChunkBytes(c.front()));
      pieces->push_back(std::move(c.front()));
      c.pop_front();
    }
  }
  cut_account.Set(cut_bytes);  // (the caller's copy of them is its own to count)
}

int64_t TandemSession::Impl::CutTriangles(int64_t through) const {
  int64_t n = 0;
  for (const auto& c : cuts) {
    for (int64_t k = cut_taken; k <= through; ++k) {
      n += static_cast<int64_t>(c[static_cast<size_t>(k - cut_taken)].num_triangles());
    }
  }
  return n;
}

absl::Status TandemSession::Impl::QueueSlice(const float* values, DType dtype,
                                             const uint8_t* bytes) {
  TANDEM_RETURN_IF_ERROR(CheckSliceIndex());
  const int64_t k = slices_added;
  const size_t n = static_cast<size_t>(grid.nx * grid.ny);
  MaybeSettleSeams();
  {
    std::lock_guard<std::mutex> lock(mu);
    TANDEM_RETURN_IF_ERROR(QueuedFailure());
  }
  RingSlot& slot = ring[static_cast<size_t>(ring_next)];
  steps->WaitUntil(
      [&] {
        std::lock_guard<std::mutex> lock(mu);
        return slot.pending == 0 || meter.stopped();
      },
      /*help=*/false);
  if (meter.stopped()) return meter.status();  // its steps are dropped with it
  // The slot is free (pending == 0) until it is queued: a refused slice leaves it so. A slice
  // is refused before any slab moves: its values are checked while copied.
  const DType kept = values != nullptr ? DType::kFloat32 : dtype;
  const size_t size = n * DTypeSize(kept);
  slot.storage.resize((size + sizeof(float) - 1) / sizeof(float));
  slot.dtype = kept;
  auto* dst = reinterpret_cast<uint8_t*>(slot.storage.data());
  if (values != nullptr) {
    if (!CopyFinite(values, n, slot.storage.data())) return NonFiniteError(values);
  } else {
    std::memcpy(dst, bytes, size);
    if (kept == DType::kFloat32 && FirstNonFinite(dst, n) >= 0) {
      return NonFiniteError(slot.storage.data());
    }
    TANDEM_RETURN_IF_ERROR(CheckLabels(dst, kept));
  }
  buffers.Hold(BufferBytes(), "receiving slice", k);
  std::vector<size_t> idle;
  {
    std::lock_guard<std::mutex> lock(mu);
    slot.pending = static_cast<int>(slabs.size());
    for (size_t i = 0; i < slabs.size(); ++i) {
      queues[i].slices.push_back(ring_next);
      if (!queues[i].busy) {
        queues[i].busy = true;
        idle.push_back(i);
      }
    }
  }
  for (size_t i : idle) steps->Run([this, i] { StepQueued(i); });
  ring_next = (ring_next + 1) % kRingSlots;
  ++slices_added;
  return absl::OkStatus();
}

absl::Status TandemSession::Impl::QueuedFailure() {
  for (const SlabQueue& q : queues) {
    if (!q.failure.ok()) return q.failure;
  }
  return absl::OkStatus();
}

void TandemSession::Impl::StepQueued(size_t i) {
  SlabQueue& q = queues[i];
  Slab& slab = *slabs[i];
  int slot;
  bool skip;
  {
    std::lock_guard<std::mutex> lock(mu);
    if (q.slices.empty()) {  // dropped by ~Impl
      q.busy = false;
      return;
    }
    // A step that needs a target decision not made yet waits, off the threads, until the
    // last slab's report makes it (WakeParked; asked under mu, so no wake is missed).
    if (slab.target && slab.simplify_pending && q.failure.ok() &&
        !slab.target->Ready(slab.pending_front)) {
      q.busy = false;
      q.parked = true;
      return;
    }
    slot = q.slices.front();
    q.slices.pop_front();
    // A slab that failed is left as it is: its slices are dropped; so are a stopped
    // session's, at once.
    if (q.failure.ok() && meter.stopped()) q.failure = meter.status();
    skip = !q.failure.ok();
  }
  // ring[slot] is not written while a slab still needs it (pending > 0).
  absl::Status st;
  try {
    if (!skip) {
      st = StepSlab(slab, ring[static_cast<size_t>(slot)].values().From(slab.x0), options.schedule,
                    overlap);
    }
    CutSealed(slab);  // a share for every step, so that the shares stay in step with slices
  } catch (...) {     // this slab is done for; Sync and AddSlice report it
    st = StatusOfException(std::current_exception());
  }
  const SlabGauge gauge = Measure(slab);
  bool more;
  {
    std::lock_guard<std::mutex> lock(mu);
    gauges[i] = gauge;
    --ring[static_cast<size_t>(slot)].pending;
    if (!st.ok() && q.failure.ok()) q.failure = std::move(st);
    more = !q.slices.empty();
    if (!more) q.busy = false;
  }
  if (more) steps->Run([this, i] { StepQueued(i); });  // the slab's next step, after this one
}

void TandemSession::Impl::WakeParked() {
  if (!queued) return;  // slabs stepped together never wait
  std::vector<size_t> wake;
  {
    std::lock_guard<std::mutex> lock(mu);
    for (size_t i = 0; i < queues.size(); ++i) {
      SlabQueue& q = queues[i];
      if (q.parked && !q.busy) {
        q.parked = false;
        q.busy = true;
        wake.push_back(i);
      }
    }
  }
  for (size_t i : wake) steps->Run([this, i] { StepQueued(i); });
}

}  // namespace tandem
