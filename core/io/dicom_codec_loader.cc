// Loads libtandem_dicom.so (dicom_codec.h) the first time a DICOM file is read or written,
// and holds the executable's __assert_fail that turns a failed GDCM assertion into an error.
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "absl/strings/str_cat.h"
#include "dicom_codec.h"
#include "module_loader.h"

namespace tandem::dicom {
namespace {

// Set once the module is loaded; read by __assert_fail on any thread.
std::atomic<const Codec*> g_codec{nullptr};

struct Loaded {
  const Codec* codec = nullptr;
  std::string error;
};

Loaded Load() {
  const Codec* codec = nullptr;
  absl::StatusOr<void*> entry = LoadModuleEntry(kModuleName, kCodecEntryName, [&](void* e) {
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
  static const Loaded loaded = [] {
    Loaded l = Load();
    g_codec.store(l.codec, std::memory_order_release);
    return l;
  }();
  if (loaded.codec == nullptr) {
    return absl::FailedPreconditionError(absl::StrCat(
        "DICOM support is not available: its module ", kModuleName,
        " (built and installed with tandem) could not be loaded: ", loaded.error));
  }
  return loaded.codec;
}

}  // namespace tandem::dicom

// Debian builds GDCM with assertions on (see dicom_codec.cc, GdcmGuarded). The executable's
// definition takes precedence over glibc's for every shared library, also the module's GDCM
// loaded later (it is exported: tandem_io's link option --export-dynamic-symbol). A failed
// assertion inside a guarded GDCM call jumps back to that call; any other prints glibc's
// message and aborts, as glibc's own __assert_fail does.
extern "C" void __assert_fail(const char* assertion, const char* file, unsigned int line,
                              const char* function) noexcept {
  if (const tandem::dicom::Codec* codec =
          tandem::dicom::g_codec.load(std::memory_order_acquire)) {
    codec->on_failed_assertion(assertion);  // returns only outside a guarded call
  }
  std::fprintf(stderr, "%s:%u: %s%sAssertion `%s' failed.\n", file, line,
               function ? function : "", function ? ": " : "", assertion);
  std::fflush(stderr);
  std::abort();
}
