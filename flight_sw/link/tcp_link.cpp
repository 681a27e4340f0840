// TCP batches for the Zenoh session (see tcp_link.hpp).
#include "flight_sw/link/tcp_link.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>

#include "flight_sw/link/semihosting.hpp"

namespace rvd::link {
namespace {

using Clock = std::chrono::steady_clock;

// A deadline of time_point::max() means no limit (a negative timeout).
Clock::time_point deadline_in(int timeout_ms) {
  return timeout_ms < 0 ? Clock::time_point::max() : Clock::now() + std::chrono::milliseconds(timeout_ms);
}

int ms_left(Clock::time_point deadline) {
  if (deadline == Clock::time_point::max()) return -1;
  const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
  return left.count() > 0 ? static_cast<int>(left.count()) : 0;
}

void set_error(std::string* error, const std::string& what) {
  if (error) *error = what;
}

std::string errno_text(const char* what) { return std::string(what) + ": " + std::strerror(errno); }

// Waits for `events` on fd until the deadline. 1 = ready, 0 = timed out, -1 = poll failed.
int wait_fd(int fd, short events, Clock::time_point deadline) {
  for (;;) {
    pollfd p{fd, events, 0};
    const int r = ::poll(&p, 1, ms_left(deadline));
    if (r >= 0) return r > 0 ? 1 : 0;
    if (errno != EINTR) return -1;
    if (deadline == Clock::time_point::max()) return 0;  // let an unlimited wait see the signal
  }
}

}  // namespace

const char* to_string(LinkStatus s) {
  switch (s) {
    case LinkStatus::Ok: return "Ok";
    case LinkStatus::Timeout: return "Timeout";
    case LinkStatus::InvalidArgument: return "InvalidArgument";
    case LinkStatus::MessageTooLarge: return "MessageTooLarge";
    case LinkStatus::NotConnected: return "NotConnected";
    case LinkStatus::Reconnecting: return "Reconnecting";
    case LinkStatus::ConnectFailed: return "ConnectFailed";
    case LinkStatus::HandshakeFailed: return "HandshakeFailed";
    case LinkStatus::LinkLost: return "LinkLost";
    case LinkStatus::LeaseExpired: return "LeaseExpired";
    case LinkStatus::ReconnectExhausted: return "ReconnectExhausted";
    case LinkStatus::Busy: return "Busy";
  }
  return "?";
}

const char* parse_tcp_endpoint(std::string_view text, TcpEndpoint& out) {
  constexpr std::string_view kSemihosting = "semihosting/";
  if (text.substr(0, kSemihosting.size()) == kSemihosting) {
    text.remove_prefix(kSemihosting.size());
    if (text.empty()) return "semihosting endpoint must name a host directory: semihosting/DIR";
    out = TcpEndpoint{};
    out.semihosting_dir.assign(text);
    return nullptr;
  }
  constexpr std::string_view kScheme = "tcp/";
  if (text.substr(0, kScheme.size()) != kScheme) return "endpoint must start with 'tcp/' or 'semihosting/'";
  text.remove_prefix(kScheme.size());
  const size_t meta = text.find('#');  // Zenoh locator metadata, not used by a client
  if (meta != std::string_view::npos) text = text.substr(0, meta);
  std::string_view host, port;
  if (!text.empty() && text.front() == '[') {
    const size_t close = text.find(']');
    if (close == std::string_view::npos || close + 1 >= text.size() || text[close + 1] != ':')
      return "IPv6 endpoint must look like tcp/[addr]:port";
    host = text.substr(1, close - 1);
    port = text.substr(close + 2);
  } else {
    const size_t colon = text.rfind(':');
    if (colon == std::string_view::npos) return "endpoint has no ':port'";
    host = text.substr(0, colon);
    port = text.substr(colon + 1);
  }
  if (host.empty()) return "endpoint has no host";
  if (port.empty() || port.size() > 5) return "endpoint port must be 1..65535";
  uint32_t value = 0;
  for (char c : port) {
    if (c < '0' || c > '9') return "endpoint port must be a number";
    value = value * 10 + static_cast<uint32_t>(c - '0');
  }
  if (value == 0 || value > 65535) return "endpoint port must be 1..65535";
  out.host.assign(host);
  out.port = static_cast<uint16_t>(value);
  out.semihosting_dir.clear();
  return nullptr;
}

TcpLink::TcpLink() : rx_(2 * (kPrefixSize + kMaxBatch)) {}

TcpLink::~TcpLink() { close(); }

void TcpLink::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  semihosting::close(semihosting_rx_);
  semihosting::close(semihosting_tx_);
  semihosting_rx_ = semihosting_tx_ = -1;
  rx_begin_ = rx_end_ = 0;
}

