// Volume basics (dtypes, validation, OpenVolume dispatch) and the helpers every reader
// shares (byte order, plain/gzip streams, the contiguous-data SliceSource).
#include "tandem/volume.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "readers_internal.h"
#include "tandem/series.h"
#include "tandem/zarr.h"
#include "zarr_internal.h"

namespace tandem {

using internal::Sv;

std::string_view DTypeName(DType t) {
  switch (t) {
    case DType::kUInt8:
      return "uint8";
    case DType::kUInt16:
      return "uint16";
    case DType::kInt16:
      return "int16";
    case DType::kFloat32:
      return "float32";
  }
  return "unknown";
}

absl::StatusOr<DType> ParseDType(std::string_view name) {
  for (DType t : {DType::kUInt8, DType::kUInt16, DType::kInt16, DType::kFloat32}) {
    if (name == DTypeName(t)) return t;
  }
  return absl::InvalidArgumentError(absl::StrCat("unsupported dtype '", Sv(name),
                                                 "' (supported: uint8, uint16, int16, float32)"));
}

size_t DTypeSize(DType t) {
  switch (t) {
    case DType::kUInt8:
      return 1;
    case DType::kUInt16:
    case DType::kInt16:
      return 2;
    case DType::kFloat32:
      return 4;
  }
  return 1;
}

absl::Status ValidateVolumeInfo(const VolumeInfo& info) {
  // Each axis is bounded so that nx*ny*nz*4 cannot overflow int64 / size_t.
  constexpr int64_t kMaxAxis = int64_t{1} << 20;
  const int64_t dims[3] = {info.nx, info.ny, info.nz};
  const char* names[3] = {"nx", "ny", "nz"};
  for (int a = 0; a < 3; ++a) {
    if (a == 2 && dims[a] == 0) continue;  // nz not known yet
    if (dims[a] < 2) {
      return absl::InvalidArgumentError(absl::StrCat(
          "invalid dimensions: ", names[a], " = ", dims[a], " (need at least 2 samples per axis)"));
    }
    if (dims[a] > kMaxAxis) {
      return absl::InvalidArgumentError(absl::StrCat(
          "invalid dimensions: ", names[a], " = ", dims[a], " (at most ", kMaxAxis, " per axis)"));
    }
  }
  // 2^28 = 16384^2 voxels per slice, beyond any scanner's slice; extraction needs about
  // 40 bytes per slice voxel, so a file declaring more (often a corrupt header) is refused
  // before anything that size is allocated.
  if (info.slice_voxels() > (int64_t{1} << 28)) {
    return absl::InvalidArgumentError(absl::StrCat("slice too large: ", info.nx, "x", info.ny,
                                                   " voxels (at most 2^28 = 16384x16384 per slice)"));
  }
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(info.spacing[a]) || info.spacing[a] <= 0.0) {
      return absl::InvalidArgumentError(absl::StrCat("invalid spacing ", info.spacing[a],
                                                     " on axis ", a, " (must be finite and > 0)"));
    }
    if (!std::isfinite(info.origin[a])) {
      return absl::InvalidArgumentError(
          absl::StrCat("invalid origin ", info.origin[a], " on axis ", a, " (must be finite)"));
    }
  }
  // Ranges past which the numbers are certainly a unit or header error, and the float32
  // vertex positions of every output format could not hold the mesh.
  for (int a = 0; a < 3; ++a) {
    if (info.spacing[a] < kMinSpacing || info.spacing[a] > kMaxSpacing) {
      return absl::InvalidArgumentError(absl::StrCat(
          "invalid spacing ", info.spacing[a], " on axis ", a, " (must lie in [", kMinSpacing,
          ", ", kMaxSpacing, "] physical units per voxel)"));
    }
  }
  const double smallest = std::min({info.spacing[0], info.spacing[1], info.spacing[2]});
  const double largest = std::max({info.spacing[0], info.spacing[1], info.spacing[2]});
  if (largest > kMaxAnisotropy * smallest) {
    return absl::InvalidArgumentError(absl::StrCat(
        "invalid spacing ", info.spacing[0], ", ", info.spacing[1], ", ", info.spacing[2],
        ": a voxel more than ", kMaxAnisotropy,
        " times longer on one axis than on another (check the units of each axis)"));
  }
  for (int a = 0; a < 3; ++a) {
    if (std::abs(info.origin[a]) > kMaxOriginVoxels * info.spacing[a]) {
      return absl::InvalidArgumentError(absl::StrCat(
          "invalid origin ", info.origin[a], " on axis ", a, ": more than ", kMaxOriginVoxels,
          " voxels (of ", info.spacing[a],
          ") from 0, where float32 vertex positions could not resolve a voxel; shift the "
          "origin nearer to the volume"));
    }
  }
  const auto& d = info.directions;
  for (int a = 0; a < 3; ++a) {
    for (int b = a; b < 3; ++b) {
      const double dot = d[a][0] * d[b][0] + d[a][1] * d[b][1] + d[a][2] * d[b][2];
      if (!(std::abs(dot - (a == b ? 1.0 : 0.0)) <= 1e-3)) {
        return absl::InvalidArgumentError(absl::StrCat(
            "invalid directions: the grid axes must be orthonormal unit vectors (axis ", a,
            a == b ? " has length^2 " : absl::StrCat(" . axis ", b, " = "), dot, ")"));
      }
    }
  }
  return absl::OkStatus();
}

