#include "dicom_scan.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace tandem::io::dicom {
namespace {

constexpr uint64_t kUndefined = 0xffffffffu;
constexpr uint64_t kNoEnd = std::numeric_limits<uint64_t>::max();

// A forward stream of the data set's bytes with a small look-ahead buffer: the file itself,
// or its deflated data set inflated on the way.
class Source {
 public:
  virtual ~Source() = default;
  // Makes n bytes available at Data() (n <= kBuffer); false when the stream ends first.
  bool Fill(size_t n) {
    if (tail_ - head_ >= n) return true;
    std::memmove(buf_, buf_ + head_, tail_ - head_);
    tail_ -= head_;
    head_ = 0;
    while (tail_ < n) {
      const size_t got = Produce(buf_ + tail_, sizeof(buf_) - tail_);
      if (got == 0) return false;
      tail_ += got;
    }
    return true;
  }
  const uint8_t* Data() const { return buf_ + head_; }
  void Consume(size_t n) {
    head_ += n;
    pos_ += n;
  }
  // Skips n bytes; false when the stream ends first.
  bool Skip(uint64_t n) {
    const uint64_t here = std::min<uint64_t>(n, tail_ - head_);
    Consume(static_cast<size_t>(here));
    n -= here;
    const uint64_t jumped = Jump(n);
    pos_ += jumped;
    return jumped == n;
  }
  uint64_t pos() const { return pos_; }
  // Bytes left after pos(), or kNoEnd when not known before reading them (inflated).
  virtual uint64_t Left() const = 0;
  // Why the stream ended early, when it was not simply the end ("" otherwise).
  virtual std::string Failure() const { return ""; }

  static constexpr size_t kBuffer = 64 * 1024;

 protected:
  virtual size_t Produce(uint8_t* dst, size_t cap) = 0;  // 0 at the end
  virtual uint64_t Jump(uint64_t n) = 0;                 // past the buffer; bytes skipped
  size_t buffered() const { return tail_ - head_; }

 private:
  uint8_t buf_[kBuffer];
  size_t head_ = 0, tail_ = 0;
  uint64_t pos_ = 0;
};

class FileSource final : public Source {
 public:
  FileSource(int fd, uint64_t start, uint64_t size) : fd_(fd), next_(start), size_(size) {}
  uint64_t Left() const override { return size_ - next_ + buffered(); }

 private:
  size_t Produce(uint8_t* dst, size_t cap) override {
    const size_t want = static_cast<size_t>(std::min<uint64_t>(cap, size_ - next_));
    if (want == 0) return 0;
    ssize_t got;
    do {
      got = ::pread(fd_, dst, want, static_cast<off_t>(next_));
    } while (got < 0 && errno == EINTR);
    if (got <= 0) {
      size_ = next_;  // an I/O error or a file that shrank: the stream ends here
      return 0;
    }
    next_ += static_cast<uint64_t>(got);
    return static_cast<size_t>(got);
  }
  uint64_t Jump(uint64_t n) override {
    const uint64_t jumped = std::min(n, size_ - next_);
    next_ += jumped;
    return jumped;
  }

  int fd_;
  uint64_t next_, size_;
};

// The raw deflate stream of a Deflated Explicit VR Little Endian data set, inflated up to a
// cap (a few KB can claim gigabytes).
class InflateSource final : public Source {
 public:
  InflateSource(int fd, uint64_t start, uint64_t size, uint64_t cap)
      : file_(fd, start, size), cap_(cap) {
    started_ = ok_ = inflateInit2(&zs_, -MAX_WBITS) == Z_OK;
    if (!ok_) failure_ = "cannot start the zlib decoder";
  }
  ~InflateSource() override {
    if (started_) inflateEnd(&zs_);
  }
  uint64_t Left() const override { return kNoEnd; }
  std::string Failure() const override { return failure_; }

