// Multi-page TIFF stacks (one page = one z-slice) through libtiff, reader and writer.
//
// Pages must all share width, height, bits per sample and sample format; 1 sample per pixel;
// 8/16/32/64-bit unsigned or signed integers or 32-bit IEEE float; strips or tiles, any
// compression libtiff decodes. Values are delivered as stored (PhotometricInterpretation is
// ignored).
//
// Geometry: a plain TIFF has no reliable notion of voxel size (X/YResolution are usually
// print DPI), so spacing is (1,1,1) and origin 0. Stacks written by ImageJ/Fiji (and by
// WriteVolume) carry an ImageDescription starting with "ImageJ="; for those only,
// sx = 1/XResolution, sy = 1/YResolution, sz = "spacing=", and origin = -(x|y|z)origin times
// the spacing (ImageJ stores the origin in pixels). All three are in the description's
// "unit=" (no unit conversion is done). ImageJ hyperstacks (channels or frames > 1) are
// rejected, since their pages are not all z-slices.
//
// libtiff reports problems through handlers; every handle gets its own handlers that
// collect the text into the Status instead of printing to stderr.
#include <tiffio.h>

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <string>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include <filesystem>

#include "tandem/status_macros.h"
#include "volume_io_internal.h"
#include "tandem/io/series.h"

namespace tandem::io::internal {
namespace {

int CollectMessage(TIFF* /*tif*/, void* user_data, const char* module, const char* fmt,
                   va_list ap) {
  auto* out = static_cast<std::string*>(user_data);
  char buf[512];
  std::vsnprintf(buf, sizeof(buf), fmt, ap);
  if (!out->empty()) out->append("; ");
  if (module != nullptr && *module != '\0') absl::StrAppend(out, module, ": ");
  out->append(buf);
  return 1;  // handled: do not fall through to the global (stderr) handlers
}

int IgnoreWarning(TIFF*, void*, const char*, const char*, va_list) { return 1; }

// A TIFF handle with its own error sink (heap-allocated so the sink's address is stable).
class TiffFile {
 public:
  static absl::StatusOr<std::unique_ptr<TiffFile>> Open(const std::string& path, const char* mode) {
    // Messages from code paths that have no handle go to the global handlers; silence them.
    static std::once_flag once;
    std::call_once(once, [] {
      TIFFSetWarningHandler(nullptr);
      TIFFSetErrorHandler(nullptr);
    });
    auto file = std::unique_ptr<TiffFile>(new TiffFile(path));
    TIFFOpenOptions* opts = TIFFOpenOptionsAlloc();
    TIFFOpenOptionsSetErrorHandlerExtR(opts, CollectMessage, &file->errors_);
    TIFFOpenOptionsSetWarningHandlerExtR(opts, IgnoreWarning, nullptr);
    file->tif_ = TIFFOpenExt(path.c_str(), mode, opts);
    TIFFOpenOptionsFree(opts);
    if (file->tif_ == nullptr) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": not a readable TIFF file (corrupt or truncated?): ",
                       file->TakeErrors("TIFFOpen failed")));
    }
    return file;
  }
  ~TiffFile() {
    if (tif_ != nullptr) TIFFClose(tif_);
  }
  TIFF* get() const { return tif_; }
  // Closes (flushing a file being written) and reports any error libtiff raised.
  absl::Status Close() {
    TIFFClose(std::exchange(tif_, nullptr));
    if (!errors_.empty()) return absl::InternalError(absl::StrCat(path_, ": ", TakeErrors("")));
    return absl::OkStatus();
  }
  std::string TakeErrors(absl::string_view fallback) {
    std::string e = errors_.empty() ? std::string(fallback) : std::exchange(errors_, {});
    return e;
  }
  const std::string& path() const { return path_; }

 private:
  explicit TiffFile(std::string path) : path_(std::move(path)) {}
  std::string path_;
  std::string errors_;
  TIFF* tif_ = nullptr;
};

struct PageFormat {
  uint32_t width = 0, height = 0;
  uint16_t bits = 0, sample_format = SAMPLEFORMAT_UINT, samples = 1;
  bool tiled = false;
  uint32_t tile_width = 0, tile_length = 0;  // tiled pages only
};

