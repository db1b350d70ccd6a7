// The OpenIGTLink endpoint: non-blocking sockets and poll(), one thread.
#include "sonoslice/live/IgtlServer.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <deque>

#include "../core/Clock.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace {

constexpr size_t kMaxPendingSend = size_t(256) << 20;

void set_nonblocking(int fd) {
  const int flags = fcntl(fd, F_GETFL, 0);
  fcntl(fd, F_SETFL, flags | O_NONBLOCK);
  const int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));  // frames are latency-bound
}

sockaddr_in address_of(const std::string& host, int port) {
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(uint16_t(port));
  if (inet_pton(AF_INET, host == "localhost" ? "127.0.0.1" : host.c_str(), &a.sin_addr) != 1) {
    addrinfo hints{}, *found = nullptr;
    hints.ai_family = AF_INET;
    if (getaddrinfo(host.c_str(), nullptr, &hints, &found) != 0 || !found)
      throw InputError(host + ":" + std::to_string(port) + ": unknown host");
    a.sin_addr = reinterpret_cast<sockaddr_in*>(found->ai_addr)->sin_addr;
    freeaddrinfo(found);
  }
  return a;
}

struct Connection {
  int fd = -1;
  int id = 0;
  bool connected = true;  // false while a client's connect() is in progress
  bool sent_anything = false;
  double last_active = now_seconds();  // the last byte in or out (or the accept)
  std::vector<uint8_t> in;             // the message being read: header, then header + body
  std::optional<igtl::Header> header;  // its header, parsed and checked once complete
  std::deque<std::vector<uint8_t>> out;
  size_t out_offset = 0, out_bytes = 0;
};

}  // namespace

void parse_host_port(const std::string& text, const std::string& flag, std::string& host,
                     int& port) {
  const size_t colon = text.rfind(':');
  const std::string p = colon == std::string::npos ? text : text.substr(colon + 1);
  if (colon != std::string::npos) host = text.substr(0, colon);
  char* end = nullptr;
  const long v = std::strtol(p.c_str(), &end, 10);
  if (p.empty() || *end != '\0' || v < 0 || v > 65535 || host.empty())
    throw InputError(flag + " " + text + ": expected [HOST:]PORT with a port 0-65535");
  port = int(v);
}

// How long a client must have been silent (nothing in or out) to make room for a newcomer when
// the server is at its client limit.
constexpr double kIdleAtLimitSeconds = 2.0;

struct IgtlEndpoint::Impl {
  IgtlEndpointOptions options;
  int listen_fd = -1;
  int port = 0;
  int next_id = 1;
  double next_connect = 0;
  std::vector<Connection> connections;
  std::map<std::string, int64_t> counts;
  int64_t rejected = 0;

  void count_reject(const std::string& reason) {
    ++counts["rejected: " + reason];
    ++rejected;
  }
  void close_connection(size_t k, const std::string& why) {
    Connection& c = connections[k];
    if (c.connected) {
      ++counts["disconnects"];
      if (!c.sent_anything) ++counts["connections that sent nothing"];
    }
    if (!why.empty()) count_reject(why);
    ::close(c.fd);
    connections.erase(connections.begin() + long(k));
  }
  void start_connect() {
    const int fd = socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0) return;
    set_nonblocking(fd);
    const sockaddr_in a = address_of(options.host, options.port);
    Connection c;
    c.fd = fd;
    c.id = next_id++;
    const int r = ::connect(fd, reinterpret_cast<const sockaddr*>(&a), sizeof(a));
    if (r != 0 && errno != EINPROGRESS) {
      ++counts[std::string("connect failed: ") + std::strerror(errno)];
      ::close(fd);
      next_connect = now_seconds() + 0.5;
      return;
    }
    c.connected = r == 0;
    if (c.connected) ++counts["connections"];
    connections.push_back(std::move(c));
  }
  // Reads what `c` has; false when the connection must close.
  bool read_from(size_t k, const MessageHandler& on_message, std::string& why);
  bool write_to(Connection& c);
};

