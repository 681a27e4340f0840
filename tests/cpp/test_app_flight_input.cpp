// What the flight software takes from the link and what it drops: only this run's tagged, fresh
// messages; navs in step order (duplicates answered from the cache, stale ones and ones far ahead
// dropped, never adopted); navs overtaken before they were handled counted as coalesced. Every drop
// is counted by reason in telemetry. The input path (check, decode, step, answer) allocates nothing.
#include <doctest/doctest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>
#include <stdexcept>
#include <vector>

#include "flight_sw/app/flight_app.hpp"

// GCC 12 inlines the counting operator new below into std::vector and then warns about sizes it
// cannot see (known false positives of -Wstringop-overflow/-overread).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wstringop-overflow"
#pragma GCC diagnostic ignored "-Wstringop-overread"
#endif

namespace {
std::atomic<long> g_news{0};
}  // namespace

void* operator new(std::size_t n) {
  ++g_news;
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

using namespace rvd;
using Bytes = std::vector<uint8_t>;

namespace {

constexpr const char* kRun = "input-test";

app::LinkKey test_key() {
  app::LinkKey k{};
  for (size_t i = 0; i < k.size(); ++i) k[i] = static_cast<uint8_t>(0xA0 + i);
  return k;
}

app::AppConfig config() {
  app::AppConfig c;
  c.run_id = kRun;
  c.link_key = test_key();
  return c;
}

// The host's end of the link: seals what it sends as the real host does.
struct Host {
  app::LinkKey key = test_key();
  msg::LinkAuth auth{key.data(), key.size(), kRun, msg::Role::Host};

  msg::Nav nav(uint32_t step) const {
    const auto c = guidance::dissertation_case(1);
    msg::Nav n;
    n.step = step;
    n.flags = step == 0 ? 1u : 0u;
    n.t_s = 30.0 * step;
    for (int i = 0; i < 3; ++i) {
      n.position_lvlh_m[i] = c.x0(i);
      n.velocity_lvlh_mps[i] = c.x0(3 + i);
    }
    n.q_lvlh_body = {c.q_lvlh_body.w(), c.q_lvlh_body.x(), c.q_lvlh_body.y(), c.q_lvlh_body.z()};
    return n;
  }
  template <class M> Bytes seal(const M& m) {
    Bytes b(M::kSize);
    REQUIRE(msg::seal(auth, m, b.data(), b.size()) == M::kSize);
    return b;
  }
};

// Delivers a message to the app as the link would and runs the step: the cmd, or nullopt.
std::optional<msg::Cmd> step(app::FlightApp& a, const Bytes& b) {
  a.receive_nav(b.data(), b.size());
  auto nav = a.take_nav();
  return nav ? a.handle_nav(*nav) : std::nullopt;
}

}  // namespace

TEST_CASE("navs are taken in step order; duplicates, stale navs and navs far ahead are counted, never adopted") {
  app::FlightApp a(config());
  Host h;
  REQUIRE(step(a, h.seal(h.nav(0))));
  auto again = step(a, h.seal(h.nav(0)));  // a resend (a new message of the same step)
  REQUIRE(again);
  CHECK(again->step == 0);
  CHECK(a.dropped().duplicates == 1);
  REQUIRE(step(a, h.seal(h.nav(1))));
  msg::Nav old = h.nav(0);
  old.flags = 0;
  CHECK_FALSE(step(a, h.seal(old)));  // older than what was answered
  CHECK(a.dropped().stale == 1);
  // Authentic but far ahead (the host never skips steps): dropped, and nothing is wedged.
  CHECK_FALSE(step(a, h.seal(h.nav(1 + 17))));
  CHECK_FALSE(step(a, h.seal(h.nav(0xFFFFFFFFu))));
  CHECK(a.dropped().future == 2);
  auto next = step(a, h.seal(h.nav(2)));
  REQUIRE(next);
  CHECK(next->step == 2);
  CHECK(step(a, h.seal(h.nav(2 + 16))));  // within max_step_ahead: taken (navs may be lost in between)
  CHECK(a.dropped().stale == 1);
  const msg::Telemetry t = a.telemetry();
  CHECK(t.nav_duplicates == 1);
  CHECK(t.nav_stale == 1);
  CHECK(t.nav_future == 2);
}

TEST_CASE("a run starts at step 0 with the first-step flag, nothing before it is answered") {
  app::FlightApp a(config());
  Host h;
  CHECK_FALSE(step(a, h.seal(h.nav(3))));  // no run started yet
  msg::Nav bogus_start = h.nav(5);
  bogus_start.flags = 1;
  CHECK_FALSE(step(a, h.seal(bogus_start)));
  CHECK(a.dropped().future == 2);
  CHECK(step(a, h.seal(h.nav(0))));
}

TEST_CASE("navs overtaken before they were handled are counted as coalesced; the newest is taken") {
  app::FlightApp a(config());
  Host h;
  for (uint32_t k : {0u, 1u, 2u}) {
    const Bytes b = h.seal(h.nav(k));
    a.receive_nav(b.data(), b.size());
  }
  CHECK(a.dropped().coalesced == 2);
  auto nav = a.take_nav();
  REQUIRE(nav);
  CHECK(nav->step == 2);
  CHECK_FALSE(a.take_nav());
  CHECK(a.telemetry().nav_coalesced == 2);
}

TEST_CASE("untagged, mistagged, replayed, other runs' and oversized messages are dropped by kind") {
  app::FlightApp a(config());
  Host h;
  const Bytes genuine = h.seal(h.nav(0));
  Bytes v1 = {'R', 'V', 'D', 1, 2, 0, static_cast<uint8_t>(msg::Nav::kBodySize), 0};
  v1.insert(v1.end(), genuine.begin() + msg::kHeaderSize, genuine.end() - msg::kTagSize);
  Bytes bad_tag = genuine;
  bad_tag[msg::kHeaderSize + 20] ^= 0x40;  // the position, edited
  app::LinkKey other = test_key();
  other[0] ^= 1;
  msg::LinkAuth other_run(other.data(), other.size(), "another-run", msg::Role::Host);
  Bytes foreign(msg::Nav::kSize);
  REQUIRE(msg::seal(other_run, h.nav(0), foreign.data(), foreign.size()) == msg::Nav::kSize);
  const Bytes big(msg::kMaxMessageSize + 1, 0);
  for (const Bytes* b : std::initializer_list<const Bytes*>{&v1, &bad_tag, &foreign, &big}) a.receive_nav(b->data(), b->size());
  a.receive_nav(genuine.data(), genuine.size());
  a.receive_nav(genuine.data(), genuine.size());  // the same message again
  const auto& d = a.dropped();
  CHECK(d.untagged == 1);
  CHECK(d.bad_tag == 1);
  CHECK(d.wrong_run == 1);
  CHECK(d.oversized == 1);
  CHECK(d.replayed == 1);
  CHECK(d.coalesced == 0);
  auto nav = a.take_nav();
  REQUIRE(nav);
  CHECK(nav->step == 0);
  // An authentic nav whose content is NaN is the host's fault: dropped as malformed.
  Bytes nan_nav(msg::Nav::kSize);
  REQUIRE(msg::encode(h.nav(1), nan_nav.data(), nan_nav.size()) == msg::Nav::kSize);
  uint8_t* p = nan_nav.data() + msg::kHeaderSize + 16;
  msg::wire::put(p, std::nan(""));
  REQUIRE(h.auth.seal(nan_nav.data(), nan_nav.size()) == msg::Error::None);
  a.receive_nav(nan_nav.data(), nan_nav.size());
  CHECK(d.malformed == 1);
  CHECK_FALSE(a.take_nav());
  const msg::Telemetry t = a.telemetry();
  CHECK(t.rx_untagged == 1);
  CHECK(t.rx_bad_tag == 1);
  CHECK(t.rx_wrong_run == 1);
  CHECK(t.rx_oversized == 1);
  CHECK(t.rx_replayed == 1);
  CHECK(t.nav_rejected == 1);
}

TEST_CASE("only the host's own bye ends the run") {
  app::FlightApp a(config());
  Host h;
  msg::Bye bye;
  bye.reason = 0;
  Bytes forged = h.seal(bye);
  forged[msg::kHeaderSize + 8] ^= 1;  // its text, edited
  a.receive_bye(forged.data(), forged.size());
  CHECK_FALSE(a.bye_received());
  // The flight software's own bye, reflected: tagged under the other direction's key.
  app::LinkKey k = test_key();
  msg::LinkAuth flight_side(k.data(), k.size(), kRun, msg::Role::Flight);
  Bytes reflected(msg::Bye::kSize);
  REQUIRE(msg::seal(flight_side, bye, reflected.data(), reflected.size()) == msg::Bye::kSize);
  a.receive_bye(reflected.data(), reflected.size());
  CHECK_FALSE(a.bye_received());
  CHECK(a.dropped().bad_tag == 2);
  const Bytes genuine = h.seal(bye);
  a.receive_bye(genuine.data(), genuine.size());
  CHECK(a.bye_received());
}

TEST_CASE("the hello declares the limits the host checks; bad run ids and missing keys are refused") {
  app::FlightApp a(config());
  const msg::Hello hello = a.hello(1);
  for (int i = 0; i < 3; ++i) {
    CHECK(hello.max_pulse_s[i] > 0.0);
    CHECK(hello.max_pulse_s[i] <= hello.period_s[i]);
  }
  for (const char* run : {"", "*", "**", "a/b", "x$*"}) {
    app::AppConfig c = config();
    c.run_id = run;
    CHECK_THROWS_AS(app::FlightApp{c}, std::invalid_argument);
  }
  app::AppConfig no_key = config();
  no_key.link_key = {};
  CHECK_THROWS_AS(app::FlightApp{no_key}, std::invalid_argument);
  app::LinkKey k;
  CHECK(app::parse_link_key(std::string(64, 'a') + "\n", k));
  CHECK(k[0] == 0xAA);
  CHECK_FALSE(app::parse_link_key(std::string(63, 'a'), k));
  CHECK_FALSE(app::parse_link_key(std::string(62, 'a') + "zz", k));
}

TEST_CASE("checking, decoding and answering a nav, and sealing a cmd, allocate nothing") {
  app::AppConfig cfg = config();
  app::FlightApp a(cfg);
  Host h;
  std::vector<Bytes> navs, resends;
  for (uint32_t k = 0; k < 40; ++k) {
    navs.push_back(h.seal(h.nav(k)));
    resends.push_back(h.seal(h.nav(k)));
  }
  Bytes forged = navs[5];
  forged.back() ^= 1;
  REQUIRE(step(a, navs[0]));  // the first step may set things up
  const long before = g_news;
  for (uint32_t k = 1; k < navs.size(); ++k) {
    a.receive_nav(forged.data(), forged.size());
    REQUIRE(step(a, navs[k]));
    REQUIRE(step(a, resends[k]));  // a resend of the same step: answered from the cache
    a.receive_nav(navs[k].data(), navs[k].size());  // a replay: dropped
    (void)a.telemetry();
  }
  // Sealing what the flight software sends: no allocation either.
  app::LinkKey k = test_key();
  msg::LinkAuth flight_side(k.data(), k.size(), kRun, msg::Role::Flight);
  uint8_t out[msg::Cmd::kSize];
  for (int i = 0; i < 100; ++i) {
    msg::Cmd c;
    c.step = static_cast<uint32_t>(i);
    REQUIRE(msg::seal(flight_side, c, out, sizeof out) == msg::Cmd::kSize);
  }
  CHECK(g_news - before == 0);
  CHECK(a.dropped().bad_tag == navs.size() - 1);
  CHECK(a.dropped().duplicates == navs.size() - 1);
  CHECK(a.dropped().replayed == navs.size() - 1);
}
