// The C++ side of the link schema: the golden byte vectors of schema/golden.toml (sealed under the
// golden key and run id), message authentication, and bad input.
#include <doctest/doctest.h>

#include <array>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "flight_sw/link/messages.hpp"
#include "tests/cpp/golden_vectors.hpp"

using namespace rvd::msg;

namespace {
using golden_vectors::auth_for;
std::vector<uint8_t> golden(const std::string& name) { return golden_vectors::vector_of(name); }
const auto golden_key = golden_vectors::key;
constexpr const char* kGoldenRun = golden_vectors::kRun;
template <class M>
std::vector<uint8_t> encoded(const M& m, Role sender = Role::Flight, uint32_t seq = 1) { return golden_vectors::sealed(m, sender, seq); }
constexpr uint32_t kGoldenNonce = 2018313737u;

}  // namespace

TEST_CASE("hello golden vector") {
  Hello m;
  set_str(m.arch, "aarch64");
  set_str(m.cpu_model, "cortex-a53");
  set_str(m.compiler, "gcc 12.2.0");
  set_str(m.build, "Release -O2 -static");
  m.solver_mode = 1;
  m.step_clock = 1;
  m.solver_max_iter = 100;
  m.solver_tol = 1e-8;
  m.horizon = {30, 15, 12};
  m.period_s = {30.0, 20.0, 5.0};
  m.max_pulse_s = {1.5, 1.0, 0.25};
  m.deadline_fraction = 0.5;
  m.pid = 4242;
  m.session = 1;
  CHECK(encoded(m, Role::Flight, 1) == golden("hello"));
  Hello d;
  auto g = golden("hello");
  LinkAuth host = auth_for(Role::Host);
  CHECK(host.run_nonce() == kGoldenNonce);
  REQUIRE(receive(host, g.data(), g.size(), d) == Error::None);
  CHECK(d.max_pulse_s[2] == 0.25);
  CHECK(get_str(d.cpu_model) == "cortex-a53");
  CHECK(d.horizon[2] == 12);
}

TEST_CASE("nav golden vector") {
  Nav m;
  m.step = 7;
  m.flags = 1;
  m.t_s = 210.0;
  m.position_lvlh_m = {140.0, -1580.0, 60.0};
  m.velocity_lvlh_mps = {-0.9, -0.32, 0.0};
  m.q_lvlh_body = {0.7071067811865476, 0.0, 0.0, -0.7071067811865476};
  m.omega_body_rad_s = {0.0, 0.0, 0.004363323129985824};
  CHECK(encoded(m, Role::Host, 7) == golden("nav"));
  Nav d;
  auto g = golden("nav");
  LinkAuth flight = auth_for(Role::Flight);
  REQUIRE(receive(flight, g.data(), g.size(), d) == Error::None);
  CHECK(flight.last_received() == 7);
  CHECK(d.position_lvlh_m[1] == -1580.0);
  CHECK(d.omega_body_rad_s[2] == 0.004363323129985824);
}

TEST_CASE("cmd golden vector") {
  Cmd m;
  m.step = 7;
  m.phase = 2;
  m.guidance_status = 1;
  m.solver_status = 1;
  m.overrun = 1;
  m.period_s = 20.0;
  m.dv_cmd_lvlh_mps = {0.01, -0.02, 0.0};
  m.dv_alloc_lvlh_mps = {0.0099, -0.0201, 0.0};
  m.pulse_s = {0.2772, 0.0, 0.0, 0.5628, 0.0, 0.0};
  m.solve_time_us = 123.5;
  m.step_time_us = 150.25;
  m.instructions = 987654321;
  m.iterations = 17;
  m.overruns = 3;
  m.primal_residual = 1e-9;
  m.dual_residual = 2e-10;
  m.objective = -42.5;
  CHECK(encoded(m, Role::Flight, 8) == golden("cmd"));
}

TEST_CASE("telemetry and bye golden vectors") {
  Telemetry t;
  t.steps = {60, 15, 63};
  t.overruns = {0, 1, 0};
  t.mean_solve_us = {45.5, 30.25, 12.0};
  t.max_solve_us = {90.0, 60.5, 20.75};
  t.max_step = {12, 70, 100};
  t.step_clock = 1;
  t.total_instructions = {1000000, 2000000, 3000000};
  t.peak_heap_bytes = 524288;
  t.max_rss_kb = 4096;
  t.nav_rejected = 2;
  t.nav_duplicates = 5;
  t.nav_stale = 1;
  t.nav_future = 2;
  t.nav_coalesced = 3;
  t.rx_oversized = 4;
  t.rx_untagged = 5;
  t.rx_wrong_run = 6;
  t.rx_bad_tag = 7;
  t.rx_replayed = 8;
  t.link_losses = 9;
  t.link_resyncs = 10;
  t.link_rx_rejected = 11;
  t.link_rx_unmatched = 12;
  CHECK(encoded(t, Role::Flight, 9) == golden("telemetry"));
  Bye b;
  b.reason = 1;
  b.last_step = 137;
  set_str(b.text, "docked: 0.08 m from port");
  CHECK(encoded(b, Role::Flight, 10) == golden("bye"));
}

