#pragma once
/// @file An OpenIGTLink endpoint: a TCP server that takes many clients (`--listen`) or a client of
/// one server (`--connect`, reconnecting when it goes away), with one thread doing every read and
/// write through poll(). Messages are parsed as they complete and handed to the caller; a
/// malformed message is counted with its reason and the connection goes on where the stream
/// still makes sense (a bad CRC, a bad body), or is closed where it cannot (a bad header, a body
/// over igtl::kMaxBodyBytes). Nothing a peer sends can make it allocate more than one message.
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "sonoslice/live/Igtl.h"

namespace sonoslice {

struct IgtlEndpointOptions {
  std::string host = "127.0.0.1";
  int port = 18944;      ///< 0 with listen: a free port (see IgtlEndpoint::port())
  bool listen = true;    ///< false: connect to host:port as a client
  int max_clients = 16;  ///< further connections are refused (counted)
};

/// "[HOST:]PORT" → host and port; InputError naming `flag` otherwise.
void parse_host_port(const std::string& text, const std::string& flag, std::string& host,
                     int& port);

class IgtlEndpoint {
 public:
  /// A complete, well-formed message from `client`; `arrival` is steady-clock seconds.
  using MessageHandler = std::function<void(int client, igtl::Message&& message, double arrival)>;

  /// Binds (listen) or starts connecting; throws InputError/Error naming host:port when the
  /// address cannot be used.
  explicit IgtlEndpoint(const IgtlEndpointOptions& options);
  ~IgtlEndpoint();
  IgtlEndpoint(const IgtlEndpoint&) = delete;
  IgtlEndpoint& operator=(const IgtlEndpoint&) = delete;

  int port() const;  ///< the bound port (listen) or the server's
  const IgtlEndpointOptions& options() const;

  /// One round: accepts, reads (only when `read` is true: false leaves the data in the
  /// peers' sockets, which is how a full queue pushes back on senders), writes what is queued,
  /// and calls `on_message` for each complete message. Waits at most `timeout_ms`.
  void poll(int timeout_ms, bool read, const MessageHandler& on_message);
  /// Queues `bytes` for `client` (written by poll(); a client that does not read is dropped
  /// once 256 MiB wait for it). Unknown clients are ignored.
  void send(int client, std::vector<uint8_t> bytes);
  void send_all(const std::vector<uint8_t>& bytes);
  /// Writes what is queued, for at most `timeout_ms`.
  void flush(int timeout_ms);
  int clients() const;

  /// Counts: "connections", "disconnects", "bytes", and per rejection reason
  /// ("rejected: a CRC that does not match its body", ...).
  const std::map<std::string, int64_t>& counts() const;
  int64_t rejected() const;
  /// Called by the message handler for messages it refuses (counted with the others).
  void reject(const std::string& reason);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace sonoslice
