// What tandem_io (dicom_worker_client.cc) and the DICOM reader process (dicom_worker.cc)
// say to each other over their socket. Both are built together, so this is a private
// format: little-endian fixed-size fields and length-prefixed strings.
//   request: u32 size, then u8 op, u64 arg, the path's bytes (size counts from op on)
// and the decoded pixels go through shared memory (fd 4 in the worker), not the socket.
//   reply:   u32 code (absl::StatusCode), u32 message size, u8 retiring (the process exits
//            after this reply), u64 payload size, then the message and the payload
// Header replies carry a SliceHeader (EncodeHeader), pixel replies the stored pixels.
#ifndef TANDEM_IO_DICOM_WIRE_H_
#define TANDEM_IO_DICOM_WIRE_H_

#include <cstdint>
#include <cstring>
#include <optional>
#include <string>

#include "dicom_codec.h"

namespace tandem::io::dicom::wire {

enum Op : uint8_t {
  kHeader = 1,     // arg unused; payload: u8 has_slice, then the SliceHeader
  kPixels = 2,     // arg: the stored bytes expected, written to the shared memory
  kMisbehave = 3,  // tests: arg 1 crash, 2 hang, 3 allocate without bound
};

inline constexpr size_t kRequestFixed = 1 + 8;
inline constexpr size_t kReplyFixed = 4 + 4 + 1 + 8;
inline constexpr int kSocketFd = 3;  // the worker's end of the socket
inline constexpr int kSharedFd = 4;  // a memfd the caller sizes for a slice's pixels

class Writer {
 public:
  void U8(uint8_t v) { out_.push_back(static_cast<char>(v)); }
  void U32(uint32_t v) { Raw(&v, 4); }
  void U64(uint64_t v) { Raw(&v, 8); }
  void F64(double v) { Raw(&v, 8); }
  void Str(const std::string& s) {
    U32(static_cast<uint32_t>(s.size()));
    out_ += s;
  }
  std::string& out() { return out_; }

 private:
  void Raw(const void* p, size_t n) { out_.append(static_cast<const char*>(p), n); }
  std::string out_;
};

// Reads what Writer wrote; any read past the end sets !ok() (and yields zeros).
class Reader {
 public:
  Reader(const char* p, size_t n) : p_(p), n_(n) {}
  uint8_t U8() { return Get<uint8_t>(); }
  uint32_t U32() { return Get<uint32_t>(); }
  uint64_t U64() { return Get<uint64_t>(); }
  double F64() { return Get<double>(); }
  std::string Str() {
    const uint32_t n = U32();
    if (n > n_) {
      ok_ = false;
      return "";
    }
    std::string s(p_, n);
    p_ += n;
    n_ -= n;
    return s;
  }
  bool ok() const { return ok_ && n_ == 0; }

 private:
  template <typename T>
  T Get() {
    T v{};
    Raw(&v, sizeof v);
    return v;
  }
  void Raw(void* dst, size_t n) {
    if (n > n_) {
      ok_ = false;
      n_ = 0;
      return;
    }
    std::memcpy(dst, p_, n);
    p_ += n;
    n_ -= n;
  }
  const char* p_;
  size_t n_;
  bool ok_ = true;
};

inline void EncodeHeader(const std::optional<SliceHeader>& h, Writer* w) {
  w->U8(h.has_value());
  if (!h) return;
  w->Str(h->path);
  w->Str(h->series_uid);
  for (double v : h->position) w->F64(v);
  for (double v : h->orientation) w->F64(v);
  w->U64(static_cast<uint64_t>(h->rows));
  w->U64(static_cast<uint64_t>(h->cols));
  w->F64(h->row_spacing);
  w->F64(h->col_spacing);
  w->U8(h->has_spacing);
  for (int v : {h->bits_allocated, h->bits_stored, h->pixel_representation, h->samples}) {
    w->U64(static_cast<uint64_t>(static_cast<int64_t>(v)));
  }
  w->U64(static_cast<uint64_t>(h->frames));
  w->F64(h->slope);
  w->F64(h->intercept);
  w->Str(h->modality);
  w->Str(h->description);
  w->Str(h->image_type);
  w->U64(static_cast<uint64_t>(h->instance));
}

// False when the bytes are not a whole header as EncodeHeader writes it.
inline bool DecodeHeader(Reader* r, std::optional<SliceHeader>* out) {
  if (r->U8() == 0) {
    out->reset();
    return r->ok();
  }
  SliceHeader h;
  h.path = r->Str();
  h.series_uid = r->Str();
  for (double& v : h.position) v = r->F64();
  for (double& v : h.orientation) v = r->F64();
  h.rows = static_cast<int64_t>(r->U64());
  h.cols = static_cast<int64_t>(r->U64());
  h.row_spacing = r->F64();
  h.col_spacing = r->F64();
  h.has_spacing = r->U8() != 0;
  for (int* v : {&h.bits_allocated, &h.bits_stored, &h.pixel_representation, &h.samples}) {
    *v = static_cast<int>(static_cast<int64_t>(r->U64()));
  }
  h.frames = static_cast<int64_t>(r->U64());
  h.slope = r->F64();
  h.intercept = r->F64();
  h.modality = r->Str();
  h.description = r->Str();
  h.image_type = r->Str();
  h.instance = static_cast<int64_t>(r->U64());
  *out = std::move(h);
  return r->ok();
}

}  // namespace tandem::io::dicom::wire

#endif  // TANDEM_IO_DICOM_WIRE_H_
