// Loads libtandem_dicom.so (dicom_codec.h) the first time a DICOM file is read or written,
// and holds the executable's __assert_fail that turns a failed GDCM assertion into an error.
#include <dlfcn.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "dicom_codec.h"

namespace tandem::dicom {
namespace {

// Set once the module is loaded; read by __assert_fail on any thread.
std::atomic<const Codec*> g_codec{nullptr};

// Where the module is looked for: next to the executable (the build tree's bin/), then in
// ../lib/tandem/ beside it (cmake --install, the container image).
std::vector<std::string> Places() {
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) return {kModuleName};  // no /proc: the loader's own search path
  const std::filesystem::path dir = exe.parent_path();
  return {(dir / kModuleName).string(),
          (dir.parent_path() / "lib" / "tandem" / kModuleName).string()};
}

struct Loaded {
  const Codec* codec = nullptr;
  std::string error;
};

Loaded Load() {
  std::vector<std::string> problems;
  for (const std::string& place : Places()) {
    std::error_code ec;
    if (place.find('/') != std::string::npos && !std::filesystem::exists(place, ec)) {
      problems.push_back(absl::StrCat(place, ": no such file"));
      continue;
    }
    // RTLD_NOW: a missing GDCM library shows here, with its name, not at the first call.
    void* handle = dlopen(place.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
      const char* e = dlerror();
      problems.push_back(e != nullptr ? e : place + ": cannot be loaded");
      continue;
    }
    auto* entry = reinterpret_cast<CodecEntry*>(dlsym(handle, kCodecEntryName));
    const Codec* codec = entry != nullptr ? entry() : nullptr;
    if (codec == nullptr || codec->abi != kDicomCodecAbi) {
      problems.push_back(absl::StrCat(place, ": not this build's DICOM module (expected ",
                                      kCodecEntryName, " version ", kDicomCodecAbi, ")"));
      continue;  // never unloaded: dlclose of a C++ library with statics is not worth it
    }
    return {codec, ""};
  }
  return {nullptr, absl::StrJoin(problems, "; ")};
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