absl::StatusOr<PageFormat> ReadPageFormat(TiffFile& f, int64_t page) {
  TIFF* tif = f.get();
  PageFormat p;
  if (!TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &p.width) ||
      !TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &p.height)) {
    return absl::InvalidArgumentError(
        absl::StrCat(f.path(), ": page ", page, " has no image width/length"));
  }
  TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &p.bits);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &p.samples);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &p.sample_format);
  if (p.sample_format == SAMPLEFORMAT_VOID) p.sample_format = SAMPLEFORMAT_UINT;
  p.tiled = TIFFIsTiled(tif) != 0;
  if (p.tiled) {
    TIFFGetField(tif, TIFFTAG_TILEWIDTH, &p.tile_width);
    TIFFGetField(tif, TIFFTAG_TILELENGTH, &p.tile_length);
  }
  return p;
}

// A tile is read whole into one buffer, so its declared size must be plausible for the page:
// at most the page itself or 64 MiB, whichever is larger (a 32x32 page declaring 65520^2
// tiles would otherwise allocate 17 GB before libtiff notices the data is missing).
absl::Status CheckTileSize(const std::string& path, int64_t page, const PageFormat& p,
                           DType dtype) {
  if (!p.tiled) return absl::OkStatus();
  const uint64_t px = DTypeSize(dtype);
  const uint64_t tile_bytes = uint64_t{p.tile_width} * p.tile_length * px;
  const uint64_t page_bytes = uint64_t{p.width} * p.height * px;
  constexpr uint64_t kTileFloor = uint64_t{64} << 20;
  if (p.tile_width == 0 || p.tile_length == 0 || tile_bytes > std::max(page_bytes, kTileFloor)) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": page ", page, " declares tiles of ", p.tile_width, " x ", p.tile_length,
        " pixels (", tile_bytes, " bytes) for a ", p.width, " x ", p.height,
        " page (corrupt file?)"));
  }
  return absl::OkStatus();
}

uint16_t TiffSampleFormat(DType t) {
  return t == DType::kFloat32 ? SAMPLEFORMAT_IEEEFP
         : IsSignedDType(t)   ? SAMPLEFORMAT_INT
                              : SAMPLEFORMAT_UINT;
}

absl::StatusOr<DType> PageDType(const std::string& path, int64_t page, const PageFormat& p) {
  if (p.samples != 1) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": page ", page, " has ", p.samples,
                     " samples per pixel (RGB?); only single-channel stacks are supported"));
  }
  for (DType t : kAllDTypes) {
    if (p.bits == 8 * DTypeSize(t) && p.sample_format == TiffSampleFormat(t)) return t;
  }
  const char* kind = p.sample_format == SAMPLEFORMAT_INT      ? "signed integer"
                     : p.sample_format == SAMPLEFORMAT_IEEEFP ? "floating-point"
                     : p.sample_format == SAMPLEFORMAT_UINT   ? "unsigned integer"
                                                              : "complex/other";
  return absl::InvalidArgumentError(
      absl::StrCat(path, ": unsupported pixel type on page ", page, ": ", p.bits, "-bit ", kind,
                   " (supported: 8/16/32/64-bit unsigned or signed integer, 32-bit float)"));
}

// Strip/tile extents must lie inside the file; catches truncation before any slice is read.
absl::Status CheckStrilesInFile(TiffFile& f, int64_t page, uint64_t file_size) {
  TIFF* tif = f.get();
  const uint32_t n = TIFFIsTiled(tif) ? TIFFNumberOfTiles(tif) : TIFFNumberOfStrips(tif);
  for (uint32_t i = 0; i < n; ++i) {
    int err = 0;
    const uint64_t off = TIFFGetStrileOffsetWithErr(tif, i, &err);
    const uint64_t count = err ? 0 : TIFFGetStrileByteCountWithErr(tif, i, &err);
    if (err) {
      return absl::DataLossError(
          absl::StrCat(f.path(), ": page ", page,
                       ": cannot read strip/tile offsets: ", f.TakeErrors("corrupt directory")));
    }
    if (off + count > file_size) {
      return absl::DataLossError(absl::StrCat(f.path(), ": truncated: page ", page,
                                              " needs data up to byte ", off + count, ", file has ",
                                              file_size, " bytes"));
    }
  }
  return absl::OkStatus();
}

