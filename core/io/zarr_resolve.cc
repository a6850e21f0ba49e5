// Zarr resolution: a store path and its selector (an array path, an OME-Zarr multiscale
// level) resolved to one array and its axes, scale and translation (zarr_metadata.h).
#include <algorithm>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "nlohmann/json.hpp"
#include "zarr_metadata.h"
#include "tandem/status_macros.h"

namespace tandem::io::internal::zarr {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

// The OME multiscales list of a group's attributes (v0.5 nests it under "ome").
const json* Multiscales(const json& attrs) {
  if (attrs.contains("multiscales") && attrs["multiscales"].is_array() &&
      !attrs["multiscales"].empty()) {
    return &attrs["multiscales"];
  }
  if (attrs.contains("ome") && attrs["ome"].is_object()) return Multiscales(attrs["ome"]);
  return nullptr;
}

// Applies a list of OME coordinateTransformations (scale, translation) after *s, *t.
absl::Status ApplyTransforms(const std::string& file, const json& list, size_t ndim,
                             std::vector<double>* s, std::vector<double>* t) {
  if (!list.is_array()) return absl::OkStatus();
  for (const json& tr : list) {
    if (!tr.is_object()) continue;
    const json type = tr.value("type", json());
    const char* key = type == "scale" ? "scale" : type == "translation" ? "translation" : nullptr;
    if (key == nullptr || !tr.contains(key)) continue;  // "identity", or by "path": ignored
    const json& v = tr[key];
    if (!v.is_array() || v.size() != ndim) {
      return MetaError(file, absl::StrCat("coordinateTransformations ", key, " ", v.dump(),
                                          " does not have one number per axis (", ndim, ")"));
    }
    for (size_t i = 0; i < ndim; ++i) {
      if (!v[i].is_number()) return MetaError(file, absl::StrCat(key, " must hold numbers"));
      const double x = v[i].get<double>();
      if (type == "scale") {
        (*s)[i] *= x;
        (*t)[i] *= x;
      } else {
        (*t)[i] += x;
      }
    }
  }
  return absl::OkStatus();
}

// `rel` (an array selector, or a multiscales dataset's path, named `what` in the error) as
// a path inside the group at `root`: relative, without "..", and inside it still once
// symlinks are resolved, so that metadata cannot send the reader elsewhere on the disk.
absl::StatusOr<std::string> InsideStore(const std::string& root, const std::string& rel,
                                        const std::string& what) {
  const fs::path p(rel);
  bool up = false;
  for (const fs::path& part : p) up = up || part == "..";
  const auto refuse = [&](absl::string_view why) {
    return absl::InvalidArgumentError(absl::StrCat(what, " '", rel, "' ", why, " (", root,
                                                   "); paths must stay inside the store"));
  };
  if (rel.empty() || p.is_absolute() || up) {
    return refuse(rel.empty() ? "is empty" : p.is_absolute() ? "is absolute" : "goes up with ..");
  }
  const fs::path joined = fs::path(root) / p;
  std::error_code ec_root, ec;
  const fs::path real_root = fs::weakly_canonical(root, ec_root);
  const fs::path real = fs::weakly_canonical(joined, ec);
  if (!ec_root && !ec) {
    auto [r, j] = std::mismatch(real_root.begin(), real_root.end(), real.begin(), real.end());
    if (r != real_root.end())
      return refuse(absl::StrCat("leads outside the group, to ", real.string()));
  }
  return joined.string();
}

bool AllDigits(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

absl::StatusOr<Resolved> ResolveMultiscale(const std::string& root, const Node& group,
                                           const std::string& level_sel,
                                           const std::string& path_sel);


}  // namespace

absl::StatusOr<Resolved> Resolve(const std::string& root, const std::string& selector) {
  TANDEM_ASSIGN_OR_RETURN(Node node, LoadNode(root));
  if (node.is_array) {
    if (!selector.empty()) {
      return absl::InvalidArgumentError(absl::StrCat(
          root, ": is a Zarr array, not a group: the selector '", selector, "' does not apply"));
    }
    Resolved r;
    r.array = std::move(node.array);
    r.what = absl::StrCat("Zarr v", r.array.version, " array");
    return r;
  }
  const json* ms = Multiscales(node.attrs);
  // A number is a level of the multiscale image (in a plain group, an array's name).
  if (selector.empty() || (AllDigits(selector) && ms != nullptr)) {
    if (ms == nullptr) {
      return absl::InvalidArgumentError(
          absl::StrCat(root,
                       ": is a Zarr group without OME-Zarr multiscales metadata; name an array "
                       "inside it as ",
                       root, "#PATH (tandem info/extract --zarr-array PATH)"));
    }
    return ResolveMultiscale(root, node, selector.empty() ? "0" : selector, "");
  }
  TANDEM_ASSIGN_OR_RETURN(std::string inside, InsideStore(root, selector, "array path"));
  const std::string sub = inside;
  TANDEM_ASSIGN_OR_RETURN(Node inner, LoadNode(sub));
  if (!inner.is_array) return Resolve(sub, "");
  // An array that is one of this group's levels keeps the level's scale and translation.
  if (ms != nullptr) {
    for (const json& ds : (*ms)[0].value("datasets", json::array())) {
      if (ds.is_object() && ds.value("path", json()) == selector) {
        return ResolveMultiscale(root, node, "", selector);
      }
    }
  }
  Resolved r;
  r.array = std::move(inner.array);
  r.what = absl::StrCat("Zarr v", r.array.version, " array '", selector, "'");
  return r;
}


namespace {

absl::StatusOr<Resolved> ResolveMultiscale(const std::string& root, const Node& group,
                                           const std::string& level_sel,
                                           const std::string& path_sel) {
  const std::string& file = group.attrs_file;
  const json& m = (*Multiscales(group.attrs))[0];
  if (!m.is_object() || !m.contains("datasets") || !m["datasets"].is_array() ||
      m["datasets"].empty()) {
    return MetaError(file, "multiscales[0] has no datasets");
  }
  const json& datasets = m["datasets"];
  size_t level = 0;
  if (path_sel.empty()) {
    uint64_t n = 0;
    if (!absl::SimpleAtoi(level_sel, &n) || n >= datasets.size()) {
      return absl::InvalidArgumentError(
          absl::StrCat(root, ": level ", level_sel, " does not exist (the image has ",
                       datasets.size(), " levels, 0..", datasets.size() - 1, ")"));
    }
    level = static_cast<size_t>(n);
  } else {
    level = datasets.size();
    for (size_t i = 0; i < datasets.size(); ++i) {
      if (datasets[i].is_object() && datasets[i].value("path", json()) == path_sel) level = i;
    }
  }
  Resolved r;
  std::string path;
  if (level < datasets.size()) {
    const json& ds = datasets[level];
    if (!ds.is_object() || !ds.contains("path") || !ds["path"].is_string()) {
      return MetaError(file, absl::StrCat("multiscales dataset ", level, " has no 'path'"));
    }
    path = ds["path"].get<std::string>();
  } else {
    path = path_sel;  // an array of the group that is not a level: no transforms
  }
  TANDEM_ASSIGN_OR_RETURN(
      std::string inside,
      InsideStore(root, path, absl::StrCat(file, ": multiscales dataset path")));
  TANDEM_ASSIGN_OR_RETURN(Node arr, LoadNode(inside));
  if (!arr.is_array) {
    return absl::InvalidArgumentError(
        absl::StrCat(root, ": multiscale dataset '", path, "' is not an array"));
  }
  r.array = std::move(arr.array);
  const size_t ndim = r.array.shape.size();
  if (m.contains("axes") && m["axes"].is_array()) {
    const json& axes = m["axes"];
    if (axes.size() != ndim) {
      return MetaError(file, absl::StrCat("multiscales axes list ", axes.size(),
                                          " axes but array '", path, "' has ", ndim));
    }
    for (const json& a : axes) {
      std::string name, type, unit;
      if (a.is_string()) {
        name = a.get<std::string>();  // v0.3: names only
      } else if (a.is_object()) {
        if (a.contains("name") && a["name"].is_string()) name = a["name"].get<std::string>();
        if (a.contains("type") && a["type"].is_string()) type = a["type"].get<std::string>();
        if (a.contains("unit") && a["unit"].is_string()) unit = a["unit"].get<std::string>();
      }
      r.axis_names.push_back(absl::AsciiStrToLower(name));
      r.axis_types.push_back(type);
      r.axis_units.push_back(unit);
    }
  }
  if (level < datasets.size()) {
    r.scale.assign(ndim, 1.0);
    r.translation.assign(ndim, 0.0);
    const json& ds = datasets[level];
    for (const json* list :
         {ds.contains("coordinateTransformations") ? &ds["coordinateTransformations"] : nullptr,
          m.contains("coordinateTransformations") ? &m["coordinateTransformations"] : nullptr}) {
      if (list == nullptr) continue;
      if (absl::Status st = ApplyTransforms(file, *list, ndim, &r.scale, &r.translation);
          !st.ok()) {
        return st;
      }
    }
  }
  std::string name;
  if (m.contains("name") && m["name"].is_string()) name = m["name"].get<std::string>();
  r.what = absl::StrCat("OME-Zarr image", name.empty() ? "" : " '", name, name.empty() ? "" : "'",
                        level < datasets.size() ? absl::StrCat(", level ", level) : "", " (array '",
                        path, "', Zarr v", r.array.version, ")");
  return r;
}

}  // namespace
}  // namespace tandem::io::internal::zarr
