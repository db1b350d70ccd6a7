#include "ViewFlags.h"

#include <chrono>
#include <cstdio>
#include <thread>

#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/live/IgtlServer.h"

namespace sonoslice {
namespace cli {

std::unique_ptr<ViewServer> start_view(const std::string& command, ViewContent content,
                                       const std::string& host_port,
                                       std::shared_ptr<LiveFeed> live) {
  std::string host = "127.0.0.1";
  int port = 0;
  parse_host_port(host_port, command == "sonoslice view" ? "--port" : "--view", host, port);
  auto server = std::make_unique<ViewServer>(std::move(content), host, port, std::move(live));
  std::printf("%s: %s\n", command.c_str(), server->url().c_str());
  std::fflush(stdout);
  return server;
}

void wait_for_interrupt() {
  StopOnSignals signals;
  while (!StopOnSignals::stop_requested().load())
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
}

}  // namespace cli
}  // namespace sonoslice
