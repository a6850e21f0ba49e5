// The GDCM side of the DICOM reader and writer (dicom_codec.h): built into libtandem_dicom.so,
// which tandem_io loads to write (dicom_codec_loader.cc), and into tandem-dicom-worker, the
// process that reads (dicom_worker.cc). Only what touches GDCM is here; the series' rules
// are in format_dicom.cc and tandem/series.h.
#include "dicom_codec.h"

#include <gdcmAttribute.h>
#include <gdcmDataSet.h>
#include <gdcmImageChangeTransferSyntax.h>
#include <gdcmImageReader.h>
#include <gdcmImageWriter.h>
#include <gdcmMediaStorage.h>
#include <gdcmReader.h>
#include <gdcmTrace.h>
#include <gdcmUIDGenerator.h>
#include <setjmp.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <mutex>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "dicom_scan.h"
#include "tandem/io/series.h"
#include "tandem/status_macros.h"

namespace tandem::io::dicom {
namespace {

// GDCM reports problems through gdcm::Trace on stderr; our errors carry the file names.
void SilenceGdcm() {
  static std::once_flag once;
  std::call_once(once, [] {
    gdcm::Trace::SetDebug(false);
    gdcm::Trace::SetWarning(false);
    gdcm::Trace::SetError(false);
  });
}

// Debian 12 builds GDCM with assertions on, and a corrupt file can trip one (fuzz_dicom found
// gdcm::ReadExplicitDataElement's assert(0 && "Should not happen") within seconds), which
// aborts the reading process. An exception cannot help (glibc declares __assert_fail
// noexcept, so unwinding from it terminates). So the reader's __assert_fail
// (dicom_worker.cc; it takes precedence over glibc's for GDCM's libraries) calls
// OnFailedAssertion, which jumps back to the GDCM call in progress on this thread, which
// reports the file as corrupt, naming the assertion; the reader then exits, since what the
// jump skipped (GDCM's objects of that call, ours inside the guarded lambda) is leaked. An
// assertion outside a guarded call prints glibc's message and aborts.
thread_local sigjmp_buf* t_gdcm_jump = nullptr;
thread_local const char* t_gdcm_assertion = nullptr;

// Runs f (which must keep what it needs after a jump outside its own frame) and turns a
// failed GDCM assertion or a GDCM exception into DataLoss naming the file.
template <typename F>
absl::Status GdcmGuarded(const std::string& path, F&& f) {
  SilenceGdcm();
  absl::Status st;
  sigjmp_buf here;
  sigjmp_buf* const outer = t_gdcm_jump;
  if (sigsetjmp(here, 0) != 0) {
    t_gdcm_jump = outer;
    return absl::DataLossError(absl::StrCat(
        path, ": corrupt DICOM file (GDCM's internal check '", t_gdcm_assertion, "' failed)"));
  }
  t_gdcm_jump = &here;
  try {
    st = f();
  } catch (const std::exception& e) {
    st = absl::DataLossError(absl::StrCat(path, ": corrupt DICOM file (GDCM: ", e.what(), ")"));
  }
  t_gdcm_jump = outer;
  return st;
}

template <uint16_t G, uint16_t E>
bool Has(const gdcm::DataSet& ds) {
  return ds.FindDataElement(gdcm::Tag(G, E)) && !ds.GetDataElement(gdcm::Tag(G, E)).IsEmpty();
}

std::string Trimmed(std::string s) {
  while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
  return std::string(absl::StripAsciiWhitespace(s));
}

// Outcome of reading one header: a slice, a file to skip (DICOMDIR), or an error.
absl::StatusOr<std::optional<SliceHeader>> ReadHeaderUnguarded(const std::string& path,
                                                               gdcm::Reader& reader) {
  reader.SetFileName(path.c_str());
  // Up to and including the pixel data element, whose value is skipped (not loaded).
  if (!reader.ReadUpToTag(gdcm::Tag(0x7fe0, 0x0010), {gdcm::Tag(0x7fe0, 0x0010)})) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": not a readable DICOM file (not DICOM, truncated or corrupt); a "
                           "series folder must hold only the series' files"));
  }
  const gdcm::File& file = reader.GetFile();
  const gdcm::DataSet& ds = file.GetDataSet();
  gdcm::MediaStorage ms;
  ms.SetFromFile(file);
  if (ms == gdcm::MediaStorage::MediaStorageDirectoryStorage) return std::nullopt;  // DICOMDIR

  SliceHeader h;
  h.path = path;
  {
    gdcm::Attribute<0x0020, 0x000e> a;
    a.SetFromDataSet(ds);
    h.series_uid = Trimmed(std::string(a.GetValue()));
  }
  if (!Has<0x0028, 0x0010>(ds) || !Has<0x0028, 0x0011>(ds)) {
    return absl::FailedPreconditionError(
        absl::StrCat(path, ": DICOM file without an image (no Rows/Columns)"));
  }
  {
    gdcm::Attribute<0x0028, 0x0010> rows;
    gdcm::Attribute<0x0028, 0x0011> cols;
    rows.SetFromDataSet(ds);
    cols.SetFromDataSet(ds);
    h.rows = rows.GetValue();
    h.cols = cols.GetValue();
  }
  if (Has<0x0020, 0x0013>(ds)) {
    gdcm::Attribute<0x0020, 0x0013> instance;
    instance.SetFromDataSet(ds);
    h.instance = instance.GetValue();
  }
  if (!Has<0x0020, 0x0032>(ds) || !Has<0x0020, 0x0037>(ds)) {
    return absl::FailedPreconditionError(absl::StrCat(
        path, ": no ImagePositionPatient / ImageOrientationPatient: the slices of this series "
              "cannot be placed in space (secondary capture or a localizer?)"));
  }
  {
    gdcm::Attribute<0x0020, 0x0032> ipp;
    gdcm::Attribute<0x0020, 0x0037> iop;
    ipp.SetFromDataSet(ds);
    iop.SetFromDataSet(ds);
    for (int i = 0; i < 3; ++i) h.position[i] = ipp.GetValue(i);
    for (int i = 0; i < 6; ++i) h.orientation[i] = iop.GetValue(i);
  }
  if (Has<0x0028, 0x0030>(ds)) {
    gdcm::Attribute<0x0028, 0x0030> ps;
    ps.SetFromDataSet(ds);
    h.row_spacing = ps.GetValue(0);
    h.col_spacing = ps.GetValue(1);
    h.has_spacing = true;
  }
  {
    gdcm::Attribute<0x0028, 0x0100> ba;
    gdcm::Attribute<0x0028, 0x0101> bs;
    gdcm::Attribute<0x0028, 0x0103> pr;
    ba.SetFromDataSet(ds);
    bs.SetFromDataSet(ds);
    pr.SetFromDataSet(ds);
    h.bits_allocated = ba.GetValue();
    h.bits_stored = Has<0x0028, 0x0101>(ds) ? bs.GetValue() : h.bits_allocated;
    h.pixel_representation = pr.GetValue();
  }
  if (Has<0x0028, 0x0002>(ds)) {
    gdcm::Attribute<0x0028, 0x0002> spp;
    spp.SetFromDataSet(ds);
    h.samples = spp.GetValue();
  }
  if (Has<0x0028, 0x0008>(ds)) {
    gdcm::Attribute<0x0028, 0x0008> nf;
    nf.SetFromDataSet(ds);
    h.frames = nf.GetValue();
  }
  if (Has<0x0028, 0x1053>(ds)) {
    gdcm::Attribute<0x0028, 0x1053> s;
    s.SetFromDataSet(ds);
    h.slope = s.GetValue();
  }
  if (Has<0x0028, 0x1052>(ds)) {
    gdcm::Attribute<0x0028, 0x1052> i;
    i.SetFromDataSet(ds);
    h.intercept = i.GetValue();
  }
  if (Has<0x0008, 0x0060>(ds)) {
    gdcm::Attribute<0x0008, 0x0060> m;
    m.SetFromDataSet(ds);
    h.modality = Trimmed(std::string(m.GetValue()));
  }
  if (Has<0x0008, 0x103e>(ds)) {
    gdcm::Attribute<0x0008, 0x103e> d;
    d.SetFromDataSet(ds);
    h.description = Trimmed(std::string(d.GetValue()));
  }
  if (Has<0x0008, 0x0008>(ds)) {
    const gdcm::ByteValue* v = ds.GetDataElement(gdcm::Tag(0x0008, 0x0008)).GetByteValue();
    if (v != nullptr) h.image_type = Trimmed(std::string(v->GetPointer(), v->GetLength()));
  }
  if (h.samples != 1) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": ", h.samples, " samples per pixel (colour); only greyscale series are supported"));
  }
  if (h.frames != 1) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": multi-frame image (", h.frames,
                     " frames); only series with one slice per file are supported"));
  }
  if (!(h.bits_allocated == 8 || h.bits_allocated == 16) ||
      (h.bits_allocated == 8 && h.pixel_representation != 0) || h.bits_stored < 1 ||
      h.bits_stored > h.bits_allocated) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": unsupported pixels: ", h.bits_allocated, " bits allocated, ", h.bits_stored,
        " stored, ", h.pixel_representation ? "signed" : "unsigned",
        " (supported: 8-bit unsigned, 16-bit signed or unsigned)"));
  }
  if (!std::isfinite(h.slope) || !std::isfinite(h.intercept) || h.slope == 0.0) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": invalid RescaleSlope ", h.slope,
                                                   " / RescaleIntercept ", h.intercept));
  }
  return h;
}