LinkStatus TcpLink::connect(const TcpEndpoint& endpoint, int timeout_ms, std::string* error) {
  close();
  if (!endpoint.semihosting_dir.empty()) {
    // The host's bridge opens to-guest for writing first, then from-guest for reading: same order.
    const std::string dir = "semihosting/" + endpoint.semihosting_dir + ": ";
    semihosting_rx_ = semihosting::open(endpoint.semihosting_dir + "/to-guest", false);
    if (semihosting_rx_ >= 0) semihosting_tx_ = semihosting::open(endpoint.semihosting_dir + "/from-guest", true);
    if (semihosting_tx_ < 0) {
      set_error(error, dir + semihosting::errno_text());
      close();
      return LinkStatus::ConnectFailed;
    }
    return LinkStatus::Ok;
  }
  const Clock::time_point deadline = deadline_in(timeout_ms);
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_NUMERICSERV;
  addrinfo* found = nullptr;
  const std::string port = std::to_string(endpoint.port);
  const int gai = ::getaddrinfo(endpoint.host.c_str(), port.c_str(), &hints, &found);
  if (gai != 0) {
    set_error(error, "cannot resolve '" + endpoint.host + "': " + ::gai_strerror(gai));
    return LinkStatus::ConnectFailed;
  }
  std::string last = "no address for '" + endpoint.host + "'";
  for (addrinfo* a = found; a && fd_ < 0; a = a->ai_next) {
    const int fd = ::socket(a->ai_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) {
      last = errno_text("socket");
      continue;
    }
    int r = ::connect(fd, a->ai_addr, a->ai_addrlen);
    if (r != 0 && errno == EINPROGRESS) {
      const int w = wait_fd(fd, POLLOUT, deadline);
      if (w <= 0) {
        last = w == 0 ? "connect timed out or interrupted after " + std::to_string(timeout_ms) + " ms"
                      : errno_text("poll");
        ::close(fd);
        continue;
      }
      int so_error = 0;
      socklen_t len = sizeof so_error;
      ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &so_error, &len);
      errno = so_error;
      r = so_error == 0 ? 0 : -1;
    }
    if (r != 0) {
      last = errno_text("connect");
      ::close(fd);
      continue;
    }
    const int one = 1;  // batches are already whole messages: do not wait to coalesce them
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    fd_ = fd;
  }
  ::freeaddrinfo(found);
  if (fd_ < 0) {
    set_error(error, "tcp/" + endpoint.host + ":" + port + ": " + last);
    return LinkStatus::ConnectFailed;
  }
  return LinkStatus::Ok;
}

