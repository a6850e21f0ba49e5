// The pipeline of a split session: each slice is copied once into a ring slot and queued for
// every slab. A slab's steps run one at a time and in order, each step a task that queues the
// slab's next one, so the result does not depend on which thread runs it. The steps
// (TandemSession::Impl::StepQueued, WakeParked) and the sealed shares they cut (CutSealed,
// TakeCuts) are in slab_pipeline.cc.
#ifndef TANDEM_SLAB_PIPELINE_H_
#define TANDEM_SLAB_PIPELINE_H_

#include <deque>
#include <vector>

#include "absl/status/status.h"
#include "layer_extractor.h"
#include "tandem/volume.h"

namespace tandem {

struct RingSlot {
  std::vector<float> storage;  // the slice's bytes (float storage: float32 stays aligned)
  DType dtype = DType::kFloat32;
  int pending = 0;  // slabs that have not finished with it
  SliceValues values() const { return {reinterpret_cast<const uint8_t*>(storage.data()), dtype}; }
};
struct SlabQueue {
  std::deque<int> slices;  // ring slots
  bool busy = false;       // a task of this slab is queued or running
  bool parked = false;     // waiting for the target count's decision (TargetControl)
  absl::Status failure;    // the first failure of a queued step (none expected)
};

}  // namespace tandem

#endif  // TANDEM_SLAB_PIPELINE_H_