// ImageJ description fields we use; absent ones keep their defaults.
struct ImageJInfo {
  bool present = false;
  double spacing = 1.0;
  double origin[3] = {0, 0, 0};  // in pixels
  int64_t channels = 1, frames = 1;
};

ImageJInfo ParseImageJ(absl::string_view desc) {
  ImageJInfo ij;
  if (!absl::StartsWith(desc, "ImageJ=")) return ij;
  ij.present = true;
  for (absl::string_view line : absl::StrSplit(desc, '\n')) {
    const size_t eq = line.find('=');
    if (eq == absl::string_view::npos) continue;
    const absl::string_view key = absl::StripAsciiWhitespace(line.substr(0, eq));
    const absl::string_view val = absl::StripAsciiWhitespace(line.substr(eq + 1));
    double d;
    if (key == "spacing" && absl::SimpleAtod(val, &d)) ij.spacing = std::abs(d);
    if (key == "xorigin" && absl::SimpleAtod(val, &d)) ij.origin[0] = d;
    if (key == "yorigin" && absl::SimpleAtod(val, &d)) ij.origin[1] = d;
    if (key == "zorigin" && absl::SimpleAtod(val, &d)) ij.origin[2] = d;
    if (key == "channels") (void)absl::SimpleAtoi(val, &ij.channels);
    if (key == "frames") (void)absl::SimpleAtoi(val, &ij.frames);
  }
  return ij;
}

class TiffSliceSource final : public CountedSliceSource {
 public:
  TiffSliceSource(std::unique_ptr<TiffFile> file, VolumeInfo info)
      : CountedSliceSource(file->path(), std::move(info), OnFailure::kKeep),
        file_(std::move(file)) {}

 private:
  absl::Status ReadNext(std::vector<uint8_t>* bytes) override {
    TIFF* tif = file_->get();
    if (next_slice() > 0 && !TIFFReadDirectory(tif)) {
      return Failure("cannot read the page directory");
    }
    bytes->resize(info_.slice_bytes());
    return TIFFIsTiled(tif) ? ReadTiles(bytes->data()) : ReadStrips(bytes->data());
  }

  absl::Status Failure(absl::string_view what) {
    return absl::DataLossError(
        absl::StrCat(file_->path(), ": page ", next_slice(), ": ", what,
                     " (truncated or corrupt file?): ", file_->TakeErrors("libtiff error")));
  }

  absl::Status ReadStrips(uint8_t* dst) {
    TIFF* tif = file_->get();
    const size_t row_bytes = static_cast<size_t>(info_.nx) * DTypeSize(info_.dtype);
    uint32_t rows_per_strip = 0;
    TIFFGetFieldDefaulted(tif, TIFFTAG_ROWSPERSTRIP, &rows_per_strip);
    rows_per_strip = std::clamp<uint32_t>(rows_per_strip, 1, static_cast<uint32_t>(info_.ny));
    const uint32_t strips = TIFFNumberOfStrips(tif);
    for (uint32_t s = 0; s < strips; ++s) {
      const int64_t row0 = int64_t{s} * rows_per_strip;
      if (row0 >= info_.ny) break;
      const int64_t rows = std::min<int64_t>(rows_per_strip, info_.ny - row0);
      const tmsize_t want = static_cast<tmsize_t>(rows * row_bytes);
      // Decodes (and byte-swaps to host order) straight into the slice.
      if (TIFFReadEncodedStrip(tif, s, dst + row0 * row_bytes, want) != want) {
        return Failure(absl::StrCat("cannot read strip ", s));
      }
    }
    return absl::OkStatus();
  }