LinkStatus TcpLink::send_batch(uint8_t* frame, size_t size, int timeout_ms, std::string* error) {
  if (!is_open()) return LinkStatus::NotConnected;
  if (size > kMaxBatch) {
    set_error(error, "batch of " + std::to_string(size) + " bytes exceeds the u16 length prefix");
    return LinkStatus::MessageTooLarge;
  }
  frame[0] = static_cast<uint8_t>(size & 0xFF);
  frame[1] = static_cast<uint8_t>(size >> 8);
  const size_t total = size + kPrefixSize;
  if (semihosting_tx_ >= 0) {
    if (semihosting::write(semihosting_tx_, frame, total)) return LinkStatus::Ok;
    set_error(error, "semihosting write: " + semihosting::errno_text());
    close();
    return LinkStatus::LinkLost;
  }
  const Clock::time_point deadline = deadline_in(timeout_ms);
  size_t sent = 0;
  while (sent < total) {
    const ssize_t n = ::send(fd_, frame + sent, total - sent, MSG_NOSIGNAL);
    if (n > 0) {
      sent += static_cast<size_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      const int w = wait_fd(fd_, POLLOUT, deadline);
      if (w > 0) continue;
      if (w == 0 && sent == 0) {
        set_error(error, "send timed out: the remote is not reading");
        return LinkStatus::Timeout;
      }
      set_error(error, w == 0 ? "send stalled in the middle of a batch" : errno_text("poll"));
      close();
      return LinkStatus::LinkLost;
    }
    set_error(error, errno_text("send"));
    close();
    return LinkStatus::LinkLost;
  }
  return LinkStatus::Ok;
}

LinkStatus TcpLink::receive_batch(const uint8_t*& data, size_t& size, int timeout_ms,
                                  std::string* error, int stall_ms) {
  if (!is_open()) return LinkStatus::NotConnected;
  const Clock::time_point deadline = deadline_in(timeout_ms);
  for (;;) {
    const size_t have = rx_end_ - rx_begin_;
    if (have >= kPrefixSize) {
      const size_t len = rx_[rx_begin_] | (static_cast<size_t>(rx_[rx_begin_ + 1]) << 8);
      if (have >= kPrefixSize + len) {
        data = rx_.data() + rx_begin_ + kPrefixSize;
        size = len;
        rx_begin_ += kPrefixSize + len;
        if (rx_begin_ < rx_end_) pending_since_ = Clock::now();  // the next batch has begun
        return LinkStatus::Ok;
      }
    }
    // Need more bytes: move the partial batch to the front (it is at most one batch long, so at
    // least one maximal batch of room remains).
    if (rx_begin_ > 0) {
      std::memmove(rx_.data(), rx_.data() + rx_begin_, have);
      rx_begin_ = 0;
      rx_end_ = have;
    }
    ssize_t n = 0;
    if (semihosting_rx_ >= 0) {
      if (timeout_ms == 0) return LinkStatus::Timeout;  // a read would block
      // Exactly the rest of this batch's prefix or body: how many batches the host has queued
      // must not change what the guest does (the bridge writes whole batches).
      const size_t want = have < kPrefixSize
                              ? kPrefixSize - have
                              : kPrefixSize + (rx_[0] | (static_cast<size_t>(rx_[1]) << 8)) - have;
      n = semihosting::read(semihosting_rx_, rx_.data() + rx_end_, want);
    } else {
      n = ::recv(fd_, rx_.data() + rx_end_, rx_.size() - rx_end_, 0);
    }
    if (n > 0) {
      if (have == 0) pending_since_ = Clock::now();
      rx_end_ += static_cast<size_t>(n);
      continue;
    }
    if (n == 0) {
      set_error(error, have ? "remote closed the stream in the middle of a batch"
                            : "remote closed the connection");
      close();
      return LinkStatus::LinkLost;
    }
    if (semihosting_rx_ >= 0) {
      set_error(error, "semihosting read: " + semihosting::errno_text());
      close();
      return LinkStatus::LinkLost;
    }
    if (errno == EINTR) continue;
    if (errno != EAGAIN && errno != EWOULDBLOCK) {
      set_error(error, errno_text("recv"));
      close();
      return LinkStatus::LinkLost;
    }
    // A batch that has begun must not keep the caller waiting past its stall limit.
    const Clock::time_point until = (stall_ms >= 0 && have > 0)
                                        ? std::min(deadline, pending_since_ + std::chrono::milliseconds(stall_ms))
                                        : deadline;
    const int w = wait_fd(fd_, POLLIN, until);
    if (w == 0) return LinkStatus::Timeout;
    if (w < 0) {
      set_error(error, errno_text("poll"));
      close();
      return LinkStatus::LinkLost;
    }
  }
}

}  // namespace rvd::link