absl::StatusOr<std::optional<SliceHeader>> ReadHeader(const std::string& path) {
  // Depth, element count and lengths first (a declared length past the end of the file is a
  // slice still being written or cut short: GDCM would pad it silently).
  TANDEM_RETURN_IF_ERROR(ScanFile(path));
  std::optional<SliceHeader> header;
  absl::Status st = GdcmGuarded(path, [&]() -> absl::Status {
    auto* reader = new gdcm::Reader;  // leaked, not freed, if an assertion jumps out
    absl::StatusOr<std::optional<SliceHeader>> h = ReadHeaderUnguarded(path, *reader);
    delete reader;
    if (!h.ok()) return h.status();
    header = *std::move(h);
    return absl::OkStatus();
  });
  if (!st.ok()) return st;
  return header;
}

// An RLE frame is one fragment whose header (checked by ScanFile before GDCM decodes it)
// has one segment per byte of a sample (PS3.5 G.2): GDCM decodes other counts to garbage.
absl::Status CheckRle(const std::string& path, const gdcm::Image& image) {
  const gdcm::SequenceOfFragments* frags = image.GetDataElement().GetSequenceOfFragments();
  const gdcm::ByteValue* bv = frags != nullptr && frags->GetNumberOfFragments() == 1
                                  ? frags->GetFragment(0).GetByteValue()
                                  : nullptr;
  if (bv == nullptr || bv->GetLength() < 4) {
    return absl::DataLossError(
        absl::StrCat(path, ": corrupt RLE pixel data: a one-frame image has one fragment"));
  }
  uint32_t segments;
  std::memcpy(&segments, bv->GetPointer(), 4);  // little-endian, as the host
  const gdcm::PixelFormat& pf = image.GetPixelFormat();
  const uint32_t want = static_cast<uint32_t>(pf.GetSamplesPerPixel()) *
                        static_cast<uint32_t>((pf.GetBitsAllocated() + 7) / 8);
  if (segments != want) {
    return absl::DataLossError(absl::StrCat(path, ": corrupt RLE pixel data: ", segments,
                                            " segment(s), ", pf.GetBitsAllocated(),
                                            "-bit samples need ", want));
  }
  return absl::OkStatus();
}