namespace {
template <typename T>
void ConvertTyped(const uint8_t* src, size_t n, float* dst) {
  // memcpy: src need not be aligned for T.
  for (size_t i = 0; i < n; ++i) {
    T v;
    std::memcpy(&v, src + i * sizeof(T), sizeof(T));
    dst[i] = static_cast<float>(v);
  }
}
}  // namespace

void ConvertToFloat(DType t, const uint8_t* src, size_t n, float* dst) {
  switch (t) {
    case DType::kUInt8:
      ConvertTyped<uint8_t>(src, n, dst);
      break;
    case DType::kUInt16:
      ConvertTyped<uint16_t>(src, n, dst);
      break;
    case DType::kInt16:
      ConvertTyped<int16_t>(src, n, dst);
      break;
    case DType::kFloat32:
      std::memcpy(dst, src, n * sizeof(float));
      break;
  }
}

absl::Status ValueRangeSource::ReadSlice(std::vector<uint8_t>* bytes) {
  absl::Status st = inner_->ReadSlice(bytes);
  if (st.ok()) Scan(bytes->data());
  return st;
}

absl::Status ValueRangeSource::ViewSlice(const uint8_t** data) {
  absl::Status st = inner_->ViewSlice(data);
  if (st.ok() && *data != nullptr) Scan(*data);
  return st;
}

void ValueRangeSource::Scan(const uint8_t* data) {
  const VolumeInfo& info = inner_->info();
  values_.resize(static_cast<size_t>(info.slice_voxels()));
  ConvertToFloat(info.dtype, data, values_.size(), values_.data());
  float lo = std::numeric_limits<float>::infinity(), hi = -lo;
  for (float v : values_) {
    if (v == v) {  // NaN never; infinities are values too (they stay on one side)
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  }
  if (lo <= hi) {
    if (lo_ > hi_) {
      lo_ = lo;
      hi_ = hi;
    } else {
      lo_ = std::min<double>(lo_, lo);
      hi_ = std::max<double>(hi_, hi);
    }
  }
}

absl::StatusOr<std::unique_ptr<SliceSource>> OpenVolume(const std::string& path) {
  // Zarr stores are directories; "image.zarr#1" picks level 1 (see tandem/zarr.h).
  if (auto [store, selector] = SplitZarrSelector(path); internal::LooksLikeZarr(store)) {
    return OpenZarrVolume(store, ZarrReadOptions{.array = selector});
  }
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    absl::StatusOr<std::vector<std::string>> files = ListSliceFiles(path);
    if (!files.ok()) return files.status();
    if (std::vector<std::string> tiffs = TiffNames(*files); !tiffs.empty()) {
      return OpenTiffSequence(path, tiffs);
    }
    return OpenDicomSeries(path, *files);
  }
  const std::string ext = internal::VolumeExtension(path);
  if (ext == ".json") return internal::OpenRawVolume(path);
  if (ext == ".nrrd" || ext == ".nhdr") return internal::OpenNrrdVolume(path);
  if (ext == ".nii" || ext == ".nii.gz") return internal::OpenNiftiVolume(path);
  if (ext == ".tif" || ext == ".tiff") return internal::OpenTiffVolume(path);
  if (ext == ".hdr" || ext == ".img" || ext == ".hdr.gz" || ext == ".img.gz") {
    return absl::InvalidArgumentError(absl::StrCat(
        path,
        ": NIfTI/Analyze .hdr + .img pairs are not supported; convert to a single-file "
        ".nii or .nii.gz"));
  }
  return absl::InvalidArgumentError(absl::StrCat(
      path, ": unsupported volume format '", ext.empty() ? "(no extension)" : ext,
      "'; supported: .json (raw + JSON sidecar), .nrrd, .nhdr, .nii, .nii.gz, .tif, .tiff, a "
      "Zarr store, or a folder holding a DICOM series or numbered TIFF slices"));
}

