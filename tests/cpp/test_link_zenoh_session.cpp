// ZenohSession's API contract: bad configuration and keys are errors, not crashes; callbacks may
// put but not re-enter; a throwing callback is contained; close() inside a callback is deferred.
// Protocol fidelity is tested against the real eclipse-zenoh in tests/test_link_zenoh_*.py; the
// peer here is a scripted loopback socket that completes the handshake with the codec's
// peer-side encoders.
#include <doctest/doctest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <atomic>
#include <cstring>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "flight_sw/link/zenoh_session.hpp"

using namespace rvd::link;
using Buf = std::vector<uint8_t>;

namespace {

int listen_loopback(uint16_t& port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
  REQUIRE(::listen(fd, 2) == 0);
  socklen_t len = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  port = ntohs(a.sin_port);
  return fd;
}

// Blocking helpers for the peer thread (a 5 s receive timeout keeps it from hanging).
bool read_exact(int fd, uint8_t* p, size_t n) {
  while (n > 0) {
    const ssize_t r = ::recv(fd, p, n, 0);
    if (r <= 0) return false;
    p += r;
    n -= static_cast<size_t>(r);
  }
  return true;
}

bool read_batch(int fd, Buf& out) {
  uint8_t len[2];
  if (!read_exact(fd, len, 2)) return false;
  out.resize(len[0] | (len[1] << 8));
  return read_exact(fd, out.data(), out.size());
}

void send_batch(int fd, const Buf& b) {
  Buf framed = {static_cast<uint8_t>(b.size() & 0xFF), static_cast<uint8_t>(b.size() >> 8)};
  framed.insert(framed.end(), b.begin(), b.end());
  ::send(fd, framed.data(), framed.size(), MSG_NOSIGNAL);
}

template <typename F>
Buf build(F&& f) {
  Buf b(4096);
  zenoh::Writer w(b.data(), b.size());
  f(w);
  b.resize(w.size());
  return b;
}

}  // namespace

TEST_CASE("configuration, keys and calls without a link are reported, not crashed on") {
  ZenohConfig bad;
  bad.endpoint = "udp/127.0.0.1:7447";
  ZenohSession a(bad);
  CHECK(a.open() == LinkStatus::InvalidArgument);
  CHECK(a.last_error().find("tcp/") != std::string::npos);

  ZenohConfig cfg;
  cfg.batch_size = 32;
  ZenohSession b(cfg);
  CHECK(b.open() == LinkStatus::InvalidArgument);

  ZenohConfig timed_semihosting;  // a semihosting read cannot time out, so timed waits are refused
  timed_semihosting.endpoint = "semihosting//tmp/rvd-link";
  ZenohSession d(timed_semihosting);
  CHECK(d.open() == LinkStatus::InvalidArgument);
  CHECK(d.last_error().find("--untimed-link") != std::string::npos);

  ZenohConfig ok;
  ok.batch_size = 2048;
  ZenohSession c(ok);
  const uint8_t byte = 1;
  CHECK(c.put("rvd/x", &byte, 1) == LinkStatus::NotConnected);
  CHECK(c.declare_subscriber("rvd//x", [](const Sample&) {}) == LinkStatus::InvalidArgument);
  CHECK(c.declare_subscriber("rvd/x", nullptr) == LinkStatus::InvalidArgument);
  CHECK(c.declare_subscriber("rvd/*/x", [](const Sample&) {}) == LinkStatus::Ok);
  uint16_t id = 0;
  CHECK(c.declare_keyexpr("rvd/x", &id) == LinkStatus::Ok);
  CHECK(id == 1);
  CHECK(c.declare_keyexpr("rvd/x", &id) == LinkStatus::Ok);  // the same key keeps its id
  CHECK(id == 1);
  CHECK(c.poll(0) == LinkStatus::NotConnected);
  // Before the handshake the cap assumes the proposed batch and the widest SN: 2046 bytes of
  // batch minus frame (1 + 4), push (1 + scope 1), put (1) and the payload length (2).
  CHECK(c.max_put_payload("rvd/y") == 2046 - 5 - 1 - 1 - 6 - 1 - 2);
  CHECK(c.max_put_payload("rvd/x") == 2046 - 5 - 1 - 1 - 1 - 2);  // by declared id: no suffix
}

