#pragma once
// The page files (src/view/web/), compiled into the binary so that the viewer needs nothing
// beside it: no install path to find, no CDN.
#include <cstddef>
#include <string>

namespace sonoslice {

struct WebAsset {
  const char* data;
  size_t size;
  const char* mime;
};

/// The file `name` ("index.html", "view.js", ...) of src/view/web/, or null.
const WebAsset* find_web_asset(const std::string& name);

}  // namespace sonoslice
