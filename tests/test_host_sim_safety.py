"""The safety monitor (rvd_pil.host_sim.safety) against trajectories whose violations are known in closed form,
the truth path it is fed (rvd_pil.host_sim.simulator), and whole PIL runs: a deliberately unsafe guidance
setting must be judged unsafe, the default one safe."""
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from rvd_pil.host_sim.attitude import TargetAttitude
from rvd_pil.host_sim.cw import cw_forced_response, cw_stm
from rvd_pil.host_sim.safety import SafetyLimits, SafetyMonitor, pyramid_rows
from rvd_pil.host_sim.simulator import Simulator

LIM = SafetyLimits()
A15, A8 = math.radians(15.0), math.radians(8.0)
APPROACH, DOCKING, RENDEZVOUS = 2, 3, 1


def monitor(angle_deg=0.0, spin_deg_s=0.0):
    """A monitor for a target whose docking axis (body +x) is LVLH +x rotated by angle_deg about z."""
    att = TargetAttitude(math.radians(angle_deg), math.radians(spin_deg_s), (0.5, 0.0, 0.0))
    events = []
    mon = SafetyMonitor(LIM, att.state, sigma_w_percent=4.62, on_event=lambda kind, ep: events.append((kind, ep)))
    return mon, events


def feed_line(mon, phase, p0, p1, duration_s, samples=2001, v=None, step=0):
    """A straight path p0 -> p1 at constant velocity, as one period sampled densely."""
    t = np.linspace(0.0, duration_s, samples)
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    vel = (p1 - p0) / duration_s if v is None else np.asarray(v, float)
    x = np.array([np.concatenate((p0 + (p1 - p0) * tau / duration_s, vel)) for tau in t])
    return mon.period(phase, step, t, x)


def only(events, limit):
    return [ep for kind, ep in events if ep.limit == limit]


def test_a_pass_behind_the_target_through_the_sphere_is_a_keepout_violation_of_known_size():
    mon, events = monitor()
    # x = -150 m: behind the target (the corridor opens along +x); y from +300 to -300 m in 600 s.
    feed_line(mon, RENDEZVOUS, (-150.0, 300.0, 0.0), (-150.0, -300.0, 0.0), 600.0, samples=20001)
    mon.finish()
    (ep,) = only(events, "keepout")
    spacing = 600.0 / 20000
    # Distance to the safe set: min(depth inside r1, distance outside the corridor) with depth
    # 200 - sqrt(150^2 + y^2) and corridor |y| cos a + 150 sin a; the largest where the two cross.
    depth = lambda y: 200.0 - math.hypot(150.0, y)
    corridor = lambda y: abs(y) * math.cos(A15) + 150.0 * math.sin(A15)
    y_cross = brentq(lambda y: corridor(y) - depth(y), 0.0, 100.0)
    # 49.59 m at the kink; a sample can miss it by half a spacing along the steeper (corridor) side.
    assert ep.worst == pytest.approx(depth(y_cross), abs=math.cos(A15) * spacing / 2)
    assert abs(ep.worst_t_s - 300.0) == pytest.approx(y_cross, abs=spacing)
    # Inside the sphere while |y| < sqrt(200^2 - 150^2): 264.6 s at 1 m/s.
    assert ep.end_t_s - ep.start_t_s == pytest.approx(2.0 * math.sqrt(200.0**2 - 150.0**2), abs=2 * spacing)
    s = mon.summary()
    assert s["verdict"] == "unsafe" and s["per_limit"]["keepout"]["violations"] == 1
    # Not the approach phase: the corridor and overshoot limits do not apply.
    assert not only(events, "approach_corridor") and not only(events, "overshoot")


def test_an_approach_along_the_axis_through_the_overshoot_plane():
    mon, events = monitor(angle_deg=-90.0)  # docking axis along LVLH -y
    feed_line(mon, APPROACH, (0.0, -50.0, 0.0), (0.0, -20.0, 0.0), 100.0)
    mon.finish()
    (ep,) = only(events, "overshoot")
    assert ep.worst == pytest.approx(10.0, abs=1e-9)  # r2 - 20 m
    assert ep.end_t_s - ep.start_t_s == pytest.approx(100.0 / 3.0, abs=0.1)
    assert not only(events, "approach_corridor") and not only(events, "keepout")  # on the axis


def test_a_limit_exceeded_from_the_first_sample_is_the_scenario_s_not_a_guidance_violation():
    mon, events = monitor()
    # Starts 150 m behind the target (inside r1, outside the corridor) and leaves the sphere.
    feed_line(mon, RENDEZVOUS, (-150.0, 0.0, 0.0), (-250.0, 0.0, 0.0), 100.0)
    mon.finish()
    ((kind, ep),) = events
    assert kind == "safety_initial_violation" and ep.initial and ep.limit == "keepout"
    s = mon.summary()
    assert s["verdict"] == "started_unsafe" and s["violations"] == 0 and s["initial_violations"] == 1
    # A later entry is the guidance's: unsafe.
    feed_line(mon, RENDEZVOUS, (-250.0, 0.0, 0.0), (-190.0, 0.0, 0.0), 100.0, step=1)
    mon.finish()
    assert mon.summary()["verdict"] == "unsafe"


