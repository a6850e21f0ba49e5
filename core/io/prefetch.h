// SlicePrefetcher: reads the next slices of a SliceSource on a background thread while the
// caller works on the current one, so disk reads and gzip inflation overlap extraction and
// simplification on another core. Slices stay raw voxels (the source's dtype, host byte
// order): TandemSession::AddSliceBytes converts them straight into its own slice ring, so a
// float slice is copied once between the page cache and the extractor, not three times.
// At most `depth` slices are held ahead; the data and its order are exactly the source's,
// so results are identical to a single-threaded run.
#ifndef TANDEM_PREFETCH_H_
#define TANDEM_PREFETCH_H_

#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "tandem/volume.h"

namespace tandem::io {

class SlicePrefetcher {
 public:
  // `source` must outlive the prefetcher; reading starts at once.
  explicit SlicePrefetcher(SliceSource* source, size_t depth = 2);
  ~SlicePrefetcher();  // stops the thread (a read in progress finishes first)
  SlicePrefetcher(const SlicePrefetcher&) = delete;
  SlicePrefetcher& operator=(const SlicePrefetcher&) = delete;

  // The next slice as the source's raw voxels (swapped into *bytes, as ReadSlice gives
  // them). OutOfRange after the last slice; a read error is returned, in order, and then
  // again on every later call: it ends the stream.
  absl::Status Next(std::vector<uint8_t>* bytes);

 private:
  struct Item {
    absl::Status status;
    std::vector<uint8_t> bytes;
  };
  void Run();

  SliceSource* source_;
  size_t depth_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Item> ready_;         // guarded by mu_
  std::vector<std::vector<uint8_t>> spare_;  // recycled buffers, guarded by mu_
  bool stop_ = false;              // guarded by mu_
  bool done_ = false;              // guarded by mu_: the thread has pushed its last item
  std::thread thread_;
};

}  // namespace tandem::io

#endif  // TANDEM_PREFETCH_H_
