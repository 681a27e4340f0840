// The chaser's rotation on an air-bearing table through the flight software: a chaser_attitude message
// sealed by the host reaches the law with the next nav, and the torque the built-in MPC commands comes
// back for that step (within its limit, turning the chaser towards its docking attitude); a resent nav
// gets the same torque, a step without the message none, a tampered message is dropped.
#include <doctest/doctest.h>

#include <cmath>
#include <vector>

#include "flight_sw/app/flight_app.hpp"

using namespace rvd;
using Bytes = std::vector<uint8_t>;

namespace {
constexpr const char* kRun = "attitude-test";
constexpr double kDeg = 3.14159265358979323846 / 180.0;

app::LinkKey test_key(uint8_t base = 0x30) {
  app::LinkKey k{};
  for (size_t i = 0; i < k.size(); ++i) k[i] = static_cast<uint8_t>(base + i);
  return k;
}

app::AppConfig config() {
  app::AppConfig c;
  c.run_id = kRun;
  c.link_key = test_key();
  auto& g = c.guidance;
  g.relative_motion = guidance::RelativeMotion::DoubleIntegrator;
  for (guidance::PhaseParams* p : {&g.rendezvous, &g.approach, &g.docking}) {
    p->N = 15;
    p->Ts_s = 2.0;
    p->u_max_mps = 0.0177;
  }
  g.thrusters.mass_kg = 16.9;
  g.thrusters.thrust_N = 0.15;
  g.keepout_radius_m = 0.5;
  g.approach_stop_m = 0.46;
  g.port_body_m = Eigen::Vector3d(0.45, 0.0, 0.0);
  g.attitude.inertia_kgm2 = 0.27;
  g.attitude.torque_max_nm = 0.0225;
  return c;
}

struct Host {
  app::LinkKey key = test_key();
  msg::LinkAuth auth{key.data(), key.size(), kRun, msg::Role::Host};
  msg::Nav nav(uint32_t step) const {
    msg::Nav n;
    n.step = step;
    n.flags = step == 0 ? 1u : 0u;
    n.t_s = 2.0 * step;
    n.position_lvlh_m = {1.9, 0.0, 0.0};
    n.q_lvlh_body = {1.0, 0.0, 0.0, 0.0};  // the target's port faces +x, towards the chaser
    return n;
  }
  // The chaser turned `deg` about z (its docking attitude is 180 deg: facing the target's port).
  msg::ChaserAttitude attitude(uint32_t step, double deg) const {
    msg::ChaserAttitude m;
    m.step = step;
    m.t_s = 2.0 * step;
    m.q_lvlh_chaser = {std::cos(0.5 * deg * kDeg), 0.0, 0.0, std::sin(0.5 * deg * kDeg)};
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

TEST_CASE("the chaser's attitude reaches the law with the next nav and its torque comes back for that step") {
  app::FlightApp app(config());
  Host host;
  // 30 deg past its docking attitude, at rest: the torque turns it back (negative about z), within the limit.
  const Bytes att = host.seal(host.attitude(0, 210.0));
  app.receive_chaser_attitude(att.data(), att.size());
  const Bytes nav0 = host.seal(host.nav(0));
  REQUIRE(step(app, nav0));
  const auto tq = app.torque_for(0);
  REQUIRE(tq);
  CHECK(tq->torque_body_nm[0] == 0.0);
  CHECK(tq->torque_body_nm[1] == 0.0);
  CHECK(tq->torque_body_nm[2] < 0.0);
  CHECK(std::abs(tq->torque_body_nm[2]) <= 0.0225 * (1.0 + 1e-12));
  CHECK(tq->torque_max_nm == 0.0225);
  // 30 deg short of it: the opposite torque.
  const Bytes att1 = host.seal(host.attitude(1, 150.0));
  app.receive_chaser_attitude(att1.data(), att1.size());
  REQUIRE(step(app, host.seal(host.nav(1))));
  const auto tq1 = app.torque_for(1);
  REQUIRE(tq1);
  CHECK(tq1->torque_body_nm[2] > 0.0);
  // A resent nav 1: the same cmd and the same torque.
  REQUIRE(step(app, host.seal(host.nav(1))));
  REQUIRE(app.torque_for(1));
  CHECK(app.torque_for(1)->torque_body_nm[2] == tq1->torque_body_nm[2]);
  // A step without the chaser's attitude commands none.
  REQUIRE(step(app, host.seal(host.nav(2))));
  CHECK_FALSE(app.torque_for(2));
  // A chaser_attitude with a flipped bit is dropped and counted: the next step has none either.
  Bytes forged = host.seal(host.attitude(3, 210.0));
  forged[30] ^= 0x01;
  app.receive_chaser_attitude(forged.data(), forged.size());
  CHECK(app.telemetry().rx_bad_tag == 1u);
  REQUIRE(step(app, host.seal(host.nav(3))));
  CHECK_FALSE(app.torque_for(3));
}
