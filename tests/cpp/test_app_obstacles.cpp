// The flight software's obstacle input: an obstacles message sealed by the host reaches the guidance
// with the next nav; a list longer than the guidance holds keeps the nearest and says so in
// obstacle_status; bad entries and messages are refused and counted, never planned with; a forged
// or replayed one is dropped like any host message.
#include <doctest/doctest.h>

#include <vector>

#include "flight_sw/app/flight_app.hpp"

using namespace rvd;
using Bytes = std::vector<uint8_t>;

namespace {
constexpr const char* kRun = "obstacle-test";

app::LinkKey test_key() {
  app::LinkKey k{};
  for (size_t i = 0; i < k.size(); ++i) k[i] = static_cast<uint8_t>(0x30 + i);
  return k;
}

app::AppConfig config(bool obstacles) {
  app::AppConfig c;
  c.run_id = kRun;
  c.link_key = test_key();
  c.guidance.obstacle_capacity = obstacles ? guidance::kMaxObstacles : 0;
  return c;
}

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
  // `count` spheres of radius 10 m on a line from the chaser's start, the k-th (100 + 100 k) m away.
  msg::Obstacles obstacles(uint32_t step, int count) const {
    const auto c = guidance::dissertation_case(1);
    msg::Obstacles m;
    m.step = step;
    m.count = static_cast<uint16_t>(count);
    m.sensed = m.count;
    m.t_s = 30.0 * step;
    for (int k = 0; k < count; ++k) {
      m.id[k] = static_cast<uint32_t>(100 + k);
      m.t_seen_s[k] = 0.0;
      m.position_lvlh_m[3 * k] = c.x0(0);
      m.position_lvlh_m[3 * k + 1] = c.x0(1) + 110.0 + 100.0 * (count - 1 - k);  // far first
      m.position_lvlh_m[3 * k + 2] = c.x0(2);
      for (int j = 0; j < 3; ++j) m.semi_axes_m[3 * k + j] = 10.0;
      m.q_lvlh_body[4 * k] = 1.0;
    }
    return m;
  }
  template <class M> Bytes seal(const M& m) {
    Bytes b(M::kSize);
    REQUIRE(msg::seal(auth, m, b.data(), b.size()) == M::kSize);
    return b;
  }
};

std::optional<msg::Cmd> step(app::FlightApp& a, const Bytes& nav) {
  a.receive_nav(nav.data(), nav.size());
  auto n = a.take_nav();
  return n ? a.handle_nav(*n) : std::nullopt;
}
}  // namespace

TEST_CASE("eight obstacles for a guidance that holds four: the nearest four are planned with, four dropped") {
  app::FlightApp a(config(true));
  Host h;
  const Bytes o = h.seal(h.obstacles(0, 8));
  a.receive_obstacles(o.data(), o.size());
  REQUIRE(step(a, h.seal(h.nav(0))));
  const msg::ObstacleStatus s = a.obstacle_status();
  CHECK(s.step == 0);
  CHECK(s.received == 8);
  CHECK(s.held == guidance::kMaxObstacles);
  CHECK(s.capacity == guidance::kMaxObstacles);
  CHECK(s.dropped_total == 8u - guidance::kMaxObstacles);
  for (int k = 0; k < guidance::kMaxObstacles; ++k) CHECK(s.held_id[k] == static_cast<uint32_t>(107 - k));  // nearest first
  // The host sensed 20 and sent its nearest 8: the 12 it could not send count as dropped too.
  msg::Obstacles more = h.obstacles(1, 8);
  more.sensed = 20;
  const Bytes m = h.seal(more);
  a.receive_obstacles(m.data(), m.size());
  REQUIRE(step(a, h.seal(h.nav(1))));
  CHECK(a.obstacle_status().received == 20);
  CHECK(a.obstacle_status().dropped_total == 4u + 16u);
}

TEST_CASE("bad obstacle entries and messages are refused and counted; forged ones are dropped as such") {
  app::FlightApp a(config(true));
  Host h;
  msg::Obstacles bad = h.obstacles(0, 3);
  bad.semi_axes_m[4] = -1.0;  // entry 1: a negative axis
  bad.q_lvlh_body[8] = 2.0;   // entry 2: not a unit quaternion
  const Bytes b = h.seal(bad);
  a.receive_obstacles(b.data(), b.size());
  REQUIRE(step(a, h.seal(h.nav(0))));
  CHECK(a.obstacle_status().held == 1);
  CHECK(a.obstacle_status().held_id[0] == 100u);
  CHECK(a.obstacle_status().rejected_total == 2u);
  // More obstacles than the message has slots: refused whole, the held list stays.
  msg::Obstacles overfull = h.obstacles(1, 2);
  overfull.count = 9;
  const Bytes o = h.seal(overfull);
  a.receive_obstacles(o.data(), o.size());
  REQUIRE(step(a, h.seal(h.nav(1))));
  CHECK(a.obstacle_status().rejected_total == 3u);
  CHECK(a.obstacle_status().held == 1);
  // A flipped bit and a replay: link drops, counted in telemetry.
  Bytes forged = h.seal(h.obstacles(2, 2));
  const Bytes replay = forged;
  forged[40] ^= 0x01;
  a.receive_obstacles(forged.data(), forged.size());
  a.receive_obstacles(replay.data(), replay.size());
  a.receive_obstacles(replay.data(), replay.size());
  CHECK(a.telemetry().rx_bad_tag == 1u);
  CHECK(a.telemetry().rx_replayed == 1u);
}

TEST_CASE("without obstacle rows the flight software holds none and says so") {
  app::FlightApp a(config(false));
  Host h;
  const Bytes o = h.seal(h.obstacles(0, 3));
  a.receive_obstacles(o.data(), o.size());
  REQUIRE(step(a, h.seal(h.nav(0))));
  CHECK(a.obstacle_status().held == 0);
  CHECK(a.obstacle_status().capacity == 0);
  CHECK(a.obstacle_status().dropped_total == 3u);
}