  absl::Status ReadTiles(uint8_t* dst) {
    TIFF* tif = file_->get();
    uint32_t tw = 0, th = 0;
    TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tw);
    TIFFGetField(tif, TIFFTAG_TILELENGTH, &th);
    if (tw == 0 || th == 0) return Failure("bad tile size");
    const size_t px = DTypeSize(info_.dtype);
    tile_.resize(static_cast<size_t>(TIFFTileSize(tif)));
    if (tile_.size() < size_t{tw} * th * px) return Failure("bad tile size");
    for (uint32_t y = 0; y < info_.ny; y += th) {
      for (uint32_t x = 0; x < info_.nx; x += tw) {
        const uint32_t tile = TIFFComputeTile(tif, x, y, 0, 0);
        if (TIFFReadEncodedTile(tif, tile, tile_.data(), static_cast<tmsize_t>(tile_.size())) < 0) {
          return Failure(absl::StrCat("cannot read tile ", tile));
        }
        const uint32_t rows = std::min<uint32_t>(th, static_cast<uint32_t>(info_.ny) - y);
        const size_t cols = std::min<uint32_t>(tw, static_cast<uint32_t>(info_.nx) - x);
        for (uint32_t r = 0; r < rows; ++r) {
          std::memcpy(dst + ((size_t{y} + r) * info_.nx + x) * px,
                      tile_.data() + size_t{r} * tw * px, cols * px);
        }
      }
    }
    return absl::OkStatus();
  }

  std::unique_ptr<TiffFile> file_;
  std::vector<uint8_t> tile_;  // reused tile buffer
};


// A TIFF file opened, its pages walked once (so inconsistent stacks fail at open time), the
// directory reset to page 0. info.nz = the page count; spacing and origin as the header says.
struct OpenedTiff {
  std::unique_ptr<TiffFile> file;
  VolumeInfo info;
  bool imagej = false;  // spacing came from an ImageJ description
};

absl::StatusOr<OpenedTiff> OpenTiffPages(const std::string& path) {
  TANDEM_ASSIGN_OR_RETURN(uint64_t size, NonEmptyFileSize(path));
  // "m": no memory mapping (a file truncated while mapped would crash with SIGBUS).
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<TiffFile> file, TiffFile::Open(path, "rm"));
  TiffFile& f = *file;
  TIFF* tif = f.get();

  VolumeInfo info;
  PageFormat first;
  int64_t pages = 0;
  do {
    TANDEM_ASSIGN_OR_RETURN(PageFormat p, ReadPageFormat(f, pages));
    TANDEM_ASSIGN_OR_RETURN(DType dtype, PageDType(path, pages, p));
    if (pages == 0) {
      first = p;
      info.dtype = dtype;
    } else if (p.width != first.width || p.height != first.height || p.bits != first.bits ||
               p.sample_format != first.sample_format) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": size mismatch: page ", pages, " is ", p.width, "x", p.height, " ",
                       p.bits, "-bit but page 0 is ", first.width, "x", first.height, " ",
                       first.bits, "-bit (all pages of a stack must match)"));
    }
    TANDEM_RETURN_IF_ERROR(CheckTileSize(path, pages, p, dtype));
    TANDEM_RETURN_IF_ERROR(CheckStrilesInFile(f, pages, size));
    ++pages;
  } while (TIFFReadDirectory(tif));
  if (std::string e = f.TakeErrors(""); !e.empty()) {
    return absl::DataLossError(
        absl::StrCat(path, ": cannot read page ", pages, " (truncated or corrupt file?): ", e));
  }
  if (!TIFFSetDirectory(tif, 0)) {
    return absl::DataLossError(
        absl::StrCat(path, ": cannot return to page 0: ", f.TakeErrors("libtiff error")));
  }

  info.nx = first.width;
  info.ny = first.height;
  info.nz = pages;
  char* desc = nullptr;
  std::string description;
  if (TIFFGetField(tif, TIFFTAG_IMAGEDESCRIPTION, &desc) && desc != nullptr) description = desc;
  const ImageJInfo ij = ParseImageJ(description);
  if (ij.present) {
    if (ij.channels > 1 || ij.frames > 1) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": ImageJ hyperstack with ", ij.channels, " channels and ", ij.frames,
                       " frames is not supported (pages must be z-slices only)"));
    }
    float res = 0.0f;
    if (TIFFGetField(tif, TIFFTAG_XRESOLUTION, &res) && std::isfinite(res) && res > 0.0f) {
      info.spacing[0] = 1.0 / res;
    }
    if (TIFFGetField(tif, TIFFTAG_YRESOLUTION, &res) && std::isfinite(res) && res > 0.0f) {
      info.spacing[1] = 1.0 / res;
    }
    info.spacing[2] = ij.spacing;
    for (int a = 0; a < 3; ++a) info.origin[a] = -ij.origin[a] * info.spacing[a];
  } else {
    info.description = description;
    info.spacing_known = false;
  }
  return OpenedTiff{std::move(file), std::move(info), ij.present};
}