TEST_CASE("a refused connection with reconnection disabled ends in NotConnected") {
  uint16_t port = 0;
  ::close(listen_loopback(port));  // a free port nobody listens on
  ZenohConfig cfg;
  cfg.endpoint = "tcp/127.0.0.1:" + std::to_string(port);
  cfg.reconnect.enabled = false;
  ZenohSession z(cfg);
  CHECK(z.open() == LinkStatus::ConnectFailed);
  CHECK_FALSE(z.connected());
  CHECK(z.poll(10) == LinkStatus::NotConnected);
  CHECK(z.poll_until([] { return false; }, 50) == LinkStatus::NotConnected);
}

TEST_CASE("callbacks may put but not re-enter; exceptions are contained; close is deferred") {
  uint16_t port = 0;
  const int server = listen_loopback(port);
  std::atomic<bool> peer_ok{false};
  Buf put_seen, close_seen;
  std::thread peer([&] {
    const int fd = ::accept(server, nullptr, nullptr);
    timeval tv{5, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    Buf in;
    zenoh::Zid zid;
    zid.size = 4;
    zid.bytes[0] = 0x2a;
    const Buf cookie = {1, 2, 3};
    if (!read_batch(fd, in)) return;  // InitSyn
    send_batch(fd, build([&](zenoh::Writer& w) {
                 zenoh::encode_init_ack(w, zid, zenoh::whatami::Router, 0x0A, 4096,
                                        {cookie.data(), cookie.size()});
               }));
    if (!read_batch(fd, in)) return;  // OpenSyn
    send_batch(fd, build([](zenoh::Writer& w) { zenoh::encode_open_ack(w, 10000, 77); }));
    if (!read_batch(fd, in)) return;  // the DeclareSubscriber frame
    const Buf payload = {'n', 'a', 'v'};
    zenoh::PutFields put;
    put.payload = payload.data();
    put.size = payload.size();
    send_batch(fd, build([&](zenoh::Writer& w) {
                 zenoh::encode_frame_header(w, true, 77);
                 zenoh::encode_push_put(w, zenoh::WireExpr{0, "rvd/nav", true}, put);
               }));
    if (!read_batch(fd, put_seen)) return;    // the callback's put
    if (!read_batch(fd, close_seen)) return;  // the deferred close()
    peer_ok = true;
    ::close(fd);
  });

  ZenohConfig cfg;
  cfg.endpoint = "tcp/127.0.0.1:" + std::to_string(port);
  ZenohSession z(cfg);
  int calls = 0;
  LinkStatus inner_poll = LinkStatus::Ok, inner_declare = LinkStatus::Ok, inner_put = LinkStatus::Timeout;
  REQUIRE(z.declare_subscriber("rvd/nav", [&](const Sample& s) {
    ++calls;
    CHECK(s.key == "rvd/nav");
    CHECK(std::string(reinterpret_cast<const char*>(s.payload), s.size) == "nav");
    inner_poll = z.poll(0);
    inner_declare = z.declare_subscriber("rvd/other", [](const Sample&) {});
    const uint8_t reply[] = {'c', 'm', 'd'};
    inner_put = z.put("rvd/cmd", reply, sizeof reply);
    z.close();  // deferred until the callback returns
    throw std::runtime_error("guidance failed");
  }) == LinkStatus::Ok);
  REQUIRE(z.open() == LinkStatus::Ok);
  CHECK(z.link_info().batch_size == 4096);
  CHECK(z.link_info().remote_whatami == zenoh::whatami::Router);
  CHECK(z.poll_until([&] { return calls > 0; }, 5000) == LinkStatus::Ok);
  peer.join();
  ::close(server);

  CHECK(calls == 1);
  CHECK(inner_poll == LinkStatus::Busy);
  CHECK(inner_declare == LinkStatus::Busy);
  CHECK(inner_put == LinkStatus::Ok);
  CHECK(z.stats().callback_exceptions == 1);
  CHECK_FALSE(z.connected());
  CHECK(z.poll(0) == LinkStatus::NotConnected);  // closed by the app: no reconnection
  REQUIRE(peer_ok);
  const std::string put_text(put_seen.begin(), put_seen.end());
  CHECK(put_text.find("rvd/cmd") != std::string::npos);
  CHECK(put_seen.back() == 'd');
  CHECK(close_seen == Buf{0x23, 0x00});
}
