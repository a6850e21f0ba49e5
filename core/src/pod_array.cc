#include "pod_array.h"

#include <cstddef>
#include <cstring>
#include <new>

#include "pod_array_config.h"
#if TANDEM_POD_MAP
#include <sys/mman.h>
#endif

namespace tandem {
namespace {

#if TANDEM_POD_MAP
constexpr size_t kPage = 4096;
size_t MapLength(size_t bytes) { return (bytes + kPage - 1) / kPage * kPage; }
bool Mapped(size_t bytes) { return bytes >= kPodMapBytes; }
#endif

// Heap blocks come from operator new, as a std::vector's do: a program that replaces it
// (the failure injection of session_barrier_test) sees these allocations too.
void* HeapBlock(size_t bytes, size_t align) {
  return align <= __STDCPP_DEFAULT_NEW_ALIGNMENT__ ? ::operator new(bytes)
                                                   : ::operator new(bytes, std::align_val_t(align));
}
void FreeHeapBlock(void* block, size_t align) {
  if (block == nullptr) return;
  if (align <= __STDCPP_DEFAULT_NEW_ALIGNMENT__) {
    ::operator delete(block);
  } else {
    ::operator delete(block, std::align_val_t(align));
  }
}

}  // namespace

void* ResizePodBlock(void* block, size_t old_bytes, size_t new_bytes, size_t align) {
  if (block == nullptr) old_bytes = 0;
  if (old_bytes == new_bytes) return block;
#if TANDEM_POD_MAP
  if (Mapped(old_bytes) && Mapped(new_bytes)) {
    // The pages move (or the mapping grows where it is): nothing is copied or faulted.
    if (MapLength(old_bytes) == MapLength(new_bytes)) return block;
    void* p = mremap(block, MapLength(old_bytes), MapLength(new_bytes), MREMAP_MAYMOVE);
    if (p == MAP_FAILED) throw std::bad_alloc();
    return p;
  }
  void* p = nullptr;
  if (Mapped(new_bytes)) {
    p = mmap(nullptr, MapLength(new_bytes), PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS,
             -1, 0);
    if (p == MAP_FAILED) throw std::bad_alloc();
  } else if (new_bytes > 0) {
    p = HeapBlock(new_bytes, align);
  }
  const size_t keep = old_bytes < new_bytes ? old_bytes : new_bytes;
  if (keep > 0) std::memcpy(p, block, keep);
  if (Mapped(old_bytes)) {
    munmap(block, MapLength(old_bytes));
  } else {
    FreeHeapBlock(block, align);
  }
  return p;
#else
  void* p = new_bytes > 0 ? HeapBlock(new_bytes, align) : nullptr;
  const size_t keep = old_bytes < new_bytes ? old_bytes : new_bytes;
  if (keep > 0) std::memcpy(p, block, keep);
  FreeHeapBlock(block, align);
  return p;
#endif
}

}  // namespace tandem