namespace {
// Natural order: runs of digits compare by value ("s2" < "s10"), the rest byte by byte.
bool NaturalLess(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    const bool da = absl::ascii_isdigit(static_cast<unsigned char>(a[i]));
    const bool db = absl::ascii_isdigit(static_cast<unsigned char>(b[j]));
    if (da && db) {
      size_t ie = i, je = j;
      while (ie < a.size() && absl::ascii_isdigit(static_cast<unsigned char>(a[ie]))) ++ie;
      while (je < b.size() && absl::ascii_isdigit(static_cast<unsigned char>(b[je]))) ++je;
      size_t is = i, js = j;  // skip leading zeros, then longer = larger
      while (is + 1 < ie && a[is] == '0') ++is;
      while (js + 1 < je && b[js] == '0') ++js;
      if (ie - is != je - js) return ie - is < je - js;
      if (int c = a.compare(is, ie - is, b, js, je - js); c != 0) return c < 0;
      if (ie - i != je - j) return ie - i < je - j;  // "01" before "1" only as a tie-break
      i = ie;
      j = je;
    } else {
      if (a[i] != b[j]) return static_cast<unsigned char>(a[i]) < static_cast<unsigned char>(b[j]);
      ++i;
      ++j;
    }
  }
  return a.size() - i < b.size() - j;
}
}  // namespace

absl::StatusOr<std::vector<std::string>> ListSliceFiles(const std::string& dir) {
  std::error_code ec;
  std::filesystem::directory_iterator it(dir, ec);
  if (ec) {
    const std::string msg = absl::StrCat(dir, ": cannot list the folder: ", ec.message());
    return ec == std::errc::no_such_file_or_directory ? absl::NotFoundError(msg)
                                                      : absl::InvalidArgumentError(msg);
  }
  std::vector<std::string> names;
  for (; it != std::filesystem::directory_iterator(); it.increment(ec)) {
    if (ec) return absl::InternalError(absl::StrCat(dir, ": listing failed: ", ec.message()));
    const std::string name = it->path().filename().string();
    if (name.empty() || name[0] == '.') continue;
    std::error_code fec;
    if (!it->is_regular_file(fec)) continue;
    names.push_back(name);
  }
  std::sort(names.begin(), names.end(), NaturalLess);
  for (std::string& n : names) n = (std::filesystem::path(dir) / n).string();
  return names;
}

std::vector<std::string> TiffNames(const std::vector<std::string>& files) {
  std::vector<std::string> out;
  for (const std::string& f : files) {
    const std::string ext = internal::VolumeExtension(f);
    if (ext == ".tif" || ext == ".tiff") out.push_back(f);
  }
  return out;
}

namespace internal {

void SwapBytesInPlace(uint8_t* data, size_t n, size_t elem_size) {
  if (elem_size < 2) return;
  for (size_t i = 0; i < n; ++i) std::reverse(data + i * elem_size, data + (i + 1) * elem_size);
}

absl::Status ErrnoError(const std::string& path, absl::string_view what) {
  const int err = errno;
  std::string msg = absl::StrCat(path, ": ", what, ": ", std::strerror(err));
  if (err == ENOENT) return absl::NotFoundError(msg);
  if (err == EACCES || err == EPERM) return absl::PermissionDeniedError(msg);
  return absl::InternalError(msg);
}

absl::StatusOr<uint64_t> FileSize(const std::string& path) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) return ErrnoError(path, "cannot open");
  if (S_ISDIR(st.st_mode)) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": is a directory, not a volume file"));
  }
  return static_cast<uint64_t>(st.st_size);
}

