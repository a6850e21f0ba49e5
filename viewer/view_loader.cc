// ViewServer::Start in the programs: loads libtandem_view.so (view_server.h) the first time
// and starts its server.
#include "absl/strings/str_cat.h"
#include "tandem/module/module_loader.h"
#include "tandem/viewer/view_server.h"

namespace tandem::viewer {

absl::StatusOr<std::unique_ptr<ViewServer>> ViewServer::Start(const ViewOptions& options) {
  using Loaded = absl::StatusOr<const ViewModule*>;
  static const Loaded loaded = []() -> Loaded {
    const ViewModule* module = nullptr;
    absl::StatusOr<void*> entry =
        module::LoadModuleEntry(kViewModuleName, kViewModuleEntryName, [&](void* e) {
          module = reinterpret_cast<ViewModuleEntry*>(e)();
          if (module != nullptr && module->abi == kViewModuleAbi) return absl::OkStatus();
          return absl::FailedPreconditionError(
              absl::StrCat("not this build's viewer module (expected ", kViewModuleEntryName,
                           " version ", kViewModuleAbi, ")"));
        });
    if (!entry.ok()) {
      return absl::FailedPreconditionError(absl::StrCat(
          "the browser viewer is not available: its module ", kViewModuleName,
          " (built and installed with tandem) could not be loaded: ", entry.status().message()));
    }
    return module;
  }();
  if (!loaded.ok()) return loaded.status();
  return (*loaded)->start(options);
}

}  // namespace tandem::viewer
