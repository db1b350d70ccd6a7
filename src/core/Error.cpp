#include "sonoslice/core/Error.h"

#include <atomic>
#include <cstdio>

namespace sonoslice {
namespace {
void default_warning_handler(const std::string& message) {
  std::fprintf(stderr, "sonoslice: warning: %s\n", message.c_str());
}
std::atomic<WarningHandler> g_handler{&default_warning_handler};
}  // namespace

void set_warning_handler(WarningHandler handler) {
  g_handler.store(handler ? handler : &default_warning_handler);
}

void warn(const std::string& message) {
  g_handler.load()(message);
}

}  // namespace sonoslice