absl::StatusOr<uint64_t> NonEmptyFileSize(const std::string& path) {
  absl::StatusOr<uint64_t> size = FileSize(path);
  if (size.ok() && *size == 0) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": empty file (0 bytes)"));
  }
  return size;
}

std::string FormatDouble(double v) {
  char buf[64];
  auto [end, ec] = std::to_chars(buf, buf + sizeof(buf), v);
  return ec == std::errc() ? std::string(buf, end) : std::string("nan");
}

std::string DescribeGrid(const VolumeInfo& info) {
  return absl::StrCat(info.nx, "x", info.ny, "x", info.nz, " ", Sv(DTypeName(info.dtype)));
}

uint64_t VolumeBytes(const VolumeInfo& info) {
  return static_cast<uint64_t>(info.slice_bytes()) * static_cast<uint64_t>(info.nz);
}

absl::Status FetchSlice(const std::string& path, const VolumeInfo& info, const SliceFn& slice_fn,
                        int64_t z, std::vector<uint8_t>* bytes) {
  absl::Status st = slice_fn(z, bytes);
  if (!st.ok()) {
    return absl::Status(st.code(), absl::StrCat(path, ": slice ", z, ": ", st.message()));
  }
  if (bytes->size() != info.slice_bytes()) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": slice ", z, " has ", bytes->size(), " bytes, expected ", info.slice_bytes(), " (",
        info.nx, "x", info.ny, " ", Sv(DTypeName(info.dtype)), ")"));
  }
  return absl::OkStatus();
}

std::string VolumeExtension(const std::string& path) {
  std::string name = absl::AsciiStrToLower(std::filesystem::path(path).filename().string());
  if (name.size() > 3 && name.ends_with(".gz")) {
    std::string inner = std::filesystem::path(name.substr(0, name.size() - 3)).extension();
    return inner + ".gz";
  }
  return std::filesystem::path(name).extension().string();
}

// ---------------------------------------------------------------------------------------
// Byte streams.

absl::Status ByteReader::Skip(uint64_t n) {
  char buf[1 << 14];
  while (n > 0) {
    const size_t want = static_cast<size_t>(std::min<uint64_t>(n, sizeof(buf)));
    absl::StatusOr<size_t> got = Read(buf, want);
    if (!got.ok()) return got.status();
    if (*got == 0) return absl::OutOfRangeError(absl::StrCat(path_, ": data ends early"));
    n -= *got;
  }
  return absl::OkStatus();
}

namespace {

class PlainReader final : public ByteReader {
 public:
  PlainReader(std::string path, FILE* f) : ByteReader(std::move(path), false), f_(f) {}
  ~PlainReader() override { std::fclose(f_); }
  absl::StatusOr<size_t> Read(void* dst, size_t n) override {
    const size_t got = std::fread(dst, 1, n, f_);
    if (got < n && std::ferror(f_)) return ErrnoError(path_, "read error");
    return got;
  }

 private:
  FILE* f_;
};

// gzerror() text without its "<path>: " or "<fd:3>: " prefix (callers name the file).
std::string GzErrorText(gzFile gz, int* errnum, const std::string& path) {
  std::string msg = gzerror(gz, errnum);
  if (msg.starts_with(path + ": ")) {
    msg.erase(0, path.size() + 2);
  } else if (msg.starts_with("<fd:")) {
    if (size_t colon = msg.find(": "); colon != std::string::npos) msg.erase(0, colon + 2);
  }
  return msg;
}

class GzipReader final : public ByteReader {
 public:
  GzipReader(std::string path, gzFile gz) : ByteReader(std::move(path), true), gz_(gz) {}
  ~GzipReader() override { gzclose(gz_); }
  absl::StatusOr<size_t> Read(void* dst, size_t n) override {
    size_t total = 0;
    auto* out = static_cast<uint8_t*>(dst);
    while (total < n) {
      // gzread takes an unsigned count; read huge requests in chunks.
      const unsigned chunk = static_cast<unsigned>(std::min<size_t>(n - total, 1u << 30));
      const int got = gzread(gz_, out + total, chunk);
      if (got < 0) return Error();
      if (got == 0) break;
      total += static_cast<size_t>(got);
    }
    return total;
  }
  // Why the stream ended early ("unexpected end of file", "invalid distance too far back").
  std::string EndReason() override {
    int errnum = Z_OK;
    std::string msg = GzErrorText(gz_, &errnum, path_);
    return errnum == Z_OK ? std::string() : msg;
  }