 private:
  size_t Produce(uint8_t* dst, size_t cap) override {
    if (!ok_ || done_) return 0;
    if (produced_ >= cap_) {
      failure_ = absl::StrCat("its deflated data set inflates to more than ", cap_, " bytes");
      ok_ = false;
      return 0;
    }
    cap = static_cast<size_t>(std::min<uint64_t>(cap, cap_ - produced_));
    zs_.next_out = dst;
    zs_.avail_out = static_cast<uInt>(cap);
    while (zs_.avail_out == cap) {
      if (zs_.avail_in == 0) {
        if (!file_.Fill(1)) {
          done_ = true;
          break;
        }
        const size_t n = std::min<size_t>(Source::kBuffer, file_.Left());
        file_.Fill(n);
        in_.assign(file_.Data(), file_.Data() + n);
        file_.Consume(n);
        zs_.next_in = in_.data();
        zs_.avail_in = static_cast<uInt>(in_.size());
      }
      const int rc = inflate(&zs_, Z_NO_FLUSH);
      if (rc == Z_STREAM_END) {
        done_ = true;
        break;
      }
      if ((rc != Z_OK && rc != Z_BUF_ERROR) || (rc == Z_BUF_ERROR && zs_.avail_in > 0)) {
        failure_ = "its deflated data set is corrupt";
        ok_ = false;
        break;
      }
    }
    const size_t got = cap - zs_.avail_out;
    produced_ += got;
    return got;
  }
  uint64_t Jump(uint64_t n) override {
    uint8_t scratch[4096];
    uint64_t done = 0;
    while (done < n) {
      const size_t got =
          Produce(scratch, static_cast<size_t>(std::min<uint64_t>(sizeof scratch, n - done)));
      if (got == 0) break;
      done += got;
    }
    return done;
  }

  FileSource file_;
  uint64_t cap_;
  z_stream zs_{};
  std::vector<uint8_t> in_;
  uint64_t produced_ = 0;
  bool started_ = false, ok_ = false, done_ = false;
  std::string failure_;
};

bool IsVr(const uint8_t* p) {
  static const char* const kVrs[] = {"AE", "AS", "AT", "CS", "DA", "DS", "DT", "FL", "FD",
                                     "IS", "LO", "LT", "OB", "OD", "OF", "OL", "OV", "OW",
                                     "PN", "SH", "SL", "SQ", "SS", "ST", "SV", "TM", "UC",
                                     "UI", "UL", "UN", "UR", "US", "UT", "UV"};
  for (const char* v : kVrs) {
    if (p[0] == v[0] && p[1] == v[1]) return true;
  }
  return false;
}

// VRs whose length is 4 bytes after 2 reserved ones (PS3.5 7.1.2).
bool LongVr(const uint8_t* p) {
  static const char* const kLong[] = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ",
                                      "SV", "UC", "UN", "UR", "UT", "UV"};
  for (const char* v : kLong) {
    if (p[0] == v[0] && p[1] == v[1]) return true;
  }
  return false;
}

struct Syntax {
  bool is_explicit = true;
  bool big_endian = false;
  bool deflated = false;
  bool rle = false;  // RLE Lossless: each fragment of the pixel data starts with an RLE header
};

uint16_t U16(const uint8_t* p, bool big) {
  return big ? static_cast<uint16_t>(p[0] << 8 | p[1]) : static_cast<uint16_t>(p[1] << 8 | p[0]);
}
uint32_t U32(const uint8_t* p, bool big) {
  return big ? uint32_t{p[0]} << 24 | uint32_t{p[1]} << 16 | uint32_t{p[2]} << 8 | p[3]
             : uint32_t{p[3]} << 24 | uint32_t{p[2]} << 16 | uint32_t{p[1]} << 8 | p[0];
}

std::string TagText(uint16_t g, uint16_t e) { return absl::StrFormat("(%04X,%04X)", g, e); }

// The outcome of one walk: within the limits, refused (a status), or a stream the walk
// cannot follow under the syntax it assumed (`lost`: GDCM gets it).
struct Walk {
  absl::Status status;
  bool lost = false;
  bool bad_vr = false;  // lost at an explicit element whose VR is not one
};

class Walker {
 public:
  Walker(const std::string& path, const ScanLimits& limits, Source* src, uint64_t base)
      : path_(path), limits_(limits), src_(*src), base_(base) {}

  int64_t pixel_bytes() const { return pixel_bytes_; }

