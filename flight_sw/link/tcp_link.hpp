// The TCP layer under the Zenoh session: connect with a timeout, TCP_NODELAY, length-prefixed
// batches (u16 little-endian length, then the batch: see flight_sw/link/README.md), non-blocking socket
// with poll()-based waits. The same byte stream can also run through ARM semihosting
// ("semihosting/<host dir>": two FIFOs on the host, <dir>/to-guest and <dir>/from-guest, that
// rvd_pil/qemu/semihosting_link.py joins to the host's TCP endpoint), for QEMU system-mode runs whose guest
// clock must stand still while the host computes (semihosting.hpp). Every call takes a timeout
// (negative: wait without limit); semihosting reads can only wait without limit or not at all.
// The receive buffer is allocated once.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace rvd::link {

// Result of every link and session call. Errors are values; details are in a text message.
enum class LinkStatus : uint8_t {
  Ok,
  Timeout,             // nothing arrived (or could be written) in the time given
  InvalidArgument,     // bad endpoint, key expression or parameter
  MessageTooLarge,     // the message does not fit one batch of the negotiated size
  NotConnected,        // no session: never opened, closed, or lost with reconnection disabled
  Reconnecting,        // the link is down; poll() retries on the reconnect schedule
  ConnectFailed,       // TCP connect refused, unreachable or timed out
  HandshakeFailed,     // the remote refused the session (Close) or answered wrongly or too late
  LinkLost,            // TCP closed or failed, the remote sent Close, or a send stalled mid-batch
  LeaseExpired,        // nothing received from the remote for its whole lease
  ReconnectExhausted,  // the reconnect schedule ran out; open() starts over
  Busy,                // called from inside a subscriber callback where that is not allowed
};
const char* to_string(LinkStatus s);

struct TcpEndpoint {
  std::string host;
  uint16_t port = 0;
  std::string semihosting_dir;  // semihosting/<dir>: the stream runs through host FIFOs instead
};
// Parses "tcp/<host>:<port>" ("tcp/[::1]:7447" for IPv6) or "semihosting/<host dir>"
// ("semihosting//tmp/rvd-link"; a relative one is relative to the emulator's working directory).
// nullptr when valid, else why not.
const char* parse_tcp_endpoint(std::string_view text, TcpEndpoint& out);

class TcpLink {
 public:
  static constexpr size_t kPrefixSize = 2;     // the u16 length in front of every batch
  static constexpr size_t kMaxBatch = 65535;   // the largest length the prefix can state

  TcpLink();
  ~TcpLink();
  TcpLink(const TcpLink&) = delete;
  TcpLink& operator=(const TcpLink&) = delete;

  // Resolves the host, connects within timeout_ms, sets TCP_NODELAY (semihosting: opens the two
  // FIFOs, waiting for the host's end without limit). Closes any previous connection.
  LinkStatus connect(const TcpEndpoint& endpoint, int timeout_ms, std::string* error);

  // Sends one batch. `frame` holds kPrefixSize free bytes followed by `size` batch bytes; the
  // length prefix is written into them. Timeout means nothing was written (the stream is intact);
  // a stall after a partial write is LinkLost, since the stream can no longer be resynchronised.
  LinkStatus send_batch(uint8_t* frame, size_t size, int timeout_ms, std::string* error);

  // Waits up to timeout_ms (0 = only what is already there; negative = without limit; semihosting:
  // any nonzero timeout waits without limit) for one whole batch. On Ok, `data`
  // and `size` view it inside the link's buffer until the next receive_batch() or connect().
  // stall_ms >= 0 also ends the wait (Timeout) once a batch has been incomplete for that long
  // (pending_since()), so that the caller can tell a corrupted length from a quiet link.
  LinkStatus receive_batch(const uint8_t*& data, size_t& size, int timeout_ms, std::string* error,
                           int stall_ms = -1);

  void close();
  bool is_open() const { return fd_ >= 0 || semihosting_rx_ >= 0; }
  // Bytes received but not yet handed out as a whole batch (a batch still arriving), and since when.
  size_t pending_bytes() const { return rx_end_ - rx_begin_; }
  std::chrono::steady_clock::time_point pending_since() const { return pending_since_; }

 private:
  int fd_ = -1;
  long semihosting_rx_ = -1, semihosting_tx_ = -1;  // host handles of to-guest and from-guest
  std::vector<uint8_t> rx_;  // two maximal batches, so one recv() can fetch several batches
  size_t rx_begin_ = 0, rx_end_ = 0;
  std::chrono::steady_clock::time_point pending_since_{};
};

}  // namespace rvd::link