 private:
  absl::Status Error() {
    int errnum = Z_OK;
    const std::string msg = GzErrorText(gz_, &errnum, path_);
    if (errnum == Z_ERRNO) return ErrnoError(path_, "read error");
    return absl::DataLossError(absl::StrCat(path_, ": corrupt gzip data: ", msg));
  }
  gzFile gz_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<ByteReader>> ByteReader::Open(const std::string& path,
                                                             uint64_t offset, bool gzip) {
  if (!gzip) {
    FILE* f = std::fopen(path.c_str(), "rb");
    if (f == nullptr) return ErrnoError(path, "cannot open");
    if (fseeko(f, static_cast<off_t>(offset), SEEK_SET) != 0) {
      absl::Status st = ErrnoError(path, "cannot seek");
      std::fclose(f);
      return st;
    }
    return std::unique_ptr<ByteReader>(new PlainReader(path, f));
  }
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return ErrnoError(path, "cannot open");
  // zlib would silently pass non-gzip bytes through; a file that claims gzip must be gzip.
  unsigned char magic[2] = {0, 0};
  if (::pread(fd, magic, 2, static_cast<off_t>(offset)) != 2 || magic[0] != 0x1f ||
      magic[1] != 0x8b) {
    ::close(fd);
    return absl::DataLossError(absl::StrCat(path, ": gzip-compressed data expected at byte ",
                                            offset, " but no gzip header found there"));
  }
  if (::lseek(fd, static_cast<off_t>(offset), SEEK_SET) < 0) {
    absl::Status st = ErrnoError(path, "cannot seek");
    ::close(fd);
    return st;
  }
  gzFile gz = gzdopen(fd, "rb");  // starts reading at the fd's current position
  if (gz == nullptr) {
    ::close(fd);
    return absl::ResourceExhaustedError(absl::StrCat(path, ": cannot start gzip decoder"));
  }
  gzbuffer(gz, 1 << 17);
  return std::unique_ptr<ByteReader>(new GzipReader(path, gz));
}

namespace {

class PlainWriter final : public ByteWriter {
 public:
  PlainWriter(std::string path, FILE* f) : ByteWriter(std::move(path)), f_(f) {}
  ~PlainWriter() override {
    if (f_ != nullptr) std::fclose(f_);
  }
  absl::Status Write(const void* src, size_t n) override {
    if (std::fwrite(src, 1, n, f_) != n) return ErrnoError(path_, "write failed");
    return absl::OkStatus();
  }
  absl::Status Close() override {
    FILE* f = std::exchange(f_, nullptr);
    if (f == nullptr) return absl::OkStatus();
    if (std::fclose(f) != 0) return ErrnoError(path_, "write failed");
    return absl::OkStatus();
  }