absl::Status ReadPixelsUnguarded(const std::string& path, size_t stored_bytes,
                                 gdcm::ImageReader& reader, uint8_t* out) {
  reader.SetFileName(path.c_str());
  if (!reader.Read()) {
    return absl::DataLossError(
        absl::StrCat(path, ": cannot read the DICOM image (truncated or corrupt file?)"));
  }
  const gdcm::Image& image = reader.GetImage();
  if (image.GetBufferLength() != stored_bytes) {
    return absl::DataLossError(absl::StrCat(path, ": pixel data holds ",
                                            image.GetBufferLength(), " bytes, expected ",
                                            stored_bytes, " (truncated or corrupt file?)"));
  }
  const gdcm::ByteValue* raw = image.GetDataElement().GetByteValue();
  if (!image.GetTransferSyntax().IsEncapsulated() &&
      (raw == nullptr || raw->GetLength() < stored_bytes)) {
    return absl::DataLossError(absl::StrCat(
        path, ": pixel data is truncated (", raw ? static_cast<uint32_t>(raw->GetLength()) : 0u,
        " of ", stored_bytes, " bytes)"));
  }
  if (image.GetTransferSyntax() == gdcm::TransferSyntax::RLELossless) {
    TANDEM_RETURN_IF_ERROR(CheckRle(path, image));
  }
  if (!image.GetBuffer(reinterpret_cast<char*>(out))) {
    return absl::DataLossError(absl::StrCat(
        path, ": cannot decode the pixel data (transfer syntax ",
        gdcm::TransferSyntax::GetTSString(image.GetTransferSyntax()),
        "; truncated or corrupt, or a codec this GDCM build lacks)"));
  }
  return absl::OkStatus();
}

