// Loads libtandem_dicom.so (dicom_codec.h) the first time a DICOM file is written (files
// are read by tandem-dicom-worker: dicom_worker_client.h).
#include <string>

#include "absl/strings/str_cat.h"
#include "dicom_codec.h"
#include "tandem/module/module_loader.h"

namespace tandem::io::dicom {
namespace {

struct Loaded {
  const Codec* codec = nullptr;
  std::string error;
};

Loaded Load() {
  const Codec* codec = nullptr;
  absl::StatusOr<void*> entry = module::LoadModuleEntry(kModuleName, kCodecEntryName, [&](void* e) {
    codec = reinterpret_cast<CodecEntry*>(e)();
    if (codec != nullptr && codec->abi == kDicomCodecAbi) return absl::OkStatus();
    return absl::FailedPreconditionError(absl::StrCat(
        "not this build's DICOM module (expected ", kCodecEntryName, " version ",
        kDicomCodecAbi, ")"));
  });
  if (!entry.ok()) return {nullptr, std::string(entry.status().message())};
  return {codec, ""};
}

}  // namespace

absl::StatusOr<const Codec*> LoadCodec() {
  static const Loaded loaded = Load();
  if (loaded.codec == nullptr) {
    return absl::FailedPreconditionError(absl::StrCat(
        "DICOM support is not available: its module ", kModuleName,
        " (built and installed with tandem) could not be loaded: ", loaded.error));
  }
  return loaded.codec;
}

}  // namespace tandem::io::dicom