 private:
  FILE* f_;
};

class GzipWriter final : public ByteWriter {
 public:
  GzipWriter(std::string path, gzFile gz) : ByteWriter(std::move(path)), gz_(gz) {}
  ~GzipWriter() override {
    if (gz_ != nullptr) gzclose(gz_);
  }
  absl::Status Write(const void* src, size_t n) override {
    const auto* in = static_cast<const uint8_t*>(src);
    while (n > 0) {
      const unsigned chunk = static_cast<unsigned>(std::min<size_t>(n, 1u << 30));
      if (gzwrite(gz_, in, chunk) != static_cast<int>(chunk)) {
        int errnum = Z_OK;
        const std::string msg = GzErrorText(gz_, &errnum, path_);
        if (errnum == Z_ERRNO) return ErrnoError(path_, "write failed");
        return absl::InternalError(absl::StrCat(path_, ": gzip write failed: ", msg));
      }
      in += chunk;
      n -= chunk;
    }
    return absl::OkStatus();
  }
  absl::Status Close() override {
    gzFile gz = std::exchange(gz_, nullptr);
    if (gz == nullptr) return absl::OkStatus();
    errno = 0;
    if (gzclose(gz) != Z_OK) return ErrnoError(path_, "write failed");
    return absl::OkStatus();
  }

 private:
  gzFile gz_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<ByteWriter>> ByteWriter::Open(const std::string& path, bool gzip,
                                                             bool append) {
  if (!gzip) {
    FILE* f = std::fopen(path.c_str(), append ? "ab" : "wb");
    if (f == nullptr) return ErrnoError(path, "cannot create");
    return std::unique_ptr<ByteWriter>(new PlainWriter(path, f));
  }
  // Level 6 is zlib's default trade-off; "a" appends a new gzip member after the header.
  gzFile gz = gzopen(path.c_str(), append ? "ab6" : "wb6");
  if (gz == nullptr) return ErrnoError(path, "cannot create");
  gzbuffer(gz, 1 << 17);
  return std::unique_ptr<ByteWriter>(new GzipWriter(path, gz));
}

// ---------------------------------------------------------------------------------------
// The SliceSource for contiguous voxel data (raw sidecar, NRRD, NIfTI).

namespace {

// The voxel bytes of an uncompressed file, mapped read-only: slices are handed out in place
// (the page cache's pages, no copy), the pages behind the current slice are unmapped as it
// advances (peak RSS stays a few slices) and the next ones are read ahead. A file truncated
// while mapped would raise SIGBUS on access, so every slice first checks the file's size.
class MappedVoxels {
 public:
  // nullptr where mapping is not possible (the caller reads instead).
  static std::unique_ptr<MappedVoxels> Open(const std::string& path, uint64_t offset,
                                            uint64_t length) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return nullptr;
    const uint64_t page = static_cast<uint64_t>(::sysconf(_SC_PAGESIZE));
    const uint64_t start = offset / page * page;
    const size_t span = static_cast<size_t>(offset - start + length);
    void* base = span == 0 ? MAP_FAILED
                           : ::mmap(nullptr, span, PROT_READ, MAP_SHARED, fd,
                                    static_cast<off_t>(start));
    if (base == MAP_FAILED) {
      ::close(fd);
      return nullptr;
    }
    ::madvise(base, span, MADV_SEQUENTIAL);
    return std::unique_ptr<MappedVoxels>(
        new MappedVoxels(fd, static_cast<uint8_t*>(base), span, start, offset - start, page));
  }
  ~MappedVoxels() {
    ::munmap(base_, span_);
    ::close(fd_);
  }
  MappedVoxels(const MappedVoxels&) = delete;
  MappedVoxels& operator=(const MappedVoxels&) = delete;

  // Bytes [begin, end) of the voxel data, once the file is known to still hold them; the
  // pages before `begin` are released and [end, ahead) is read ahead.
  absl::StatusOr<const uint8_t*> Range(uint64_t begin, uint64_t end, uint64_t ahead) {
    struct stat st;
    if (::fstat(fd_, &st) != 0) return absl::DataLossError("cannot stat the file");
    if (static_cast<uint64_t>(st.st_size) < file_start_ + skew_ + end) {
      return absl::DataLossError(
          absl::StrCat("truncated while being read: the file shrank to ", st.st_size, " bytes"));
    }
    const uint64_t keep = (skew_ + begin) / page_ * page_;
    if (keep > released_) {
      ::madvise(base_ + released_, keep - released_, MADV_DONTNEED);
      released_ = keep;
    }
    const uint64_t lo = (skew_ + end) / page_ * page_;
    const uint64_t hi = std::min<uint64_t>(skew_ + ahead, span_);
    if (hi > lo) ::madvise(base_ + lo, hi - lo, MADV_WILLNEED);
    return base_ + skew_ + begin;
  }