def test_the_docking_cone_near_the_port_and_its_tolerance():
    mon, events = monitor()
    port = np.array([0.5, 0.0, 0.0])
    # 10 cm off the axis, closing from 2 m to 0.2 m ahead of the port: outside once d < 0.1 / tan 8.
    feed_line(mon, DOCKING, port + (2.0, 0.1, 0.0), port + (0.2, 0.1, 0.0), 180.0, v=(-0.01, 0.0, 0.0))
    mon.finish()
    (ep,) = only(events, "docking_cone")
    assert ep.worst == pytest.approx(0.1 * math.cos(A8) - 0.2 * math.sin(A8), abs=1e-6)
    kinds = {kind for kind, e in events if e.limit == "docking_cone"}
    assert kinds == {"safety_violation"}  # 7.1 cm > the 2 cm tolerance
    # 1 cm off the axis at 0.2 m: 0.7 mm outside, within the tolerance: an excursion.
    mon2, events2 = monitor()
    feed_line(mon2, DOCKING, port + (2.0, 0.01, 0.0), port + (0.05, 0.01, 0.0), 180.0, v=(-0.01, 0.0, 0.0))
    mon2.finish()
    (kind, ep2), = [(k, e) for k, e in events2 if e.limit == "docking_cone"]
    assert kind == "safety_excursion"
    assert ep2.worst == pytest.approx(0.01 * math.cos(A8) - 0.05 * math.sin(A8), abs=1e-6)
    assert mon2.summary()["verdict"] == "safe"


def test_docking_speed_over_v_max_with_and_without_the_tolerance():
    for speed, kind in ((0.105, "safety_violation"), (0.1005, "safety_excursion")):
        mon, events = monitor()
        feed_line(mon, DOCKING, (11.0, 0.0, 0.0), (10.0, 0.0, 0.0), 10.0, v=(-0.09, 0.0, 0.0))
        feed_line(mon, DOCKING, (10.0, 0.0, 0.0), (10.0 - speed * 10.0, 0.0, 0.0), 10.0, v=(-speed, 0.0, 0.0), step=1)
        mon.finish()
        (k, ep), = [(k, e) for k, e in events if e.limit == "docking_speed"]
        assert k == kind and ep.worst == pytest.approx(speed - 0.1, abs=1e-12)


def test_collision_and_contact_conditions():
    mon, events = monitor()
    feed_line(mon, DOCKING, (0.45, 0.0, 0.0), (0.05, 0.0, 0.0), 40.0, v=(-0.01, 0.0, 0.0))
    # Contact 10 cm off the axis at 0.2 m/s relative to the (fixed) port.
    mon.contact(5, 40.0, np.array([0.7, 0.1, 0.0, -0.2, 0.0, 0.0]))
    mon.finish()
    (col,) = only(events, "collision")
    assert col.worst == pytest.approx(0.3 - 0.05, abs=1e-9)
    (lat,) = only(events, "contact_lateral")
    assert lat.worst == pytest.approx(0.1 - LIM.contact_lateral_max_m, abs=1e-12)
    (spd,) = only(events, "contact_speed")
    assert spd.worst == pytest.approx(0.2 - LIM.contact_speed_max_mps, abs=1e-12)
    assert mon.figures["contact"]["lateral_offset_m"] == pytest.approx(0.1)


def test_commanded_and_realised_delta_v_against_u_max():
    mon, events = monitor()
    t = np.array([0.0, 30.0])
    x = np.tile([300.0, 0.0, 0.0, 0.0, 0.0, 0.0], (2, 1))
    mon.period(RENDEZVOUS, 0, t, x, dv_cmd_lvlh_mps=[0.1786, 0.0, 0.0], dv_realised_lvlh_mps=[0.19, 0.0, 0.0])
    mon.period(RENDEZVOUS, 1, t + 30, x, dv_cmd_lvlh_mps=[0.0, -0.2, 0.0], dv_realised_lvlh_mps=[0.0, -0.25, 0.0])
    mon.finish()
    # u_max exactly is allowed; 0.19 is within 3 sigma_w (4.62 %) of it; the second period is over both.
    (cmd,) = only(events, "thrust_command")
    assert cmd.worst_step == 1 and cmd.worst == pytest.approx(0.2 - 0.1786, abs=1e-12)
    (real,) = only(events, "thrust_realised")
    assert real.worst_step == 1 and real.worst == pytest.approx(0.25 - 0.1786 * (1 + 3 * 0.0462), abs=1e-12)