// Pixel size in mm from XResolution / YResolution with a centimetre or inch unit (what
// reconstruction tools that do not write ImageJ descriptions use); 0 if there is none.
std::array<double, 2> ResolutionMm(TIFF* tif) {
  uint16_t unit = RESUNIT_NONE;
  TIFFGetFieldDefaulted(tif, TIFFTAG_RESOLUTIONUNIT, &unit);
  const double mm = unit == RESUNIT_CENTIMETER ? 10.0 : unit == RESUNIT_INCH ? 25.4 : 0.0;
  std::array<double, 2> out{0, 0};
  float res = 0.0f;
  if (mm > 0 && TIFFGetField(tif, TIFFTAG_XRESOLUTION, &res) && std::isfinite(res) && res > 0) {
    out[0] = mm / res;
  }
  if (mm > 0 && TIFFGetField(tif, TIFFTAG_YRESOLUTION, &res) && std::isfinite(res) && res > 0) {
    out[1] = mm / res;
  }
  return out;
}

}  // namespace

absl::Status ReadTiffSequenceSlice(const std::string& path, const std::string& first,
                                   const VolumeInfo& info, std::vector<uint8_t>* bytes) {
  TANDEM_ASSIGN_OR_RETURN(OpenedTiff t, OpenTiffPages(path));
  if (t.info.nz != 1 || t.info.nx != info.nx || t.info.ny != info.ny ||
      t.info.dtype != info.dtype) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": ", t.info.nz, " page(s) of ", t.info.nx, "x", t.info.ny, " ",
        Sv(DTypeName(t.info.dtype)), " where the sequence (from ", first, ") has one page of ",
        info.nx, "x", info.ny, " ", Sv(DTypeName(info.dtype)),
        " per file (every slice of a TIFF sequence must match)"));
  }
  TiffSliceSource page(std::move(t.file), std::move(t.info));
  return page.ReadSlice(bytes);
}

absl::StatusOr<VolumeInfo> TiffSequenceInfo(const std::string& first_file) {
  TANDEM_ASSIGN_OR_RETURN(OpenedTiff t, OpenTiffPages(first_file));
  if (t.info.nz != 1) {
    return absl::InvalidArgumentError(
        absl::StrCat(first_file, ": ", t.info.nz,
                     " pages; a TIFF sequence folder holds one single-page TIFF per slice"));
  }
  VolumeInfo info = t.info;
  if (!t.imagej) {
    // Reconstructions are isotropic: z takes the x pixel size.
    const std::array<double, 2> mm = ResolutionMm(t.file->get());
    if (mm[0] > 0 && mm[1] > 0) {
      info.spacing = {mm[0], mm[1], mm[0]};
      info.spacing_known = true;
    }
  }
  return info;
}

namespace {

// One single-page TIFF per slice, opened as it is reached.
class TiffSequenceSource final : public CountedSliceSource {
 public:
  TiffSequenceSource(std::vector<std::string> files, VolumeInfo info)
      : CountedSliceSource("TIFF sequence", std::move(info), OnFailure::kRetry),
        files_(std::move(files)) {}

 private:
  absl::Status ReadNext(std::vector<uint8_t>* bytes) override {
    return ReadTiffSequenceSlice(files_[next_slice()], files_.front(), info_, bytes);
  }

  std::vector<std::string> files_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<SliceSource>> OpenTiffVolume(const std::string& path) {
  TANDEM_ASSIGN_OR_RETURN(OpenedTiff t, OpenTiffPages(path));
  if (absl::Status st = ValidateVolumeInfo(t.info); !st.ok()) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": ", st.message(), t.info.nz < 2 ? " (a stack needs at least 2 pages)" : ""));
  }
  return std::unique_ptr<SliceSource>(
      new TiffSliceSource(std::move(t.file), std::move(t.info)));
}

