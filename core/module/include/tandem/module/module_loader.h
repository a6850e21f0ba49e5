// Modules: parts of the programs built as shared objects of their own and loaded the first
// time they are needed, so that a run that never needs them does not load their libraries:
//   libtandem_dicom.so  GDCM (io/dicom_codec.h): its dictionaries load at every start;
//   libtandem_view.so   the browser viewer's HTTP server (tandem/viewer/view_server.h): cpp-httplib
//                       and the OpenSSL and Brotli it links (docs/decisions.md 41, 43).
// A module is looked for next to the executable (the build tree's bin/), then in
// ../lib/tandem/ beside it (cmake --install, the container image). It is never unloaded
// (dlclose of a C++ library with statics is not worth it). Both sides are built together,
// with the same compiler and libraries, so a module's entry returns a table of C++ types;
// the caller checks the table's version (another build's module is refused, not used).
#ifndef TANDEM_MODULE_LOADER_H_
#define TANDEM_MODULE_LOADER_H_

#include <functional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace tandem::module {

// Where a module (or a helper program installed with the modules) named `name` is looked
// for, in order.
std::vector<std::string> ModulePlaces(const std::string& name);

// The address of the C function `entry` of the first `module` found whose entry `accept`
// takes (OK, or why not); otherwise NotFound whose message names every place tried and
// why it was not used ("DIR/libX.so: no such file; ...").
absl::StatusOr<void*> LoadModuleEntry(const std::string& module, const std::string& entry,
                                      const std::function<absl::Status(void*)>& accept);

}  // namespace tandem::module

#endif  // TANDEM_MODULE_LOADER_H_
