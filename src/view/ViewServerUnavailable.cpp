// sonoslice built without cpp-httplib (the GPU machine has no Debian packages): the viewer's
// server says so; everything else of the viewer (ViewModel.cpp) is there.
#include "sonoslice/core/Error.h"
#include "sonoslice/view/ViewServer.h"

namespace sonoslice {

struct ViewServer::Impl {};

ViewServer::ViewServer(ViewContent, const std::string&, int, std::shared_ptr<LiveFeed>) {
  throw Error(
      "view: this sonoslice was built without its viewer (it needs cpp-httplib: Debian's "
      "libcpp-httplib-dev)");
}
ViewServer::~ViewServer() = default;
int ViewServer::port() const {
  return 0;
}
std::string ViewServer::url() const {
  return {};
}
void ViewServer::stop() {}

}  // namespace sonoslice