absl::Status WriteTiffVolume(const std::string& path, const VolumeInfo& info,
                             const SliceFn& slice_fn, const VolumeWriteOptions& opts) {
  const int tile = opts.tiff_tile_size;
  if (tile < 0 || tile % 16 != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": tiff_tile_size ", tile, " must be a multiple of 16"));
  }
  if (opts.gzip && !TIFFIsCODECConfigured(COMPRESSION_ADOBE_DEFLATE)) {
    return absl::UnimplementedError(absl::StrCat(path, ": this libtiff lacks deflate support"));
  }
  // Classic TIFF addresses 4 GiB; leave room for directories before switching to BigTIFF.
  const bool big_tiff = VolumeBytes(info) > (uint64_t{3} << 30);
  const std::string mode = absl::StrCat("w", opts.big_endian ? "b" : "l", big_tiff ? "8" : "");
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<TiffFile> file, TiffFile::Open(path, mode.c_str()));
  TiffFile& f = *file;
  TIFF* tif = f.get();

  uint16_t bits = static_cast<uint16_t>(8 * DTypeSize(info.dtype));
  uint16_t format = TiffSampleFormat(info.dtype);
  // ImageJ-style description: carries z spacing and the origin (in pixels, negated).
  std::string desc = absl::StrCat("ImageJ=1.11a\nimages=", info.nz, "\nslices=", info.nz,
                                  "\nunit=mm\nspacing=", FormatDouble(info.spacing[2]), "\n");
  const char* origin_keys[3] = {"xorigin", "yorigin", "zorigin"};
  for (int a = 0; a < 3; ++a) {
    if (info.origin[a] != 0.0) {
      absl::StrAppend(&desc, origin_keys[a], "=", FormatDouble(-info.origin[a] / info.spacing[a]),
                      "\n");
    }
  }
  absl::StrAppend(&desc, "loop=false\n");

  const size_t px = DTypeSize(info.dtype);
  const size_t row_bytes = static_cast<size_t>(info.nx) * px;
  const uint32_t rows_per_strip =
      static_cast<uint32_t>(std::clamp<size_t>((size_t{1} << 16) / row_bytes, 1, info.ny));
  std::vector<uint8_t> slice, tile_buf;
  for (int64_t z = 0; z < info.nz; ++z) {
    TANDEM_RETURN_IF_ERROR(FetchSlice(path, info, slice_fn, z, &slice));
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, static_cast<uint32_t>(info.nx));
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, static_cast<uint32_t>(info.ny));
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, bits);
    TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, format);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, uint16_t{1});
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
    TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
    TIFFSetField(tif, TIFFTAG_COMPRESSION,
                 opts.gzip ? COMPRESSION_ADOBE_DEFLATE : COMPRESSION_NONE);
    TIFFSetField(tif, TIFFTAG_SUBFILETYPE, FILETYPE_PAGE);
    TIFFSetField(tif, TIFFTAG_XRESOLUTION, 1.0 / info.spacing[0]);
    TIFFSetField(tif, TIFFTAG_YRESOLUTION, 1.0 / info.spacing[1]);
    TIFFSetField(tif, TIFFTAG_RESOLUTIONUNIT, RESUNIT_NONE);
    if (info.nz <= 0xffff) {
      TIFFSetField(tif, TIFFTAG_PAGENUMBER, static_cast<uint16_t>(z),
                   static_cast<uint16_t>(info.nz));
    }
    if (z == 0) TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, desc.c_str());

    bool ok = true;
    if (tile > 0) {
      TIFFSetField(tif, TIFFTAG_TILEWIDTH, static_cast<uint32_t>(tile));
      TIFFSetField(tif, TIFFTAG_TILELENGTH, static_cast<uint32_t>(tile));
      tile_buf.assign(size_t(tile) * tile * px, 0);  // edge tiles are zero-padded
      for (int64_t y = 0; ok && y < info.ny; y += tile) {
        for (int64_t x = 0; ok && x < info.nx; x += tile) {
          const int64_t rows = std::min<int64_t>(tile, info.ny - y);
          const int64_t cols = std::min<int64_t>(tile, info.nx - x);
          std::fill(tile_buf.begin(), tile_buf.end(), 0);
          for (int64_t r = 0; r < rows; ++r) {
            std::memcpy(tile_buf.data() + r * tile * px,
                        slice.data() + ((y + r) * info.nx + x) * px, cols * px);
          }
          const uint32_t t =
              TIFFComputeTile(tif, static_cast<uint32_t>(x), static_cast<uint32_t>(y), 0, 0);
          ok = TIFFWriteEncodedTile(tif, t, tile_buf.data(),
                                    static_cast<tmsize_t>(tile_buf.size())) >= 0;
        }
      }
    } else {
      TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, rows_per_strip);
      for (int64_t row0 = 0, s = 0; ok && row0 < info.ny; row0 += rows_per_strip, ++s) {
        const int64_t rows = std::min<int64_t>(rows_per_strip, info.ny - row0);
        // libtiff may byte-swap this buffer in place; the slice is refilled next time anyway.
        ok = TIFFWriteEncodedStrip(tif, static_cast<uint32_t>(s), slice.data() + row0 * row_bytes,
                                   static_cast<tmsize_t>(rows * row_bytes)) >= 0;
      }
    }
    if (!ok || !TIFFWriteDirectory(tif)) {
      return absl::InternalError(
          absl::StrCat(path, ": writing page ", z, " failed: ", f.TakeErrors("libtiff error")));
    }
  }
  return f.Close();
}

}  // namespace tandem::io::internal

