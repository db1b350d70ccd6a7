#pragma once
// The viewer's server as the commands start it: `sonoslice view` and the live commands' --view.
#include <memory>
#include <string>

#include "sonoslice/view/ViewServer.h"

namespace sonoslice {
namespace cli {

/// Starts the viewer on `host_port` ("[HOST:]PORT", host 127.0.0.1 unless given, port 0: a free
/// one) and prints the one line `<command>: http://HOST:PORT/` on stdout, flushed (scripts and
/// tests read the address from it). Error when this build has no viewer (no cpp-httplib).
std::unique_ptr<ViewServer> start_view(const std::string& command, ViewContent content,
                                       const std::string& host_port,
                                       std::shared_ptr<LiveFeed> live = nullptr);

/// Blocks until SIGINT or SIGTERM (StopOnSignals, Common.h).
void wait_for_interrupt();

}  // namespace cli
}  // namespace sonoslice