TEST_CASE("forged, replayed, reflected, untagged and other runs' messages are refused by kind") {
  const auto g = golden("nav");  // sealed by the host, sequence number 7
  Nav d;
  {
    LinkAuth flight = auth_for(Role::Flight);
    CHECK(receive(flight, g.data(), g.size(), d) == Error::None);
    CHECK(receive(flight, g.data(), g.size(), d) == Error::Replayed);  // the same message again
    CHECK(flight.last_received() == 7);
  }
  {
    // Any flipped bit in header, body or tag: never accepted. In nonce: WrongRun; elsewhere BadTag
    // (or a layout error for magic, version, type and size).
    for (size_t i = 0; i < g.size(); ++i) {
      for (int bit = 0; bit < 8; ++bit) {
        LinkAuth flight = auth_for(Role::Flight);
        auto bad = g;
        bad[i] ^= static_cast<uint8_t>(1u << bit);
        const Error e = receive(flight, bad.data(), bad.size(), d);
        CHECK(e != Error::None);
        if (i >= 8 && i < 12) CHECK(e == Error::WrongRun);
        if (i >= 12 && i < 16) CHECK(e == Error::BadTag);  // a changed sequence number breaks the tag
        if (i >= kHeaderSize) CHECK(e == Error::BadTag);
        CHECK(flight.last_received() == 0);  // nothing refused uses up a sequence number
      }
    }
  }
  {
    // The host's own message reflected back to the host: tagged under the other direction's key.
    LinkAuth host = auth_for(Role::Host);
    CHECK(receive(host, g.data(), g.size(), d) == Error::BadTag);
    // Another run (same key, other id) and another key (same id).
    const auto k = golden_key();
    LinkAuth other_run(k.data(), k.size(), "golden-run-8", Role::Flight);
    CHECK(receive(other_run, g.data(), g.size(), d) == Error::WrongRun);
    auto k2 = k;
    k2[31] ^= 1;
    LinkAuth other_key(k2.data(), k2.size(), kGoldenRun, Role::Flight);
    CHECK(receive(other_key, g.data(), g.size(), d) != Error::None);
  }
  {
    // The tagless protocol: version 1, 8-byte header, no tag.
    std::vector<uint8_t> v1 = {'R', 'V', 'D', 1, 2, 0, 120, 0};
    v1.insert(v1.end(), g.begin() + kHeaderSize, g.end() - kTagSize);
    LinkAuth flight = auth_for(Role::Flight);
    CHECK(receive(flight, v1.data(), v1.size(), d) == Error::Untagged);
    // Unsealed v2 bytes (zero nonce and tag), wrong type (not using up a number), oversized, no key.
    uint8_t buf[Nav::kSize];
    REQUIRE(encode(d, buf, sizeof buf) == Nav::kSize);
    CHECK(receive(flight, buf, sizeof buf, d) == Error::WrongRun);
    Cmd c;
    CHECK(receive(flight, g.data(), g.size(), c) == Error::WrongType);
    CHECK(receive(flight, g.data(), g.size(), d) == Error::None);
    std::vector<uint8_t> big(kMaxMessageSize + 1, 0);
    CHECK(receive(flight, big.data(), big.size(), d) == Error::Oversized);
    LinkAuth none;
    CHECK(receive(none, g.data(), g.size(), d) == Error::NoKey);
    CHECK(none.seal(buf, sizeof buf) == Error::NoKey);
  }
  {
    // Keys must have kKeySize bytes, run ids the documented characters.
    const auto k = golden_key();
    CHECK_FALSE(LinkAuth(k.data(), 16, kGoldenRun, Role::Host).keyed());
    for (const char* run : {"", "*", "**", "a/b", "r$*", "run 1", "rvd/*/x"}) {
      CHECK_FALSE(check_run_id(run));
      CHECK_FALSE(LinkAuth(k.data(), k.size(), run, Role::Host).keyed());
    }
    CHECK(check_run_id("a1b2c3d4e5f6"));
    CHECK(check_run_id("semihosting-check_2"));
    CHECK_FALSE(check_run_id(std::string(kRunIdMax + 1, 'a')));
  }
}

TEST_CASE("malformed bytes are rejected, never read out of bounds") {
  auto g = golden("nav");
  Nav d;
  CHECK(decode(nullptr, 0, d) == Error::TooShort);
  CHECK(decode(g.data(), 5, d) == Error::TooShort);
  CHECK(decode(g.data(), g.size() - 1, d) == Error::BadSize);
  auto bad = g;
  bad[0] = 'X';
  CHECK(decode(bad.data(), bad.size(), d) == Error::BadMagic);
  bad = g;
  bad[3] = 3;
  CHECK(decode(bad.data(), bad.size(), d) == Error::BadVersion);
  bad = g;
  bad[4] = 99;
  CHECK(decode(bad.data(), bad.size(), d) == Error::UnknownType);
  Cmd c;
  CHECK(decode(g.data(), g.size(), c) == Error::WrongType);
  // Every truncation is rejected without crashing, by the codec and by the authenticator.
  LinkAuth flight = auth_for(Role::Flight);
  for (size_t n = 0; n < g.size(); ++n) {
    CHECK(decode(g.data(), n, d) != Error::None);
    CHECK(receive(flight, g.data(), n, d) != Error::None);
  }
}

TEST_CASE("NaN and Inf never cross the wire") {
  Nav m;
  m.position_lvlh_m[0] = std::nan("");
  uint8_t buf[Nav::kSize];
  Error e = Error::None;
  CHECK(encode(m, buf, sizeof buf, &e) == 0);
  CHECK(e == Error::NonFinite);
  auto g = golden("nav");
  const double inf = HUGE_VAL;
  uint64_t bits;
  std::memcpy(&bits, &inf, 8);
  for (int i = 0; i < 8; ++i) g[kHeaderSize + 16 + i] = static_cast<uint8_t>(bits >> (8 * i));  // position x
  Nav d;
  CHECK(decode(g.data(), g.size(), d) == Error::NonFinite);
  CHECK(encode(Nav{}, buf, 10, &e) == 0);
  CHECK(e == Error::BufferTooSmall);
}