  Walk Run(const Syntax& syntax) {
    stack_.push_back({Kind::kDataSet, kNoEnd, !syntax.is_explicit});
    big_ = syntax.big_endian;
    rle_ = syntax.rle;
    while (true) {
      Frame& f = stack_.back();
      if (f.end != kNoEnd && src_.pos() >= f.end) {
        if (src_.pos() > f.end) return Lost();  // an element overran its item or sequence
        if (f.kind == Kind::kSequence) --depth_;
        stack_.pop_back();
        continue;
      }
      if (!src_.Fill(8)) {
        if (!src_.Failure().empty()) return Refuse(absl::DataLossError(Msg(src_.Failure())));
        if (src_.Fill(1)) return Lost();  // a few stray bytes at the end
        if (stack_.size() > 1) {
          return Refuse(absl::DataLossError(
              Msg("truncated: the file ends inside a sequence (still being written, or cut "
                  "short?)")));
        }
        return {};
      }
      if (++elements_ > limits_.max_elements) {
        return Refuse(absl::InvalidArgumentError(Msg(absl::StrCat(
            "more than ", limits_.max_elements,
            " data elements (a slice holds a few thousand); refused before parsing"))));
      }
      const uint8_t* p = src_.Data();
      const uint16_t g = U16(p, big_), e = U16(p + 2, big_);
      const uint64_t at = base_ + src_.pos();
      if (g == 0xfffe) {  // items and delimiters: a tag and a 4-byte length, never a VR
        const uint64_t len = U32(p + 4, big_);
        src_.Consume(8);
        if (Walk w = Delimiter(e, len, at); w.lost || !w.status.ok()) return w;
        continue;
      }
      if (f.kind != Kind::kDataSet) return Lost();  // a sequence holds only items
      uint64_t len;
      bool sequence, un = false;
      if (f.implicit) {
        len = U32(p + 4, big_);
        src_.Consume(8);
        sequence = len == kUndefined;
      } else {
        if (!IsVr(p + 4)) return {absl::OkStatus(), true, true};
        un = p[4] == 'U' && p[5] == 'N';
        sequence = (p[4] == 'S' && p[5] == 'Q') || un;
        if (LongVr(p + 4)) {
          if (!src_.Fill(12)) return Truncated(at, 12);
          len = U32(src_.Data() + 8, big_);
          src_.Consume(12);
        } else {
          len = U16(p + 6, big_);
          src_.Consume(8);
        }
        if (len == kUndefined && !sequence) {  // encapsulated data: fragments, no data sets
          if (Walk w = Push(Kind::kFragments, kNoEnd, f.implicit); w.lost || !w.status.ok()) {
            return w;
          }
          continue;
        }
        if (un && len == kUndefined) {  // PS3.5 6.2.2: an implicit VR sequence inside
          if (Walk w = Push(Kind::kSequence, kNoEnd, true, at); w.lost || !w.status.ok()) {
            return w;
          }
          continue;
        }
      }
      if (len == kUndefined) {
        const bool pixels = g == 0x7fe0 && e == 0x0010;
        if (Walk w = Push(pixels ? Kind::kFragments : Kind::kSequence, kNoEnd, f.implicit, at);
            w.lost || !w.status.ok()) {
          return w;
        }
        continue;
      }
      if (Walk w = Fits(g, e, len, at); w.lost || !w.status.ok()) return w;
      if (g == 0x7fe0 && e == 0x0010 && stack_.size() == 1)
        pixel_bytes_ = static_cast<int64_t>(len);
      // A defined-length value that starts with an item is parsed as a sequence by GDCM
      // (an implicit VR SQ found by its dictionary, or an explicit UN holding one).
      if (!sequence && (f.implicit || un) && len >= 8 && src_.Fill(4) &&
          U16(src_.Data(), big_) == 0xfffe && U16(src_.Data() + 2, big_) == 0xe000) {
        sequence = true;
      }
      if (sequence) {
        if (Walk w = Push(Kind::kSequence, src_.pos() + len, f.implicit || un, at);
            w.lost || !w.status.ok()) {
          return w;
        }
        continue;
      }
      if (!src_.Skip(len)) return Truncated(at, len);
    }
  }

 private:
  enum class Kind { kDataSet, kSequence, kFragments };
  struct Frame {
    Kind kind;
    uint64_t end;  // stream position where it ends, kNoEnd when delimited
    bool implicit;
    uint64_t items = 0;  // items read so far
  };