def test_a_path_inside_the_corridor_is_safe_and_its_figures_are_reported():
    mon, events = monitor(angle_deg=-90.0)
    feed_line(mon, RENDEZVOUS, (0.0, -1000.0, 5.0), (0.0, -220.0, 5.0), 600.0)
    feed_line(mon, APPROACH, (0.0, -220.0, 5.0), (0.0, -31.0, 1.0), 300.0, step=1)
    mon.finish()
    s = mon.summary()
    assert events == [] and s["verdict"] == "safe" and s["violations"] == 0
    assert s["figures"]["min_axial_distance_approach_m"] == pytest.approx(31.0)
    assert s["figures"]["min_range_com_m"] == pytest.approx(math.hypot(31.0, 1.0))


def test_a_spinning_target_turns_its_corridor_under_a_chaser_that_holds_still():
    # The chaser holds at 100 m on the initial axis; the corridor turns at 0.5 deg/s and leaves it after
    # 15 deg / 0.5 = 30 s: from then on the chaser is outside it, by 100 sin(theta - 15 deg).
    mon, events = monitor(spin_deg_s=0.5)
    t = np.linspace(0.0, 60.0, 601)
    x = np.tile([100.0, 0.0, 0.0, 0.0, 0.0, 0.0], (len(t), 1))
    mon.period(APPROACH, 0, t, x)
    mon.finish()
    (ep,) = only(events, "approach_corridor")
    assert ep.start_t_s == pytest.approx(30.0, abs=0.11)
    # At 60 s the body has turned 30 deg: the nearest face's row gives 100 (sin 30 cos 15 - cos 30 sin 15).
    assert ep.worst == pytest.approx(100.0 * math.sin(math.radians(15.0)), abs=1e-6)


def test_pyramid_rows_are_unit_and_open_along_the_docking_axis():
    q = np.array([math.cos(0.3), 0.0, 0.0, math.sin(0.3)])  # 0.6 rad about z
    rows = pyramid_rows(q, A15)
    np.testing.assert_allclose(np.linalg.norm(rows, axis=1), 1.0, atol=1e-15)
    axis = np.array([math.cos(0.6), math.sin(0.6), 0.0])
    assert np.all(rows @ (10.0 * axis) < 0.0) and np.all(rows @ (-10.0 * axis) > 0.0)


# ---- the truth path the monitor is fed -----------------------------------------------------------

@pytest.mark.parametrize("truth", ["cw", "nonlinear"])
def test_the_truth_path_samples_the_period_and_its_burns(truth):
    sim = Simulator("case1_vbar", truth=truth, thrust_noise=False, sensor_noise=False, path_sample_s=1.0)
    x0 = sim.truth_lvlh()
    pulses = [2.5, 0.0, 0.0, 4.0, 0.0, 0.0]
    r = sim.apply_command(pulses, 30.0, 0.5)
    t = r.path_t_s - r.t_start_s
    assert t[0] == 0.0 and t[-1] == pytest.approx(30.0)
    assert np.all(np.diff(t) > 0.0) and np.max(np.diff(t)) <= 1.0 + 1e-12
    for edge in (0.5, 3.0, 4.5):  # burn start, +x end, -y end
        assert np.min(np.abs(t - edge)) < 1e-12
    np.testing.assert_array_equal(r.path_lvlh[0], x0)
    np.testing.assert_array_equal(r.path_lvlh[-1], r.truth_after)
    if truth == "cw":
        # Independent closed form at every sample: coast, then two thrust segments, then coast.
        n = sim.mean_motion_rad_s
        a = np.array([0.5 / 14.0, -0.5 / 14.0, 0.0])
        def state(tau):
            x = cw_stm(n, min(tau, 0.5)) @ x0
            if tau <= 0.5:
                return x
            d1 = min(tau, 3.0) - 0.5
            x = cw_stm(n, d1) @ x + cw_forced_response(n, d1) @ a
            if tau <= 3.0:
                return x
            d2 = min(tau, 4.5) - 3.0
            x = cw_stm(n, d2) @ x + cw_forced_response(n, d2) @ np.array([0.0, a[1], 0.0])
            return x if tau <= 4.5 else cw_stm(n, tau - 4.5) @ x
        for tau, x in zip(t, r.path_lvlh):
            np.testing.assert_allclose(x, state(tau), rtol=0, atol=1e-9)
    else:
        # Dense output of the integrator: the mid-burn state is continuous between its neighbours.
        mid = np.argmin(np.abs(t - 2.0))
        assert np.all(np.isfinite(r.path_lvlh)) and 0 < mid < len(t) - 1