IgtlEndpoint::IgtlEndpoint(const IgtlEndpointOptions& o) : impl_(std::make_unique<Impl>()) {
  Impl& im = *impl_;
  im.options = o;
  const std::string where = o.host + ":" + std::to_string(o.port);
  if (!o.listen) {
    if (o.port <= 0) throw InputError(where + ": give the server's port");
    im.port = o.port;
    im.start_connect();
    return;
  }
  const sockaddr_in a = address_of(o.host, o.port);
  im.listen_fd = socket(AF_INET, SOCK_STREAM, 0);
  if (im.listen_fd < 0) throw Error(where + ": cannot open a socket: " + std::strerror(errno));
  const int one = 1;
  setsockopt(im.listen_fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  if (bind(im.listen_fd, reinterpret_cast<const sockaddr*>(&a), sizeof(a)) != 0 ||
      ::listen(im.listen_fd, 16) != 0) {
    const std::string e = std::strerror(errno);
    ::close(im.listen_fd);
    throw InputError(where + ": cannot listen (" + e + ")");
  }
  set_nonblocking(im.listen_fd);
  sockaddr_in bound{};
  socklen_t len = sizeof(bound);
  getsockname(im.listen_fd, reinterpret_cast<sockaddr*>(&bound), &len);
  im.port = ntohs(bound.sin_port);
}

IgtlEndpoint::~IgtlEndpoint() {
  for (auto& c : impl_->connections) ::close(c.fd);
  if (impl_->listen_fd >= 0) ::close(impl_->listen_fd);
}

int IgtlEndpoint::port() const {
  return impl_->port;
}
const IgtlEndpointOptions& IgtlEndpoint::options() const {
  return impl_->options;
}
int IgtlEndpoint::clients() const {
  int n = 0;
  for (const auto& c : impl_->connections) n += c.connected;
  return n;
}
const std::map<std::string, int64_t>& IgtlEndpoint::counts() const {
  return impl_->counts;
}
int64_t IgtlEndpoint::rejected() const {
  return impl_->rejected;
}
void IgtlEndpoint::reject(const std::string& reason) {
  impl_->count_reject(reason);
}

bool IgtlEndpoint::Impl::read_from(size_t k, const MessageHandler& on_message, std::string& why) {
  uint8_t buffer[1 << 16];
  for (int rounds = 0; rounds < 64; ++rounds) {
    Connection& c = connections[k];
    // Read exactly up to the end of the current header or body, so a message never mixes
    // with the next and `in` never holds more than one message.
    const size_t want = igtl::kHeaderBytes + (c.header ? size_t(c.header->body_bytes) : size_t(0));
    const size_t n = std::min(sizeof(buffer), want - c.in.size());
    const ssize_t got = ::recv(c.fd, buffer, n, 0);
    if (got == 0) return false;  // the peer closed (mid-message or not: nothing is half-used)
    if (got < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
    c.sent_anything = true;
    c.last_active = now_seconds();
    counts["bytes"] += got;
    c.in.insert(c.in.end(), buffer, buffer + got);
    if (!c.header && c.in.size() == igtl::kHeaderBytes) {
      const igtl::Header h = igtl::parse_header(c.in.data());
      why = igtl::header_problem(h);
      if (!why.empty()) return false;  // the stream cannot be resynchronised after a bad header
      c.header = h;
      c.in.reserve(igtl::kHeaderBytes + size_t(h.body_bytes));
    }
    if (c.header && c.in.size() == igtl::kHeaderBytes + c.header->body_bytes) {
      igtl::Message m;
      const std::string problem = igtl::parse_body(*c.header, c.in.data() + igtl::kHeaderBytes,
                                                   size_t(c.header->body_bytes), m);
      const int id = c.id;
      c.in.clear();
      c.header.reset();
      if (!problem.empty())
        count_reject(problem);
      else
        on_message(id, std::move(m), now_seconds());
      return true;  // one message per round, so the caller can apply back-pressure
    }
  }
  return true;
}

bool IgtlEndpoint::Impl::write_to(Connection& c) {
  while (!c.out.empty()) {
    const auto& front = c.out.front();
    const ssize_t sent =
        ::send(c.fd, front.data() + c.out_offset, front.size() - c.out_offset, MSG_NOSIGNAL);
    if (sent < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
    c.last_active = now_seconds();
    c.out_offset += size_t(sent);
    if (c.out_offset == front.size()) {
      c.out_bytes -= front.size();
      c.out.pop_front();
      c.out_offset = 0;
    }
  }
  return true;
}

void IgtlEndpoint::poll(int timeout_ms, bool read, const MessageHandler& on_message) {
  Impl& im = *impl_;
  if (!im.options.listen && im.connections.empty() && now_seconds() >= im.next_connect)
    im.start_connect();
  std::vector<pollfd> fds;
  if (im.listen_fd >= 0) fds.push_back({im.listen_fd, POLLIN, 0});
  for (const auto& c : im.connections) {
    short events = 0;
    if (!c.connected || !c.out.empty()) events |= POLLOUT;
    if (c.connected && read) events |= POLLIN;
    fds.push_back({c.fd, events, 0});
  }
  if (::poll(fds.data(), nfds_t(fds.size()), timeout_ms) <= 0) return;
  size_t f = 0;
  if (im.listen_fd >= 0) {
    if (fds[f].revents & POLLIN) {
      for (;;) {
        const int fd = accept(im.listen_fd, nullptr, nullptr);
        if (fd < 0) break;
        // At the limit, a client idle for a while (nothing in or out) makes room: clients that
        // connect and then do nothing would otherwise lock every sender out for the whole run.
        if (clients() >= im.options.max_clients) {
          size_t idlest = im.connections.size();
          double oldest = now_seconds() - kIdleAtLimitSeconds;
          for (size_t k = 0; k < im.connections.size(); ++k)
            if (im.connections[k].last_active < oldest)
              oldest = im.connections[k].last_active, idlest = k;
          if (idlest == im.connections.size()) {
            ::close(fd);
            im.count_reject("a connection over the client limit");
            continue;
          }
          ++im.counts["dropped: an idle client at the client limit"];
          im.close_connection(idlest, "");
        }
        set_nonblocking(fd);
        Connection c;
        c.fd = fd;
        c.id = im.next_id++;
        im.connections.push_back(std::move(c));
        ++im.counts["connections"];
      }
    }
    ++f;
  }
  // Connections accepted in this round are not in `fds`; they are polled next round.
  const size_t polled = fds.size() - f;
  std::vector<int> ids;
  for (size_t k = 0; k < polled; ++k) ids.push_back(im.connections[k].id);
  for (size_t k = 0; k < polled; ++k, ++f) {
    size_t at = 0;
    while (at < im.connections.size() && im.connections[at].id != ids[k]) ++at;
    if (at == im.connections.size()) continue;
    const short ev = fds[f].revents;
    Connection& c = im.connections[at];
    if (!c.connected && (ev & (POLLOUT | POLLERR | POLLHUP))) {
      int err = 0;
      socklen_t len = sizeof(err);
      getsockopt(c.fd, SOL_SOCKET, SO_ERROR, &err, &len);
      if (err != 0 || (ev & (POLLERR | POLLHUP))) {
        ++im.counts[std::string("connect failed: ") +
                    (err != 0 ? std::strerror(err) : "the server hung up")];
        ::close(c.fd);
        im.connections.erase(im.connections.begin() + long(at));
        im.next_connect = now_seconds() + 0.5;  // the server is not there yet: try again
        continue;
      }
      c.connected = true;
      ++im.counts["connections"];
    }
    bool keep = true;
    std::string why;
    if (ev & POLLIN) keep = im.read_from(at, on_message, why);
    // The handler may have sent (and dropped a client that does not read): find it again.
    at = 0;
    while (at < im.connections.size() && im.connections[at].id != ids[k]) ++at;
    if (at == im.connections.size()) continue;
    if (keep && (ev & POLLOUT)) keep = im.write_to(im.connections[at]);
    if (keep && (ev & (POLLERR | POLLNVAL))) keep = false;
    if (keep && (ev & POLLHUP) && !(ev & POLLIN)) keep = false;
    if (!keep) {
      im.close_connection(at, why);
      if (!im.options.listen) im.next_connect = now_seconds() + 0.5;
    }
  }
}

void IgtlEndpoint::send(int client, std::vector<uint8_t> bytes) {
  for (size_t k = 0; k < impl_->connections.size(); ++k) {
    Connection& c = impl_->connections[k];
    if (c.id != client) continue;
    if (c.out_bytes + bytes.size() > kMaxPendingSend) {
      impl_->close_connection(k, std::string("a client that does not read what it is sent"));
      return;
    }
    c.out_bytes += bytes.size();
    c.out.push_back(std::move(bytes));
    impl_->write_to(c);
    return;
  }
}

void IgtlEndpoint::send_all(const std::vector<uint8_t>& bytes) {
  std::vector<int> ids;
  for (const auto& c : impl_->connections)
    if (c.connected) ids.push_back(c.id);
  for (int id : ids) send(id, bytes);
}

void IgtlEndpoint::flush(int timeout_ms) {
  const double end = now_seconds() + timeout_ms * 1e-3;
  for (;;) {
    bool pending = false;
    for (const auto& c : impl_->connections) pending |= !c.out.empty();
    const double left = end - now_seconds();
    if (!pending || left <= 0) return;
    poll(int(left * 1e3) + 1, false, {});
  }
}

}  // namespace sonoslice