  Walk Delimiter(uint16_t e, uint64_t len, uint64_t at) {
    const Frame f = stack_.back();
    if (e == 0xe000 && f.kind == Kind::kSequence) {  // an item: a data set
      if (len == kUndefined) return Push(Kind::kDataSet, kNoEnd, f.implicit);
      if (Walk w = Fits(0xfffe, e, len, at); w.lost || !w.status.ok()) return w;
      return Push(Kind::kDataSet, src_.pos() + len, f.implicit);
    }
    if (e == 0xe000 && f.kind == Kind::kFragments) {  // a fragment: bytes
      if (len == kUndefined) return Lost();
      if (Walk w = Fits(0xfffe, e, len, at); w.lost || !w.status.ok()) return w;
      // The image's fragments (after the offset table) under RLE: GDCM decodes the first one
      // while it reads the file, trusting its header.
      if (rle_ && stack_.size() == 2 && stack_.back().items++ > 0) {
        if (absl::Status st = CheckRleHeader(len, stack_.back().items - 1); !st.ok()) {
          return Refuse(st);
        }
      }
      if (!src_.Skip(len)) return Truncated(at, len);
      return {};
    }
    if (e == 0xe00d && f.kind == Kind::kDataSet && stack_.size() > 1) {  // end of an item
      stack_.pop_back();
      return {};
    }
    if (e == 0xe0dd && f.kind != Kind::kDataSet) {  // end of a sequence or of fragments
      if (f.kind == Kind::kSequence) --depth_;
      stack_.pop_back();
      return {};
    }
    if (e == 0xe0dd && f.kind == Kind::kDataSet && stack_.size() > 2) {  // item left open
      stack_.pop_back();
      --depth_;
      stack_.pop_back();
      return {};
    }
    return Lost();
  }

  // PS3.5 G.5: a 64-byte header of 16 little-endian u32, the number of segments (1..15)
  // and their offsets, the first 64, each after the last, inside the fragment.
  absl::Status CheckRleHeader(uint64_t len, uint64_t fragment) {
    auto bad = [&](const std::string& what) {
      return absl::DataLossError(
          Msg(absl::StrCat("corrupt RLE pixel data: fragment ", fragment, " ", what)));
    };
    if (len < 64 || !src_.Fill(64)) {
      return bad(absl::StrCat("of ", len, " bytes has no 64-byte RLE header"));
    }
    const uint8_t* p = src_.Data();
    const uint32_t n = U32(p, false);
    if (n < 1 || n > 15) return bad(absl::StrCat("declares ", n, " segments (1..15)"));
    for (uint32_t k = 1; k <= n; ++k) {
      const uint32_t at = U32(p + 4 * k, false), lo = k == 1 ? 63 : U32(p + 4 * (k - 1), false);
      if (at <= lo || at >= len || (k == 1 && at != 64)) {
        return bad(absl::StrCat("puts segment ", k, " at byte ", at, " of ", len,
                                " (the first at 64, each after the last, inside the fragment)"));
      }
    }
    return absl::OkStatus();
  }

  Walk Push(Kind kind, uint64_t end, bool implicit, uint64_t at = 0) {
    if (kind == Kind::kSequence && ++depth_ > limits_.max_depth) {
      return Refuse(absl::InvalidArgumentError(Msg(absl::StrCat(
          "sequences nested more than ", limits_.max_depth, " deep (at byte ", at,
          "; images nest a few); refused before parsing, as such nesting can exhaust the "
          "DICOM parser's stack"))));
    }
    stack_.push_back({kind, end, implicit});
    return {};
  }

  // A defined length must fit in the file (else the file is cut short: GDCM would allocate
  // the length and pad) and in the item or sequence holding it (else the stream is one GDCM
  // may read its own way: left to it).
  Walk Fits(uint16_t g, uint16_t e, uint64_t len, uint64_t at) {
    if (len > src_.Left()) {
      return Refuse(absl::DataLossError(Msg(absl::StrCat(
          "truncated: element ", TagText(g, e), " at byte ", at, " declares ", len, " bytes, only ",
          src_.Left(), " follow (still being written, or cut short?)"))));
    }
    for (const Frame& f : stack_) {
      if (f.end != kNoEnd && len > f.end - std::min(f.end, src_.pos())) return Lost();
    }
    return {};
  }

  Walk Truncated(uint64_t at, uint64_t len) {
    if (!src_.Failure().empty()) return Refuse(absl::DataLossError(Msg(src_.Failure())));
    return Refuse(absl::DataLossError(
        Msg(absl::StrCat("truncated: the value at byte ", at, " declares ", len,
                         " bytes and the file ends first (still being written, or cut short?)"))));
  }

