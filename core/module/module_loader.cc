#include "tandem/module/module_loader.h"

#include <dlfcn.h>

#include <filesystem>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"

namespace tandem::module {

std::vector<std::string> ModulePlaces(const std::string& module) {
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) return {module};  // no /proc: the dynamic loader's own search path
  const std::filesystem::path dir = exe.parent_path();
  return {(dir / module).string(), (dir.parent_path() / "lib" / "tandem" / module).string()};
}

absl::StatusOr<void*> LoadModuleEntry(const std::string& module, const std::string& entry,
                                      const std::function<absl::Status(void*)>& accept) {
  std::vector<std::string> problems;
  for (const std::string& place : ModulePlaces(module)) {
    std::error_code ec;
    if (place.find('/') != std::string::npos && !std::filesystem::exists(place, ec)) {
      problems.push_back(absl::StrCat(place, ": no such file"));
      continue;
    }
    // RTLD_NOW: a missing library of the module shows here, with its name, not at a call.
    void* handle = dlopen(place.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
      const char* e = dlerror();
      problems.push_back(e != nullptr ? e : place + ": cannot be loaded");
      continue;
    }
    void* address = dlsym(handle, entry.c_str());
    const absl::Status st = address != nullptr
                                ? accept(address)
                                : absl::NotFoundError(absl::StrCat("no ", entry));
    if (!st.ok()) {
      problems.push_back(absl::StrCat(place, ": ", st.message()));
      continue;
    }
    return address;
  }
  return absl::NotFoundError(absl::StrJoin(problems, "; "));
}

}  // namespace tandem::module
