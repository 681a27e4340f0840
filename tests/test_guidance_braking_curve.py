"""The approach braking curve in the undisturbed world: a short horizon must not plan past the point
where the chaser can still stop before the overshoot plane.

Ideal world (CW truth, no noise, impulsive burns, no control delay), the native flight executable over
Zenoh, judged on the truth by the safety monitor. With the approach horizon N = 5 at Ts = 20 s the plan
sees 100 s ahead; braking from the 1-1.4 m/s it reaches in the approach takes longer. Without the curve
the plan meets the plane infeasible and the recovery QP swings the chaser out of the corridor (the ch. 4
study: 500 of 500 starts unsafe at Ts 5-20 s).
"""
import pytest

from rvd_pil.host_sim import scenario
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.server import ServerConfig

IDEAL = dict(truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True)
SHORT_APPROACH = ("--horizon", "30,5,12")
OVERSHOOT_PLANE_M = 30.0  # r2 of the dissertation's Table 3.1


def ideal_run(tmp_path, start, flight_args):
    scen = scenario.random_scenario(start)
    summary, _ = run_pil(scen, seed=0, **IDEAL, config=ServerConfig(delay_model="none"),
                         run_dir=tmp_path / f"{scen.name}-{len(flight_args)}", flight_args=list(flight_args))
    return summary


@pytest.mark.parametrize("start", [3, 7])
def test_a_short_approach_horizon_stops_before_the_plane_in_the_ideal_world(tmp_path, flight_exe, start):
    summary = ideal_run(tmp_path, start, SHORT_APPROACH)
    s = summary.safety
    assert summary.end == "docked", summary.end
    violated = {name: st for name, st in s["per_limit"].items() if st["violations"]}
    assert s["verdict"] == "safe" and not violated, violated
    assert s["figures"]["min_axial_distance_approach_m"] >= OVERSHOOT_PLANE_M


def test_without_the_braking_curve_a_short_approach_horizon_leaves_the_corridor(tmp_path, flight_exe):
    """The same start with the curve off: the monitor sees what the curve prevents (19 m outside)."""
    summary = ideal_run(tmp_path, 3, SHORT_APPROACH + ("--set", "margins.approach_brake_fraction=0"))
    assert summary.safety["verdict"] == "unsafe"
    assert summary.safety["per_limit"]["approach_corridor"]["violations"] >= 1
