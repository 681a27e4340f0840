// Wire fuzz of the flight software's whole receive path: the Zenoh client session over a real
// loopback socket, and behind its subscriber the flight application's message checks and guidance
// step (FlightApp::receive_nav / handle_nav). 330 seeded cases, each a scripted peer thread:
//   junk          random bytes instead of a handshake (framed or not)
//   bad InitAck   a handshake reply with flipped bits or cut short
//   framed junk   a good handshake, then random length-prefixed batches, then a genuine nav
//   broken framing  a good handshake, then raw random bytes (the framing out of step), then silence
//   cut batch     a good handshake, then a batch announced longer than what follows, then silence
//   rvd fuzz      a good handshake, then well-framed samples carrying random, flipped, cut, untagged,
//                 oversized and NaN-bearing messages, then a genuine nav that must get its answer
// Every case must end (the session reports NotConnected: reconnection is off) within its bound, with
// no crash and nothing for the sanitizers to report (make asan runs this file too); in the rvd fuzz
// cases every bad message must be counted in exactly one drop counter.
#include <doctest/doctest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <optional>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "flight_sw/app/flight_app.hpp"

using namespace rvd;
using Buf = std::vector<uint8_t>;
using Clock = std::chrono::steady_clock;

namespace {

constexpr const char* kRun = "wire-fuzz";
constexpr const char* kNavKey = "rvd/wire-fuzz/nav";
constexpr int kCases = 330;
constexpr auto kCaseBound = std::chrono::seconds(5);  // every case must end within this

app::LinkKey fuzz_key() {
  app::LinkKey k{};
  for (size_t i = 0; i < k.size(); ++i) k[i] = static_cast<uint8_t>(7 * i + 3);
  return k;
}

int listen_loopback(uint16_t& port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
  REQUIRE(::listen(fd, 4) == 0);
  socklen_t len = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  port = ntohs(a.sin_port);
  return fd;
}

// The peer's side of one connection; every blocking call has a 3 s receive timeout.
struct PeerConn {
  int fd = -1;
  bool read_exact(uint8_t* p, size_t n) {
    while (n > 0) {
      const ssize_t r = ::recv(fd, p, n, 0);
      if (r <= 0) return false;
      p += r;
      n -= static_cast<size_t>(r);
    }
    return true;
  }
  bool read_batch(Buf& out) {
    uint8_t len[2];
    if (!read_exact(len, 2)) return false;
    out.resize(len[0] | (len[1] << 8));
    return read_exact(out.data(), out.size());
  }
  void raw(const Buf& b) { ::send(fd, b.data(), b.size(), MSG_NOSIGNAL); }
  void batch(const Buf& b) {
    Buf framed = {static_cast<uint8_t>(b.size() & 0xFF), static_cast<uint8_t>(b.size() >> 8)};
    framed.insert(framed.end(), b.begin(), b.end());
    raw(framed);
  }
  // Until the client closes (or 3 s): what a silent peer does.
  void wait_for_close() {
    uint8_t sink[4096];
    while (::recv(fd, sink, sizeof sink, 0) > 0) {
    }
  }
};

template <typename F>
Buf build(F&& f) {
  Buf b(70000);
  link::zenoh::Writer w(b.data(), b.size());
  f(w);
  b.resize(w.size());
  return b;
}

Buf random_bytes(std::mt19937& rng, size_t n) {
  Buf b(n);
  for (auto& x : b) x = static_cast<uint8_t>(rng());
  return b;
}

enum class Kind { Junk, BadInitAck, FramedJunk, BrokenFraming, CutBatch, RvdFuzz, Count };
const char* kind_name(Kind k) {
  switch (k) {
    case Kind::Junk: return "junk";
    case Kind::BadInitAck: return "bad InitAck";
    case Kind::FramedJunk: return "framed junk";
    case Kind::BrokenFraming: return "broken framing";
    case Kind::CutBatch: return "cut batch";
    case Kind::RvdFuzz: return "rvd fuzz";
    default: return "?";
  }
}

// The host's end of the rvd link, shared by all cases (its sequence numbers keep rising).
struct Host {
  app::LinkKey key = fuzz_key();
  msg::LinkAuth auth{key.data(), key.size(), kRun, msg::Role::Host};
  uint32_t next_step = 0;
  Buf genuine_nav() {
    const auto c = guidance::dissertation_case(1);
    msg::Nav n;
    n.step = next_step++;
    n.flags = n.step == 0 ? 1u : 0u;
    n.t_s = 30.0 * n.step;
    for (int i = 0; i < 3; ++i) {
      n.position_lvlh_m[i] = c.x0(i);
      n.velocity_lvlh_mps[i] = c.x0(3 + i);
    }
    n.q_lvlh_body = {c.q_lvlh_body.w(), c.q_lvlh_body.x(), c.q_lvlh_body.y(), c.q_lvlh_body.z()};
    Buf b(msg::Nav::kSize);
    REQUIRE(msg::seal(auth, n, b.data(), b.size()) == msg::Nav::kSize);
    return b;
  }
};

// The payloads of an rvd fuzz case: none of them may be taken. Returns how many.
std::vector<Buf> bad_payloads(std::mt19937& rng, Host& host) {
  std::vector<Buf> out;
  Buf genuine = host.genuine_nav();  // sealed, never sent as is: its number is used up, later ones are fine
  --host.next_step;
  const int n = 3 + static_cast<int>(rng() % 6);
  for (int i = 0; i < n; ++i) {
    Buf b;
    switch (rng() % 6) {
      case 0: b = random_bytes(rng, rng() % 300); break;
      case 1:  // flipped bits
        b = genuine;
        for (int f = 0, m = 1 + static_cast<int>(rng() % 4); f < m; ++f) b[rng() % b.size()] ^= static_cast<uint8_t>(1u << (rng() % 8));
        break;
      case 2: b.assign(genuine.begin(), genuine.begin() + static_cast<long>(rng() % genuine.size())); break;
      case 3: {  // the tagless protocol
        b = {'R', 'V', 'D', 1, 2, 0, static_cast<uint8_t>(msg::Nav::kBodySize), 0};
        b.insert(b.end(), genuine.begin() + msg::kHeaderSize, genuine.end() - msg::kTagSize);
        break;
      }
      case 4:  // oversized: in one batch, or fragmented beyond the client's reassembly cap
        b = random_bytes(rng, rng() % 2 ? msg::kMaxMessageSize + 1 + rng() % 3000 : 5000 + rng() % 15000);
        break;
      default: {  // authentic, with a NaN or Inf inside: the content is refused
        b.resize(msg::Nav::kSize);
        msg::Nav nav;
        nav.q_lvlh_body = {1.0, 0.0, 0.0, 0.0};
        REQUIRE(msg::encode(nav, b.data(), b.size()) == msg::Nav::kSize);
        uint8_t* p = b.data() + msg::kHeaderSize + 8 + 8 * (rng() % 14);
        msg::wire::put(p, rng() % 2 ? std::nan("") : HUGE_VAL);
        REQUIRE(host.auth.seal(b.data(), b.size()) == msg::Error::None);
        break;
      }
    }
    out.push_back(std::move(b));
  }
  return out;
}

struct Script {
  Kind kind;
  std::vector<Buf> bad;  // rvd fuzz: payloads to drop
  Buf genuine;           // a genuine nav sent after the fuzz (framed junk, rvd fuzz)
};

// One scripted connection, run by the peer thread.
void play(int server, const Script& s, std::mt19937 rng) {
  pollfd p{server, POLLIN, 0};
  if (::poll(&p, 1, 3000) <= 0) return;
  PeerConn c{::accept(server, nullptr, nullptr)};
  timeval tv{3, 0};
  ::setsockopt(c.fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  Buf in;
  auto finish = [&] {
    ::shutdown(c.fd, SHUT_WR);
    c.wait_for_close();
    ::close(c.fd);
  };
  if (s.kind == Kind::Junk) {
    c.read_batch(in);
    Buf junk = random_bytes(rng, 1 + rng() % 200);
    if (rng() % 2) c.batch(junk);
    else c.raw(junk);
    return finish();
  }
  link::zenoh::Zid zid;
  zid.size = 8;
  for (int i = 0; i < 8; ++i) zid.bytes[i] = static_cast<uint8_t>(i + 1);
  const Buf cookie = random_bytes(rng, 16);
  if (!c.read_batch(in)) return finish();  // InitSyn
  Buf ack = build([&](link::zenoh::Writer& w) {
    link::zenoh::encode_init_ack(w, zid, link::zenoh::whatami::Router, 0x0A, 4096, {cookie.data(), cookie.size()});
  });
  if (s.kind == Kind::BadInitAck) {
    if (rng() % 3 == 0) ack.resize(rng() % ack.size());
    else
      for (int f = 0, m = 1 + static_cast<int>(rng() % 3); f < m; ++f) ack[rng() % ack.size()] ^= static_cast<uint8_t>(1u << (rng() % 8));
    c.batch(ack);
    if (c.read_batch(in)) c.batch(random_bytes(rng, rng() % 20));  // the client went on: an OpenAck of junk
    return finish();
  }
  c.batch(ack);
  if (!c.read_batch(in)) return finish();  // OpenSyn
  const uint64_t sn0 = 500;
  c.batch(build([&](link::zenoh::Writer& w) { link::zenoh::encode_open_ack(w, 300, sn0); }));  // lease 300 ms
  if (!c.read_batch(in)) return finish();  // the DeclareSubscriber frame
  uint64_t sn = sn0;
  auto push = [&](const Buf& payload) {
    link::zenoh::PutFields put;
    put.payload = payload.data();
    put.size = payload.size();
    c.batch(build([&](link::zenoh::Writer& w) {
      link::zenoh::encode_frame_header(w, true, sn++);
      link::zenoh::encode_push_put(w, link::zenoh::WireExpr{0, kNavKey, false}, put);
    }));
  };
  switch (s.kind) {
    case Kind::FramedJunk:
      for (int i = 0, n = 1 + static_cast<int>(rng() % 6); i < n; ++i) c.batch(random_bytes(rng, rng() % 120));
      push(s.genuine);
      return finish();
    case Kind::BrokenFraming:
      c.raw(random_bytes(rng, 1 + rng() % 3000));
      return c.wait_for_close(), (void)::close(c.fd);
    case Kind::CutBatch: {
      const size_t announced = 200 + rng() % 3000;
      Buf cut = {static_cast<uint8_t>(announced & 0xFF), static_cast<uint8_t>(announced >> 8)};
      const Buf part = random_bytes(rng, rng() % 150);
      cut.insert(cut.end(), part.begin(), part.end());
      c.raw(cut);
      return c.wait_for_close(), (void)::close(c.fd);
    }
    case Kind::RvdFuzz:
      for (const Buf& b : s.bad) {
        if (b.size() + 64 > 4096 - 2) continue;  // larger than one batch of this peer: sent below, fragmented
        push(b);
      }
      for (const Buf& b : s.bad) {
        if (b.size() + 64 <= 4096 - 2) continue;
        link::zenoh::PutFields put;
        put.payload = b.data();
        put.size = b.size();
        const Buf whole = build([&](link::zenoh::Writer& w) {
          link::zenoh::encode_push_put(w, link::zenoh::WireExpr{0, kNavKey, false}, put);
        });
        for (size_t at = 0; at < whole.size(); at += 1000) {
          const size_t n = std::min<size_t>(1000, whole.size() - at);
          c.batch(build([&](link::zenoh::Writer& w) {
            link::zenoh::encode_fragment_header(w, true, at + n < whole.size(), sn++, false);
            w.raw(whole.data() + at, n);
          }));
        }
      }
      push(s.genuine);
      return finish();
    default: return finish();
  }
}

uint32_t drops(const app::InputCounters& d, const link::ZenohStats& z) {
  return d.malformed + d.oversized + d.untagged + d.wrong_run + d.bad_tag + d.replayed + d.future + d.stale +
         static_cast<uint32_t>(z.rx_oversized);
}

}  // namespace

TEST_CASE("wire fuzz: 330 seeded cases end within their bound, crash nothing, count every bad message") {
  uint16_t port = 0;
  const int server = listen_loopback(port);
  app::AppConfig cfg;
  cfg.run_id = kRun;
  cfg.link_key = fuzz_key();
  app::FlightApp app(cfg);
  Host host;
  int ended = 0, delivered = 0, resynced = 0;
  std::optional<uint32_t> last_answered;  // genuine navs go on from the last step the app answered
  double seconds_per_kind[static_cast<int>(Kind::Count)] = {};  // reported, not checked
  for (int i = 0; i < kCases; ++i) {
    const uint32_t seed = 20240 + static_cast<uint32_t>(i);
    std::mt19937 rng(seed);
    Script s{static_cast<Kind>(i % static_cast<int>(Kind::Count)), {}, {}};
    CAPTURE(seed);
    CAPTURE(kind_name(s.kind));
    host.next_step = last_answered ? *last_answered + 1 : 0;
    if (s.kind == Kind::RvdFuzz) s.bad = bad_payloads(rng, host);
    if (s.kind == Kind::RvdFuzz || s.kind == Kind::FramedJunk) s.genuine = host.genuine_nav();
    std::thread peer(play, server, std::cref(s), rng);

    link::ZenohConfig zc;
    zc.endpoint = "tcp/127.0.0.1:" + std::to_string(port);
    zc.connect_timeout_ms = 300;
    zc.rx_stall_ms = 50;
    zc.lease_ms = 1000;
    zc.max_reassembled_bytes = 4096;  // as the flight software sets it
    zc.reconnect.enabled = false;
    link::ZenohSession z(zc);
    int answered = 0;
    z.declare_subscriber(kNavKey, [&](const link::Sample& smp) {
      app.receive_nav(smp.payload, smp.size);
      if (auto nav = app.take_nav())
        if (auto cmd = app.handle_nav(*nav)) {
          ++answered;
          last_answered = cmd->step;
        }
    });
    const uint32_t drops_before = drops(app.dropped(), z.stats());
    const auto t0 = Clock::now();
    const auto deadline = t0 + kCaseBound;
    link::LinkStatus st = z.open();
    while (st != link::LinkStatus::NotConnected && Clock::now() < deadline) st = z.poll(50);
    const bool ended_in_time = st == link::LinkStatus::NotConnected;
    CHECK(ended_in_time);
    z.close();
    peer.join();
    ended += ended_in_time;
    seconds_per_kind[static_cast<int>(s.kind)] += std::chrono::duration<double>(Clock::now() - t0).count();
    delivered += answered;
    resynced += static_cast<int>(z.stats().resyncs);
    CHECK(z.stats().callback_exceptions == 0);
    if (s.kind == Kind::RvdFuzz) {
      CHECK(answered == 1);  // the genuine nav after the fuzz got its answer
      CHECK(drops(app.dropped(), z.stats()) - drops_before == s.bad.size());
      CHECK(z.stats().rx_rejected == 0);
    }
  }
  ::close(server);
  CHECK(ended == kCases);
  MESSAGE("wire fuzz: " << kCases << " cases ended in time, " << delivered << " genuine navs answered, "
                        << resynced << " resyncs; dropped by the app: malformed " << app.dropped().malformed
                        << ", oversized " << app.dropped().oversized << ", untagged " << app.dropped().untagged
                        << ", bad tag " << app.dropped().bad_tag << ", future " << app.dropped().future);
  for (int k = 0; k < static_cast<int>(Kind::Count); ++k)
    MESSAGE(std::string(kind_name(static_cast<Kind>(k))) << ": " << seconds_per_kind[k] << " s in all");
  CHECK(resynced > 0);
  CHECK(delivered >= kCases / 6);
}