 private:
  MappedVoxels(int fd, uint8_t* base, size_t span, uint64_t file_start, uint64_t skew,
               uint64_t page)
      : fd_(fd), base_(base), span_(span), file_start_(file_start), skew_(skew), page_(page) {}

  int fd_;
  uint8_t* base_;
  size_t span_;
  uint64_t file_start_;  // file offset of the first mapped page
  uint64_t skew_;        // offset of the voxel data within that page
  uint64_t page_;
  uint64_t released_ = 0;  // mapping bytes [0, released_) are given back
};

class StreamSliceSource final : public SliceSource {
 public:
  StreamSliceSource(StreamVolumeSpec spec, std::unique_ptr<ByteReader> reader)
      : spec_(std::move(spec)), reader_(std::move(reader)) {
    info_ = spec_.info;
    if (spec_.scale) info_.dtype = DType::kFloat32;
    where_ = spec_.data_path == spec_.path
                 ? spec_.path
                 : absl::StrCat(spec_.path, " (data file ", spec_.data_path, ")");
    swap_ = spec_.big_endian == kHostIsLittleEndian && DTypeSize(spec_.info.dtype) > 1;
  }

  const VolumeInfo& info() const override { return info_; }
  int64_t next_slice() const override { return next_; }

  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override {
    if (!sticky_.ok()) return sticky_;
    if (next_ >= info_.nz) {
      return absl::OutOfRangeError(
          absl::StrCat(spec_.path, ": no more slices (all ", info_.nz, " were read)"));
    }
    const VolumeInfo& stored = spec_.info;
    const size_t stored_bytes = stored.slice_bytes();
    if (map_ != nullptr) {  // mapped by an earlier ViewSlice: stay at the same position
      const uint8_t* view = nullptr;
      if (absl::Status st = ViewSlice(&view); !st.ok()) return st;
      bytes->assign(view, view + stored_bytes);
      return absl::OkStatus();
    }
    std::vector<uint8_t>* target = spec_.scale ? &stored_slice_ : bytes;
    target->resize(stored_bytes);
    absl::StatusOr<size_t> got = reader_->Read(target->data(), stored_bytes);
    if (!got.ok()) return sticky_ = got.status();
    if (*got < stored_bytes) {
      const uint64_t have = static_cast<uint64_t>(next_) * stored_bytes + *got;
      std::string why = reader_->EndReason();
      if (!why.empty()) why = absl::StrCat(" (", why, ")");
      return sticky_ = absl::DataLossError(
                 absl::StrCat(where_, ": truncated: expected ", VolumeBytes(stored),
                              " bytes of voxel data (", DescribeGrid(stored), "), ",
                              spec_.gzip ? "compressed stream has " : "file has ", have, why));
    }
    if (swap_) SwapBytesInPlace(target->data(), stored.slice_voxels(), DTypeSize(stored.dtype));
    if (spec_.scale) {
      scaled_.resize(stored.slice_voxels());
      ConvertToFloat(stored.dtype, stored_slice_.data(), scaled_.size(), scaled_.data());
      const double slope = spec_.scl_slope, inter = spec_.scl_inter;
      for (float& v : scaled_) v = static_cast<float>(v * slope + inter);
      bytes->resize(scaled_.size() * sizeof(float));
      std::memcpy(bytes->data(), scaled_.data(), bytes->size());
    }
    ++next_;
    // A plain file's size was checked at open time; a gzip stream can only be checked here.
    if (next_ == info_.nz && spec_.gzip) {
      uint8_t extra;
      absl::StatusOr<size_t> more = reader_->Read(&extra, 1);
      if (more.ok() && *more > 0) {
        return sticky_ = absl::DataLossError(absl::StrCat(
                   where_, ": size mismatch: compressed stream holds more than the ",
                   VolumeBytes(stored), " bytes of voxel data that ", DescribeGrid(stored),
                   " needs (wrong dims or dtype in the header?)"));
      }
    }
    return absl::OkStatus();
  }

