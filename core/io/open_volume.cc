// OpenVolume: the reader for a path (by extension, or a folder's files), and the helpers the
// readers share (file names, sizes, errors, byte order).
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
#include "tandem/io/open_volume.h"
#include "tandem/io/series.h"
#include "tandem/status_macros.h"
#include "tandem/volume.h"
#include "tandem/io/zarr.h"
#include "volume_io_internal.h"
#include "zarr_internal.h"

namespace tandem::io {

using internal::Sv;

absl::StatusOr<std::unique_ptr<SliceSource>> OpenVolume(const std::string& path) {
  return OpenVolume(path, OpenOptions{});
}

absl::StatusOr<std::unique_ptr<SliceSource>> OpenVolume(const std::string& path,
                                                        const OpenOptions& opts) {
  auto not_dicom = [&] {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": --series picks a series of a DICOM folder; this is not one"));
  };
  // Zarr stores are directories; "image.zarr#1" picks level 1 (see tandem/zarr.h).
  if (auto [store, selector] = SplitZarrSelector(path); internal::LooksLikeZarr(store)) {
    if (!opts.dicom_series.empty()) return not_dicom();
    return OpenZarrVolume(store, ZarrReadOptions{.array = selector});
  }
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    TANDEM_ASSIGN_OR_RETURN(std::vector<std::string> files, ListSliceFiles(path));
    if (std::vector<std::string> tiffs = TiffNames(files); !tiffs.empty()) {
      if (!opts.dicom_series.empty()) return not_dicom();
      return OpenTiffSequence(path, tiffs);
    }
    return OpenDicomSeries(path, files, opts);
  }
  if (!opts.dicom_series.empty()) return not_dicom();
  const std::string ext = internal::VolumeExtension(path);
  if (ext == ".json") return internal::OpenRawVolume(path);
  if (ext == ".nrrd" || ext == ".nhdr") return internal::OpenNrrdVolume(path);
  if (ext == ".nii" || ext == ".nii.gz") return internal::OpenNiftiVolume(path);
  if (ext == ".tif" || ext == ".tiff") return internal::OpenTiffVolume(path);
  if (ext == ".mha" || ext == ".mhd") return internal::OpenMetaImageVolume(path);
  if (ext == ".hdr" || ext == ".img" || ext == ".hdr.gz" || ext == ".img.gz") {
    return absl::InvalidArgumentError(absl::StrCat(
        path,
        ": NIfTI/Analyze .hdr + .img pairs are not supported; convert to a single-file "
        ".nii or .nii.gz"));
  }
  return absl::InvalidArgumentError(absl::StrCat(
      path, ": unsupported volume format '", ext.empty() ? "(no extension)" : ext,
      "'; supported: .json (raw + JSON sidecar), .nrrd, .nhdr, .nii, .nii.gz, .tif, .tiff, "
      ".mha, .mhd, a "
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
    if (name.empty() || name[0] == '.' || IsTemporaryName(name)) continue;
    std::error_code fec;
    if (!it->is_regular_file(fec)) continue;
    names.push_back(name);
  }
  std::sort(names.begin(), names.end(), NaturalLess);
  for (std::string& n : names) n = (std::filesystem::path(dir) / n).string();
  return names;
}

bool IsTemporaryName(const std::string& name) {
  const std::string lower = absl::AsciiStrToLower(name);
  for (const char* suffix : {".part", ".partial", ".filepart", ".crdownload", ".download", ".tmp",
                             ".temp", ".swp", "~"}) {
    if (lower.size() > std::strlen(suffix) && lower.ends_with(suffix)) return true;
  }
  return false;
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

absl::Status CountedSliceSource::ReadSlice(std::vector<uint8_t>* bytes) {
  if (!failure_.ok()) return failure_;
  if (next_ >= info_.nz) return NoMoreSlices();
  absl::Status st = ReadNext(bytes);
  if (st.ok() && ++next_ == info_.nz) st = AfterLastSlice();
  if (!st.ok() && on_failure_ == OnFailure::kKeep) failure_ = st;
  return st;
}

absl::Status CountedSliceSource::NoMoreSlices() const {
  return absl::OutOfRangeError(
      absl::StrCat(name_, ": no more slices (all ", info_.nz, " were read)"));
}

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

absl::StatusOr<std::string> ReadHead(const std::string& path, uint64_t file_size, uint64_t max) {
  std::string text(static_cast<size_t>(std::min(file_size, max)), '\0');
  FILE* f = std::fopen(path.c_str(), "rb");
  if (f == nullptr) return ErrnoError(path, "cannot open");
  const size_t got = std::fread(text.data(), 1, text.size(), f);
  std::fclose(f);
  if (got != text.size()) return ErrnoError(path, "read error");
  return text;
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

std::string VolumeExtension(const std::string& path) {
  std::string name = absl::AsciiStrToLower(std::filesystem::path(path).filename().string());
  if (name.size() > 3 && name.ends_with(".gz")) {
    std::string inner = std::filesystem::path(name.substr(0, name.size() - 3)).extension();
    return inner + ".gz";
  }
  return std::filesystem::path(name).extension().string();
}

}  // namespace internal
}  // namespace tandem::io