namespace tandem::io {

absl::StatusOr<std::unique_ptr<SliceSource>> OpenTiffSequence(
    const std::string& dir, const std::vector<std::string>& files) {
  if (files.size() < 2) {
    return absl::InvalidArgumentError(absl::StrCat(
        dir, ": a TIFF sequence needs at least 2 slice files, found ", files.size()));
  }
  TANDEM_ASSIGN_OR_RETURN(VolumeInfo first, internal::TiffSequenceInfo(files.front()));
  VolumeInfo info = std::move(first);
  info.nz = static_cast<int64_t>(files.size());
  info.description = absl::StrCat("TIFF sequence, ", files.size(), " files",
                                  info.description.empty() ? "" : ": ", info.description);
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("TIFF sequence in ", dir, ": ", st.message()));
  }
  return std::unique_ptr<SliceSource>(new internal::TiffSequenceSource(files, std::move(info)));
}

absl::Status WriteTiffSlice(const std::string& path, const VolumeInfo& info, int64_t z,
                            const std::vector<uint8_t>& bytes) {
  VolumeInfo one = info;
  one.nz = 1;
  one.origin[2] = info.origin[2] + static_cast<double>(z) * info.spacing[2];
  auto slice = [&bytes](int64_t, std::vector<uint8_t>* out) {
    *out = bytes;
    return absl::OkStatus();
  };
  return internal::WriteTiffVolume(path, one, slice, VolumeWriteOptions{});
}

absl::Status WriteTiffSequence(const std::string& dir, const VolumeInfo& info,
                               const SliceFn& slice_fn) {
  TANDEM_RETURN_IF_ERROR(ValidateVolumeInfo(info));
  if (info.nz < 2) return absl::InvalidArgumentError("WriteTiffSequence: nz must be known");
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return absl::InternalError(absl::StrCat(dir, ": cannot create: ", ec.message()));
  std::vector<uint8_t> bytes;
  for (int64_t z = 0; z < info.nz; ++z) {
    TANDEM_RETURN_IF_ERROR(internal::FetchSlice(dir, info, slice_fn, z, &bytes));
    char name[32];
    std::snprintf(name, sizeof(name), "slice_%05lld.tif", static_cast<long long>(z));
    if (absl::Status st = WriteTiffSlice((std::filesystem::path(dir) / name).string(), info, z, bytes);
        !st.ok()) {
      return st;
    }
  }
  return absl::OkStatus();
}

}  // namespace tandem::io
