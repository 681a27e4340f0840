"""The guidance under the dissertation's own disturbances, judged on the truth by the safety monitor.

Every run: the native flight executable over Zenoh, nonlinear truth (J2, drag), the Gauss-Markov
thrust amplitude error, sensor noise (5 cm, 1 mm/s), finite burns (the default rvd-run set-up, with
no control delay so that runs repeat). The figures asserted are the acceptance limits of the safety
verdict: no keep-out, corridor, overshoot or collision violation, docking-cone excursion at most 2 cm
and |v|inf at most v_max + 1 mm/s in docking. The full-size version (100 starts x 3 noise seeds) is
the benchmark `python -m rvd_pil.bench.safety_mc`.
"""
import pytest

from rvd_pil.host_sim import scenario
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.server import ServerConfig

DISTURBED = dict(truth="nonlinear", sensor_noise=True, thrust_noise=True, impulsive=False)
HARD_LIMITS = ("collision", "keepout", "approach_corridor", "overshoot", "thrust_command", "thrust_realised",
               "contact_speed", "contact_lateral")


def disturbed_run(tmp_path, scen, seed=0, flight_args=()):
    summary, run_dir = run_pil(scen, seed=seed, **DISTURBED, config=ServerConfig(delay_model="none"),
                               run_dir=tmp_path / (scen if isinstance(scen, str) else scen.name),
                               flight_args=list(flight_args))
    return summary, run_dir


def assert_safe(summary):
    s = summary.safety
    assert summary.end == "docked", summary.end
    violated = {name: st for name, st in s["per_limit"].items() if st["violations"]}
    assert s["verdict"] == "safe" and not violated, violated
    fig = s["figures"]
    assert fig["max_docking_cone_excursion_m"] <= 0.02
    assert fig["max_speed_inf_docking_mps"] <= 0.1 + 0.001
    for name in HARD_LIMITS:
        assert s["per_limit"][name]["violations"] == 0


@pytest.mark.parametrize("case", ["case1_vbar", "case2_rbar", "case3_rotating"])
def test_the_dissertation_cases_dock_safely_under_every_disturbance(tmp_path, flight_exe, case):
    summary, _ = disturbed_run(tmp_path, case)
    assert_safe(summary)


def test_the_turning_target_at_short_horizons_is_entered_only_at_a_speed_that_stays_in_its_corridor(tmp_path, flight_exe):
    """Case 3 (target turning at 0.15 deg/s) at horizons 15 / 5 / 5: the rendezvous ends 214 m out, where the
    corridor's faces move at up to 0.56 m/s. The approach entry counts that motion when it decides whether
    the approach can stop before a face; counting the chaser's velocity alone, the run entered moving at
    about 1 m/s relative to the turning corridor and left it by 5 m on this seed."""
    summary, _ = disturbed_run(tmp_path, "case3_rotating", flight_args=("--horizon", "15,5,5"))
    assert_safe(summary)


def test_ten_random_starts_dock_safely_with_no_infeasible_approach_qp(tmp_path, flight_exe):
    """(A rendezvous QP can still be infeasible when a fast-closing chaser meets the re-centred keep-out
    planes far out; the recovery QP flies it and the record says so.)"""
    from rvd_pil.host_sim.record import load_run

    approach_infeasible = 0
    for start in range(1, 11):
        summary, run_dir = disturbed_run(tmp_path, scenario.random_scenario(start))
        assert_safe(summary)
        _, steps = load_run(run_dir)
        approach_infeasible += int(((steps["phase"] == 2) & (steps["solver_status"] == 2)).sum())
    assert approach_infeasible == 0


def test_the_nominal_mpc_without_filter_or_margins_is_judged_unsafe(tmp_path, flight_exe):
    """The monitor must be able to fire on a real run: the dissertation's nominal MPC on raw
    measurements (no navigation filter, no margins) under the same disturbances leaves its limits."""
    from rvd_pil.host_sim.record import load_events, load_run

    summary, run_dir = disturbed_run(tmp_path, "case1_vbar", flight_args=("--nav-filter", "off", "--margins", "off"))
    assert summary.safety["verdict"] == "unsafe"
    violated = {name for name, st in summary.safety["per_limit"].items() if st["violations"]}
    assert violated & {"keepout", "approach_corridor", "overshoot", "docking_cone", "docking_speed"}
    meta, _ = load_run(run_dir)
    assert meta["safety"]["verdict"] == "unsafe"
    events = load_events(run_dir)
    assert (events["kind"] == "safety_violation").sum() == summary.safety["violations"]


def approach_corridor_clearance_m(run_dir):
    """The least distance inside the approach corridor over the approach phase, in truth (the monitor's
    worst corridor margin of each period, sampled along the path; negative = outside)."""
    from rvd_pil.host_sim.record import load_run

    _, steps = load_run(run_dir)
    return -float(steps.loc[steps["phase"] == 2, "safety_corridor_m"].max())


@pytest.mark.parametrize("start", [56, 85])
def test_a_braking_thruster_weaker_than_its_estimate_does_not_swing_the_approach_out_of_the_corridor(
        tmp_path, flight_exe, start):
    """Noise seed 30 lets the thruster that brakes these approaches (+y) drift 10 % weaker while it is
    unused, from the rendezvous to the approach's braking; the filter learns it only once it fires. A plan
    that brakes at the last moment with all of its authority can then hold the hard overshoot plane only
    through the CW coupling, by a lateral swing out of the soft corridor: 7.2 m (start 56) and 7.4 m (85)
    outside it inside r1 before the braking curve. With it the chaser stays metres inside."""
    summary, run_dir = disturbed_run(tmp_path, scenario.random_scenario(start), seed=30)
    assert_safe(summary)
    assert approach_corridor_clearance_m(run_dir) >= 2.0


def test_without_the_braking_curve_the_monitor_sees_the_lateral_swing(tmp_path, flight_exe):
    """The same run with the braking curve off: the swing the test above guards against is there. (The
    rendezvous' braking curve off too: it hands this run over to the approach at another state.)"""
    summary, run_dir = disturbed_run(tmp_path, scenario.random_scenario(56), seed=30,
                                     flight_args=("--set", "margins.approach_brake_fraction=0",
                                                  "--set", "margins.rendezvous_brake_fraction=0"))
    assert summary.safety["verdict"] == "unsafe"
    assert summary.safety["per_limit"]["approach_corridor"]["violations"] >= 1
    assert approach_corridor_clearance_m(run_dir) <= -5.0
