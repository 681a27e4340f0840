// The obstacle messages on the C++ side: the golden byte vectors of schema/golden.toml (assembled
// field by field with struct and hmac, independently of the generated codecs), authentication, bad input.
#include <doctest/doctest.h>

#include <array>
#include <cmath>
#include <fstream>
#include <string>
#include <vector>

#include "flight_sw/link/messages.hpp"
#include "tests/cpp/golden_vectors.hpp"

using namespace rvd::msg;

namespace {
using golden_vectors::auth_for;
using golden_vectors::sealed;
std::vector<uint8_t> golden(const std::string& name) { return golden_vectors::vector_of(name); }

Obstacles golden_obstacles() {
  Obstacles m;
  m.step = 7;
  m.count = 2;
  m.sensed = 3;
  m.t_s = 210.0;
  m.id[0] = 5;
  m.id[1] = 9;
  m.t_seen_s[0] = 120.0;
  m.t_seen_s[1] = 195.5;
  const double pos[6] = {-30.0, -800.0, 10.0, -100.0, 0.0, -40.0};
  const double vel[6] = {-0.075, -0.005, 0.015, 0.07, -0.16, 0.01};
  const double axes[6] = {20.0, 20.0, 20.0, 50.0, 30.0, 10.0};
  const double q[8] = {1.0, 0.0, 0.0, 0.0, 0.7071067811865476, 0.0, 0.0, 0.7071067811865476};
  for (int i = 0; i < 6; ++i) {
    m.position_lvlh_m[i] = pos[i];
    m.velocity_lvlh_mps[i] = vel[i];
    m.semi_axes_m[i] = axes[i];
  }
  for (int i = 0; i < 8; ++i) m.q_lvlh_body[i] = q[i];
  return m;
}
}  // namespace

TEST_CASE("obstacles golden vector: the host seals it, the flight opens it") {
  CHECK(sealed(golden_obstacles(), Role::Host, 11) == golden("obstacles"));
  auto g = golden("obstacles");
  LinkAuth flight = auth_for(Role::Flight);
  Obstacles d;
  REQUIRE(receive(flight, g.data(), g.size(), d) == Error::None);
  CHECK(flight.last_received() == 11);
  CHECK(d.sensed == 3);
  CHECK(d.position_lvlh_m[1] == -800.0);
  CHECK(d.q_lvlh_body[7] == 0.7071067811865476);
  CHECK(d.semi_axes_m[5] == 10.0);
}

TEST_CASE("obstacle_status golden vector") {
  ObstacleStatus s;
  s.step = 7;
  s.received = 3;
  s.held = 2;
  s.capacity = 4;
  s.dropped_total = 1;
  s.rejected_total = 2;
  s.held_id[0] = 9;
  s.held_id[1] = 5;
  CHECK(sealed(s, Role::Flight, 12) == golden("obstacle_status"));
}

TEST_CASE("an obstacles message is authenticated like every other: flipped, reflected or NaN is refused") {
  auto g = golden("obstacles");
  Obstacles d;
  {
    auto bad = g;
    bad[100] ^= 0x01;  // in the body
    LinkAuth flight = auth_for(Role::Flight);
    CHECK(receive(flight, bad.data(), bad.size(), d) == Error::BadTag);
  }
  {
    LinkAuth host = auth_for(Role::Host);  // the host's own message reflected back to it
    CHECK(receive(host, g.data(), g.size(), d) == Error::BadTag);
  }
  {
    LinkAuth flight = auth_for(Role::Flight);
    REQUIRE(receive(flight, g.data(), g.size(), d) == Error::None);
    CHECK(receive(flight, g.data(), g.size(), d) == Error::Replayed);
  }
  Obstacles m = golden_obstacles();
  m.semi_axes_m[2] = std::nan("");
  std::vector<uint8_t> out(Obstacles::kSize);
  Error e = Error::None;
  CHECK(encode(m, out.data(), out.size(), &e) == 0);
  CHECK(e == Error::NonFinite);
}