  absl::Status ViewSlice(const uint8_t** data) override {
    *data = nullptr;
    if (!sticky_.ok()) return sticky_;
    // Only voxels usable as stored, from the start (ReadSlice has not moved the reader).
    if (spec_.gzip || swap_ || spec_.scale || (map_ == nullptr && (no_map_ || next_ > 0))) {
      return absl::OkStatus();
    }
    if (next_ >= info_.nz) {
      return absl::OutOfRangeError(
          absl::StrCat(spec_.path, ": no more slices (all ", info_.nz, " were read)"));
    }
    const uint64_t slice = info_.slice_bytes();
    if (map_ == nullptr) {
      map_ = MappedVoxels::Open(spec_.data_path, spec_.data_offset, VolumeBytes(info_));
      if (map_ == nullptr) {
        no_map_ = true;  // e.g. a file system without mmap: ReadSlice it is
        return absl::OkStatus();
      }
    }
    const uint64_t begin = static_cast<uint64_t>(next_) * slice;
    absl::StatusOr<const uint8_t*> view =
        map_->Range(begin, begin + slice, begin + (1 + kReadAhead) * slice);
    if (!view.ok()) {
      return sticky_ = absl::DataLossError(absl::StrCat(where_, ": ", view.status().message()));
    }
    *data = *view;
    ++next_;
    return absl::OkStatus();
  }

 private:
  static constexpr uint64_t kReadAhead = 4;  // slices asked of the disk ahead of the view
  StreamVolumeSpec spec_;
  std::unique_ptr<MappedVoxels> map_;  // set by the first ViewSlice where mapping works
  bool no_map_ = false;
  std::unique_ptr<ByteReader> reader_;
  VolumeInfo info_;  // as delivered (float32 when scaled)
  std::string where_;
  bool swap_ = false;
  int64_t next_ = 0;
  absl::Status sticky_;                // a failed stream stays failed
  std::vector<uint8_t> stored_slice_;  // scaled volumes: the slice as stored
  std::vector<float> scaled_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<SliceSource>> OpenStreamVolume(StreamVolumeSpec spec) {
  if (absl::Status st = ValidateVolumeInfo(spec.info); !st.ok()) {
    return absl::Status(st.code(), absl::StrCat(spec.path, ": ", st.message()));
  }
  if (spec.info.nz == 0) {
    return absl::InvalidArgumentError(absl::StrCat(spec.path, ": nz is missing"));
  }
  const uint64_t need = VolumeBytes(spec.info);
  absl::StatusOr<uint64_t> size = FileSize(spec.data_path);
  if (!size.ok()) {
    if (spec.data_path == spec.path) return size.status();
    return absl::Status(size.status().code(),
                        absl::StrCat(spec.path, ": data file: ", size.status().message()));
  }
  if (!spec.gzip) {
    const uint64_t have = *size > spec.data_offset ? *size - spec.data_offset : 0;
    const std::string where = spec.data_path == spec.path
                                  ? spec.path
                                  : absl::StrCat(spec.path, " (data file ", spec.data_path, ")");
    if (have < need) {
      return absl::DataLossError(absl::StrCat(where, ": truncated: expected ", need,
                                              " bytes of voxel data (", DescribeGrid(spec.info),
                                              "), file has ", have));
    }
    if (have > need) {
      return absl::DataLossError(absl::StrCat(where, ": size mismatch: file has ", have,
                                              " bytes of voxel data but ", DescribeGrid(spec.info),
                                              " needs ", need, " (wrong dims or dtype?)"));
    }
  }
  absl::StatusOr<std::unique_ptr<ByteReader>> reader =
      ByteReader::Open(spec.data_path, spec.data_offset, spec.gzip);
  if (!reader.ok()) return reader.status();
  if (spec.skip_bytes > 0) {
    if (absl::Status st = (*reader)->Skip(spec.skip_bytes); !st.ok()) {
      if (!absl::IsOutOfRange(st)) return st;
      return absl::DataLossError(absl::StrCat(spec.path, ": truncated: data ends before byte ",
                                              spec.skip_bytes, " where the voxels start"));
    }
  }
  return std::unique_ptr<SliceSource>(new StreamSliceSource(std::move(spec), std::move(*reader)));
}

}  // namespace internal
}  // namespace tandem