  std::string Msg(const std::string& what) const { return absl::StrCat(path_, ": ", what); }
  static Walk Refuse(absl::Status st) { return {std::move(st), false}; }
  static Walk Lost() { return {absl::OkStatus(), true}; }

  const std::string& path_;
  const ScanLimits& limits_;
  Source& src_;
  uint64_t base_;  // file offset of the stream's first byte (for messages)
  bool big_ = false, rle_ = false;
  std::vector<Frame> stack_;
  int depth_ = 0;
  uint64_t elements_ = 0;
  int64_t pixel_bytes_ = -1;
};

// The file meta information (explicit VR little endian, group 0002) from `start`: the data
// set's transfer syntax and where the data set begins.
struct Meta {
  Syntax syntax;
  uint64_t data_set = 0;
  bool known = false;  // a transfer syntax was found
};

Meta ReadMeta(int fd, uint64_t size, uint64_t start) {
  Meta m;
  auto owned = std::make_unique<FileSource>(fd, start, size);
  FileSource& src = *owned;
  std::string uid;
  while (src.Fill(8) && U16(src.Data(), false) == 0x0002) {
    const uint8_t* p = src.Data();
    const uint16_t e = U16(p + 2, false);
    uint64_t len;
    if (IsVr(p + 4) && LongVr(p + 4)) {
      if (!src.Fill(12)) break;
      len = U32(src.Data() + 8, false);
      src.Consume(12);
    } else if (IsVr(p + 4)) {
      len = U16(p + 6, false);
      src.Consume(8);
    } else {
      len = U32(p + 4, false);
      src.Consume(8);
    }
    if (e == 0x0010 && len <= 256 && src.Fill(static_cast<size_t>(len))) {
      uid.assign(reinterpret_cast<const char*>(src.Data()), static_cast<size_t>(len));
      while (!uid.empty() && (uid.back() == '\0' || uid.back() == ' ')) uid.pop_back();
      m.known = true;
    }
    if (len == kUndefined || !src.Skip(len)) break;
  }
  m.data_set = start + src.pos();
  if (m.known) {
    m.syntax.is_explicit = uid != "1.2.840.10008.1.2";
    m.syntax.big_endian = uid == "1.2.840.10008.1.2.2";
    m.syntax.deflated = uid == "1.2.840.10008.1.2.1.99";
    m.syntax.rle = uid == "1.2.840.10008.1.2.5";
  }
  return m;
}

}  // namespace

absl::Status ScanFile(const std::string& path, const ScanLimits& limits, ScanResult* result) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    return absl::NotFoundError(absl::StrCat(path, ": cannot open: ", std::strerror(errno)));
  }
  struct stat st;
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    return absl::InvalidArgumentError(absl::StrCat(path, ": not a regular file"));
  }
  const uint64_t size = static_cast<uint64_t>(st.st_size);
  // The preamble and "DICM", else a meta group or a bare data set from the first byte.
  uint64_t start = 0;
  uint8_t head[132];
  if (size >= 132 && ::pread(fd, head, 132, 0) == 132 && std::memcmp(head + 128, "DICM", 4) == 0) {
    start = 132;
  }
  Meta meta = ReadMeta(fd, size, start);
  if (!meta.known) {  // no transfer syntax: GDCM guesses from the first element, so do we
    uint8_t first[6];
    meta.syntax.is_explicit =
        ::pread(fd, first, 6, static_cast<off_t>(meta.data_set)) == 6 && IsVr(first + 4);
  }
  auto walk = [&](const Syntax& syntax) {
    std::unique_ptr<Source> src;
    if (syntax.deflated) {
      src = std::make_unique<InflateSource>(fd, meta.data_set, size, limits.max_inflated);
    } else {
      src = std::make_unique<FileSource>(fd, meta.data_set, size);
    }
    Walker walker(path, limits, src.get(), syntax.deflated ? 0 : meta.data_set);
    Walk w = walker.Run(syntax);
    if (result != nullptr && !w.lost) result->pixel_bytes = walker.pixel_bytes();
    return w;
  };
  Walk w = walk(meta.syntax);
  // GDCM reads a data set whose "explicit" elements carry no VR as implicit: so does this.
  if (w.bad_vr) {
    Syntax implicit = meta.syntax;
    implicit.is_explicit = false;
    w = walk(implicit);
  }
  ::close(fd);
  return w.status;
}

}  // namespace tandem::io::dicom
