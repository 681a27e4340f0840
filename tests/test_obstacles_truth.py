"""Obstacles in the truth (rvd_pil.host_sim.obstacles, the safety monitor's obstacle limit, scenario loading):
clearance against trajectories whose closest approach is known in closed form."""
import math

import numpy as np
import pytest

from rvd_pil.host_sim import scenario as scenarios
from rvd_pil.host_sim.attitude import TargetAttitude
from rvd_pil.host_sim.cw import cw_stm
from rvd_pil.host_sim.obstacles import Obstacle, ObstacleField
from rvd_pil.host_sim.safety import SafetyLimits, SafetyMonitor

N = 0.0011  # mean motion [rad/s], ~500 km
RENDEZVOUS = 1


def monitor(obstacles):
    att = TargetAttitude(math.radians(90.0), 0.0, (0.5, 0.0, 0.0))
    events = []
    mon = SafetyMonitor(SafetyLimits(), att.state, on_event=lambda kind, ep: events.append((kind, ep)),
                        obstacles=ObstacleField(obstacles, N))
    return mon, events


FAR = np.array([0.0, -1000.0, 0.0])  # far from the target: no other limit applies there


def feed(mon, t, positions, step=0):
    x = np.hstack((np.asarray(positions, float) + FAR, np.zeros((len(t), 3))))
    return mon.period(RENDEZVOUS, step, t, x)