absl::Status ReadPixels(const std::string& path, size_t stored_bytes, uint8_t* out) {
  ScanResult scan;
  TANDEM_RETURN_IF_ERROR(ScanFile(path, {}, &scan));
  if (scan.pixel_bytes >= 0 && static_cast<uint64_t>(scan.pixel_bytes) < stored_bytes) {
    return absl::DataLossError(absl::StrCat(path, ": pixel data holds ", scan.pixel_bytes,
                                            " bytes, the image needs ", stored_bytes,
                                            " (truncated or corrupt file?)"));
  }
  return GdcmGuarded(path, [&]() -> absl::Status {
    auto* reader = new gdcm::ImageReader;  // leaked, not freed, if an assertion jumps out
    absl::Status st = ReadPixelsUnguarded(path, stored_bytes, *reader, out);
    delete reader;
    return st;
  });
}

std::string GenerateUid() {
  SilenceGdcm();
  gdcm::UIDGenerator uid;
  return uid.Generate();
}

absl::Status WriteSlice(const SliceImage& in) {
  SilenceGdcm();
  gdcm::PixelFormat pf = in.bits_allocated == 8 ? gdcm::PixelFormat::UINT8
                         : in.is_signed         ? gdcm::PixelFormat::INT16
                                                : gdcm::PixelFormat::UINT16;
  const size_t n = static_cast<size_t>(in.nx) * static_cast<size_t>(in.ny);
  gdcm::ImageWriter writer;
  gdcm::Image& image = writer.GetImage();
  image.SetNumberOfDimensions(2);
  image.SetDimension(0, static_cast<unsigned int>(in.nx));
  image.SetDimension(1, static_cast<unsigned int>(in.ny));
  if (in.bits_stored > 0 && in.bits_stored < pf.GetBitsAllocated()) {
    pf.SetBitsStored(static_cast<unsigned short>(in.bits_stored));
    pf.SetHighBit(static_cast<unsigned short>(in.bits_stored - 1));
  }
  image.SetPixelFormat(pf);
  image.SetPhotometricInterpretation(gdcm::PhotometricInterpretation::MONOCHROME2);
  for (unsigned int i = 0; i < 3; ++i) image.SetSpacing(i, in.spacing[i]);
  for (unsigned int i = 0; i < 3; ++i) image.SetOrigin(i, in.origin[i]);
  image.SetDirectionCosines(in.cosines.data());
  image.SetSlope(in.slope);
  image.SetIntercept(in.intercept);
  gdcm::DataElement pixel_data(gdcm::Tag(0x7fe0, 0x0010));
  pixel_data.SetByteValue(reinterpret_cast<const char*>(in.pixels),
                          static_cast<uint32_t>(n * pf.GetPixelSize()));
  image.SetDataElement(pixel_data);
  image.SetTransferSyntax(gdcm::TransferSyntax::ExplicitVRLittleEndian);

  gdcm::TransferSyntax::TSType ts = gdcm::TransferSyntax::ExplicitVRLittleEndian;
  switch (static_cast<DicomSyntax>(in.syntax)) {
    case DicomSyntax::kExplicitLittle:
      break;
    case DicomSyntax::kImplicitLittle:
      ts = gdcm::TransferSyntax::ImplicitVRLittleEndian;
      break;
    case DicomSyntax::kJpegLossless:
      ts = gdcm::TransferSyntax::JPEGLosslessProcess14_1;
      break;
    case DicomSyntax::kJpegLs:
      ts = gdcm::TransferSyntax::JPEGLSLossless;
      break;
    case DicomSyntax::kJpeg2000:
      ts = gdcm::TransferSyntax::JPEG2000Lossless;
      break;
    case DicomSyntax::kRle:
      ts = gdcm::TransferSyntax::RLELossless;
      break;
  }
  if (ts != gdcm::TransferSyntax::ExplicitVRLittleEndian) {
    gdcm::ImageChangeTransferSyntax change;
    change.SetTransferSyntax(ts);
    change.SetInput(image);
    if (!change.Change()) {
      return absl::InternalError(absl::StrCat(in.path, ": GDCM cannot encode transfer syntax ",
                                              gdcm::TransferSyntax::GetTSString(ts)));
    }
    writer.SetImage(change.GetOutput());
  }

  gdcm::DataSet& ds = writer.GetFile().GetDataSet();
  auto put = [&ds](uint16_t g, uint16_t e, const std::string& v, gdcm::VR vr) {
    gdcm::DataElement de(gdcm::Tag(g, e));
    std::string s = v;
    if (s.size() % 2 == 1) s.push_back(vr == gdcm::VR::UI ? '\0' : ' ');
    de.SetVR(vr);
    de.SetByteValue(s.data(), static_cast<uint32_t>(s.size()));
    ds.Replace(de);
  };
  const gdcm::MediaStorage ms =
      in.ct ? gdcm::MediaStorage::CTImageStorage : gdcm::MediaStorage::MRImageStorage;
  put(0x0008, 0x0016, gdcm::MediaStorage::GetMSString(ms), gdcm::VR::UI);
  gdcm::UIDGenerator uid;
  put(0x0008, 0x0018, uid.Generate(), gdcm::VR::UI);
  put(0x0008, 0x0060, in.ct ? "CT" : in.modality, gdcm::VR::CS);
  put(0x0008, 0x103e, in.series_description, gdcm::VR::LO);
  put(0x0010, 0x0010, "TANDEM^PHANTOM", gdcm::VR::PN);
  put(0x0010, 0x0020, "TANDEM0001", gdcm::VR::LO);
  put(0x0020, 0x000d, in.study_uid, gdcm::VR::UI);
  put(0x0020, 0x000e, in.series_uid, gdcm::VR::UI);
  if (in.instance >= 0) {
    put(0x0020, 0x0013, std::to_string(in.instance), gdcm::VR::IS);
  } else {
    ds.Remove(gdcm::Tag(0x0020, 0x0013));
  }
  if (!in.image_type.empty()) put(0x0008, 0x0008, in.image_type, gdcm::VR::CS);
  put(0x0018, 0x0050, in.slice_thickness, gdcm::VR::DS);
  writer.SetFileName(in.path.c_str());
  if (!writer.Write()) return absl::InternalError(absl::StrCat(in.path, ": GDCM could not write it"));
  return absl::OkStatus();
}

// See GdcmGuarded.
void OnFailedAssertion(const char* assertion) {
  if (t_gdcm_jump == nullptr) return;
  t_gdcm_assertion = assertion;
  siglongjmp(*t_gdcm_jump, 1);
}

constexpr Codec kCodec{kDicomCodecAbi, &ReadHeader, &ReadPixels, &WriteSlice, &GenerateUid,
                       &OnFailedAssertion};

}  // namespace
}  // namespace tandem::io::dicom

extern "C" __attribute__((visibility("default"))) const tandem::io::dicom::Codec*
tandem_dicom_codec() {
  return &tandem::io::dicom::kCodec;
}