def q_about(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return (math.cos(angle / 2), *(math.sin(angle / 2) * axis))


def test_a_straight_pass_by_a_moving_sphere_has_the_closed_form_minimum_clearance():
    # Chaser along +y at 1 m/s through x = 0; a sphere of radius 20 m moving along -x at 0.5 m/s,
    # starting at (80, 100, 0): relative motion is a straight line, closest distance analytic.
    R = 20.0
    sphere = Obstacle(id=7, semi_axes_m=(R, R, R), position_lvlh_m=tuple(np.array([80.0, 100.0, 0.0]) + FAR),
                      velocity_lvlh_mps=(-0.5, 0.0, 0.0))
    t = np.linspace(0.0, 200.0, 4001)
    chaser = np.column_stack((np.zeros_like(t), t, np.zeros_like(t)))
    mon, events = monitor([sphere])
    worst = feed(mon, t, chaser)
    mon.finish()
    # relative position p(t) = chaser - obstacle = (-40 + 0.5 t, t - 100, 0); minimise |p|^2.
    p0, v = np.array([-80.0, -100.0, 0.0]), np.array([0.5, 1.0, 0.0])
    t_min = -p0 @ v / (v @ v)
    d_min = np.linalg.norm(p0 + v * t_min)
    assert d_min > R  # a clean miss: no event
    f = mon.summary()["figures"]["obstacles"]["7"]
    assert f["min_clearance"] == pytest.approx((d_min / R) ** 2, rel=1e-6)
    assert f["t_s"] == pytest.approx(t_min, abs=0.05)
    assert worst["obstacle_clearance"] == pytest.approx((d_min / R) ** 2, rel=1e-6)
    assert not events and mon.verdict() == "safe"


def test_a_pass_through_a_rotated_ellipsoid_is_a_violation_of_known_depth():
    # Ellipsoid a, b, c = 30, 10, 5 m turned 90 deg about z: its long axis along LVLH y. The chaser
    # crosses it along x at y = 20 m: clearance (x/10)^2 + (20/30)^2, minimum 4/9 at x = 0.
    ell = Obstacle(id=2, semi_axes_m=(30.0, 10.0, 5.0), q_lvlh_body=q_about((0, 0, 1), math.pi / 2),
                   position_lvlh_m=tuple(FAR))
    t = np.linspace(0.0, 100.0, 2001)
    chaser = np.column_stack((t - 50.0, np.full_like(t, 20.0), np.zeros_like(t)))
    mon, events = monitor([ell])
    feed(mon, t, chaser)
    mon.finish()
    (kind, ep), = events
    assert kind == "safety_violation" and ep.limit == "obstacle" and ep.label == "obstacle id 2"
    assert ep.worst == pytest.approx(1.0 - 4.0 / 9.0, rel=1e-9)
    assert ep.worst_t_s == pytest.approx(50.0, abs=1e-9)
    # Inside while |x| < 10 sqrt(1 - 4/9): the episode's length.
    assert ep.end_t_s - ep.start_t_s == pytest.approx(2 * 10 * math.sqrt(5 / 9), abs=0.1)
    s = mon.summary()
    assert s["verdict"] == "unsafe" and s["per_limit"]["obstacle"]["violations"] == 1
    assert s["episodes"][0]["which"] == "obstacle id 2"


def test_cw_motion_follows_the_closed_form_transition_and_a_body_axis_offset_has_clearance_four():
    x0 = np.array([-100.0, 0.0, -40.0, 0.07, -0.16, 0.01])
    o = Obstacle(id=1, semi_axes_m=(8.0, 4.0, 2.0), q_lvlh_body=q_about((1, 1, 0), 0.7),
                 position_lvlh_m=tuple(x0[:3]), velocity_lvlh_mps=tuple(x0[3:]), motion="cw")
    r = o.rotation()
    for t in (0.0, 300.0, 2000.0):
        centre = cw_stm(N, t) @ x0
        np.testing.assert_allclose(o.state(t, N), centre, rtol=1e-12, atol=1e-9)
        # Twice the semi-axis b along body y from the centre: clearance exactly 4.
        assert o.clearance(centre[:3] + r[:, 1] * 8.0, t, N) == pytest.approx(4.0, rel=1e-12)
    # The constant-velocity model of the same initial state drifts away from the CW one.
    cv = Obstacle(**{**o.__dict__, "motion": "constant_velocity"})
    assert np.linalg.norm(cv.state(2000.0, N)[:3] - o.state(2000.0, N)[:3]) > 10.0


def test_an_obstacle_is_judged_only_from_its_appearance_and_sensed_only_within_its_range():
    late = Obstacle(id=3, semi_axes_m=(10.0, 10.0, 10.0), position_lvlh_m=tuple(np.array([0.0, 50.0, 0.0]) + FAR),
                    appear_time_s=100.0)
    t = np.linspace(0.0, 60.0, 601)  # through its centre, but before it exists
    chaser = np.column_stack((np.zeros_like(t), 20.0 + t, np.zeros_like(t)))
    mon, events = monitor([late])
    feed(mon, t, chaser)
    mon.finish()
    assert not events and mon.summary()["figures"]["obstacles"]["3"]["min_clearance"] is None

    far = Obstacle(id=4, semi_axes_m=(5.0, 5.0, 5.0), position_lvlh_m=tuple(np.array([0.0, 500.0, 0.0]) + FAR),
                   sensing_range_m=100.0)
    field = ObstacleField([late, far], N)
    assert field.sensed(0.0, FAR) == []
    seen = field.sensed(120.0, np.array([0.0, 450.0, 0.0]) + FAR)
    assert [(o.id, first) for o, _, first in seen] == [(3, 120.0), (4, 120.0)]
    # Latched: still known (with its first-seen time) once the chaser has left its range.
    assert [(o.id, first) for o, _, first in field.sensed(200.0, FAR)] == [(3, 120.0), (4, 120.0)]


def test_a_monitor_without_obstacles_reports_exactly_what_it_did_before():
    att = TargetAttitude(0.0, 0.0, (0.5, 0.0, 0.0))
    s = SafetyMonitor(SafetyLimits(), att.state).summary()
    assert "obstacle" not in s["per_limit"] and "obstacles" not in s["figures"] and "obstacle" not in s["sources"]
    assert "obstacles" not in scenarios.load("case1_vbar").to_dict()


BASE = """
name = "t"
[chaser]
position_lvlh_m = [140.0, -1580.0, 60.0]
"""


def load_with(obstacle_toml: str):
    return scenarios.from_toml(BASE + obstacle_toml, source="test.toml")


def test_obstacles_load_from_toml_and_round_trip_through_the_record_dict():
    s = load_with("""
[[obstacles]]
id = 5
semi_axes_m = [20.0, 20.0, 20.0]
position_lvlh_m = [-30.0, -800.0, 10.0]
velocity_lvlh_mps = [-0.075, -0.005, 0.015]
motion = "cw"
[[obstacles]]
semi_axes_m = [50.0, 40.0, 30.0]
position_lvlh_m = [-100.0, 0.0, -400.0]
sensing_range_m = 300.0
""")
    assert [o.id for o in s.obstacles] == [5, 2] and s.obstacles[0].motion == "cw"
    again = scenarios.from_dict(s.to_dict(), source="record")
    assert again.obstacles == s.obstacles


@pytest.mark.parametrize("entry, words", [
    ("semi_axes_m = [20.0, 0.0, 20.0]\nposition_lvlh_m = [0.0, -800.0, 0.0]", "semi_axes_m must be > 0"),
    ("semi_axes_m = [20.0, -3.0, 20.0]\nposition_lvlh_m = [0.0, -800.0, 0.0]", "semi_axes_m must be > 0"),
    ("semi_axes_m = [20.0, nan, 20.0]\nposition_lvlh_m = [0.0, -800.0, 0.0]", "semi_axes_m: expected finite"),
    ("semi_axes_m = [20.0, 20.0, 20.0]\nposition_lvlh_m = [0.0, inf, 0.0]", "position_lvlh_m: expected finite"),
    ("semi_axes_m = [20.0, 20.0, 20.0]\nposition_lvlh_m = [0.0, 15.0, 0.0]", "overlaps the target"),
    ("semi_axes_m = [20.0, 20.0, 20.0]\nposition_lvlh_m = [140.0, -1570.0, 60.0]", "contains the chaser's start"),
    ("semi_axes_m = [20.0, 20.0, 20.0]\nposition_lvlh_m = [0.0, -800.0, 0.0]\nmotion = \"kepler\"", "motion: expected one of"),
    ("semi_axes = [20.0, 20.0, 20.0]", "unknown key(s) ['semi_axes']"),
    ("semi_axes_m = [20.0, 20.0]", "expected a list of 3 numbers"),
    ("semi_axes_m = [1.0, 1.0, 1.0]\nposition_lvlh_m = [0.0, -800.0, 0.0]\nq_lvlh_body = [0.0, 0.0, 0.0, 0.0]",
     "unit quaternion"),
    ("semi_axes_m = [1.0, 1.0, 1.0]\nposition_lvlh_m = [0.0, -800.0, 0.0]\nappear_time_s = -1.0", "appear_time_s must be >= 0"),
])
def test_bad_obstacle_input_gets_a_one_line_error_naming_file_and_key(entry, words):
    with pytest.raises(scenarios.ScenarioError) as err:
        load_with("[[obstacles]]\n" + entry + "\n")
    text = str(err.value)
    assert "\n" not in text and text.startswith("test.toml") and words in text


def test_an_obstacle_that_appears_later_may_start_where_the_chaser_starts_but_not_on_the_target():
    load_with("[[obstacles]]\nsemi_axes_m = [20.0, 20.0, 20.0]\nposition_lvlh_m = [140.0, -1570.0, 60.0]\n"
              "appear_time_s = 600.0\n")
    with pytest.raises(scenarios.ScenarioError, match="overlaps the target"):
        # Moving onto the target by the time it appears.
        load_with("[[obstacles]]\nsemi_axes_m = [5.0, 5.0, 5.0]\nposition_lvlh_m = [0.0, -600.0, 0.0]\n"
                  "velocity_lvlh_mps = [0.0, 1.0, 0.0]\nappear_time_s = 600.0\n")
