"""One configuration, one source of truth: the scenario's vehicle and [guidance] settings reach the
flight software at the start of a run (config message), come back in its echo and land in the record;
a run whose flight side plans with another vehicle is refused unless asked for; every guidance
setting is a flight `--set` parameter; a misspelled key is a one-line error naming key and file.

Independent truth: the host simulator's thruster model (F t / m with the scenario's F and m) against
what the flight software expects its pulses to deliver (dv_alloc, from the vehicle it plans with).
"""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rvd_pil import flight_sw
from rvd_pil.host_sim import scenario as scenarios
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.record import load_events, load_run
from rvd_pil.host_sim.server import ServerConfig

ROOT = Path(__file__).resolve().parent.parent
IDEAL = dict(truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True)
CASE1 = (ROOT / "rvd_pil" / "host_sim" / "scenarios" / "case1_vbar.toml").read_text()


def _scenario(tmp_path, name, replace=(), extra=""):
    text = CASE1
    for old, new in replace:
        assert old in text
        text = text.replace(old, new, 1)
    path = tmp_path / f"{name}.toml"
    path.write_text(text + extra)
    return path


def _run(tmp_path, scenario, name, flight_args=(), **cfg):
    mean_motion = flight_sw.GuidanceParams().mean_motion_rad_s()
    return run_pil(scenarios.load(scenario), **IDEAL, sim_options={"cw_mean_motion_rad_s": mean_motion},
                   config=ServerConfig(delay_model="none", **cfg), flight_args=list(flight_args),
                   run_dir=tmp_path / name)


def _pulses_deliver_what_the_flight_expects(steps):
    """Ideal run: the truth's delta-v of every step equals the flight software's dv_alloc."""
    burned = steps[steps["phase"].notna() & (steps["phase"] < 4)]
    realised = burned[["dv_x_mps", "dv_y_mps", "dv_z_mps"]].to_numpy()
    expected = burned[["dv_alloc_x_mps", "dv_alloc_y_mps", "dv_alloc_z_mps"]].to_numpy()
    assert np.abs(realised).max() > 0.05  # the run burned
    np.testing.assert_allclose(realised, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("change, key, value", [
    (("force_n = 0.5 ", "force_n = 1.0 "), "thrust_n", 1.0),
    (("mass_kg = 14.0\ndrag", "mass_kg = 20.0\ndrag"), "mass_kg", 20.0),
])
def test_the_flight_software_plans_with_the_scenarios_vehicle(tmp_path, flight_exe, change, key, value):
    summary, run_dir = _run(tmp_path, _scenario(tmp_path, key, [change]), key)
    assert summary.end == "docked", summary.end
    meta, steps = load_run(run_dir)
    assert meta["flight_config"][key] == value and meta["flight_config"]["status"] == 0
    assert meta["flight_config"]["law"] == "fast_mpc_3phase"
    assert any(e == "flight_config" for e in load_events(run_dir)["kind"])
    _pulses_deliver_what_the_flight_expects(steps)
    # The longest pulse the flight declares follows the vehicle: u_max m / F.
    m = value if key == "mass_kg" else 14.0
    f = value if key == "thrust_n" else 0.5
    assert summary.hello.max_pulse_s[0] == pytest.approx(0.1786 * m / f, rel=1e-12)
    # Delta-v is planned in m/s: with the vehicle known, the authority per period is the same and so
    # is the delta-v within what the minimum impulse bit changes (a few percent), not the double a
    # flight software planning with 0.5 N would burn with 1 N thrusters.
    nominal, _ = _run(tmp_path, "case1_vbar", "nominal")
    assert summary.dv_total_mps == pytest.approx(nominal.dv_total_mps, rel=0.1)


def test_the_flight_software_docks_at_the_scenarios_port(tmp_path, flight_exe):
    """The port is the scenario's (here 2 m out on the docking axis, the flight software's default is
    0.5 m): the flight software aims at it, so the ideal run ends within r3 (0.5 m, where the flight
    declares docking) of that port in truth, not 1.5 m short of the port in front of the default one."""
    path = _scenario(tmp_path, "port", [("docking_port_body_m = [0.5, 0.0, 0.0]", "docking_port_body_m = [2.0, 0.0, 0.0]")])
    summary, run_dir = _run(tmp_path, path, "port")
    assert summary.end == "docked", summary.end
    assert summary.final_range_to_port_m <= flight_sw.GuidanceParams().dock_tolerance_m
    meta, steps = load_run(run_dir)
    assert "port_body_x_m=2.0" in " ".join(meta["flight_command"])
    last = steps.iloc[-1]
    assert last["range_port_m"] == pytest.approx(summary.final_range_to_port_m, abs=1e-9)


def test_a_vehicle_mismatch_is_refused_unless_asked_for(tmp_path, flight_exe):
    pinned = ["--set", "thrusters.mass_kg=16"]  # the flight command line pins the mass
    summary, run_dir = _run(tmp_path, "case1_vbar", "refused", pinned)
    assert summary.end.startswith("vehicle mismatch") and "mass_kg 16.0 (truth 14.0)" in summary.end
    assert summary.steps == 0
    events = load_events(run_dir)
    assert "vehicle_mismatch" in set(events["kind"])
    summary, run_dir = _run(tmp_path, "case1_vbar", "allowed", pinned, allow_vehicle_mismatch=True)
    assert summary.steps > 10 and load_run(run_dir)[0]["flight_config"]["mass_kg"] == 16.0
    assert load_run(run_dir)[0]["flight_config"]["pinned"] == 1


def test_guidance_settings_of_the_scenario_reach_the_flight_software(tmp_path, flight_exe):
    path = _scenario(tmp_path, "settings", extra='\n[guidance]\n"rendezvous.N" = 20\n"docking.terminal_weight" = "dare"\n'
                                                  'recovery = false\n"approach.Q" = [1, 1, 1, 2, 2, 2]\n')
    summary, run_dir = _run(tmp_path, path, "settings")
    assert summary.end == "docked", summary.end
    echo = load_run(run_dir)[0]["flight_config"]
    assert list(echo["horizon"]) == [20, 15, 12] and summary.hello.horizon == (20, 15, 12)
    assert "docking.terminal_weight=dare" in echo["settings"] and "recovery=off" in echo["settings"]


def test_list_params_offers_the_guidance_settings_and_checks_values(flight_exe):
    out = subprocess.run([str(flight_exe), "--list-params"], capture_output=True, text=True, check=True).stdout
    listed = dict(line.split(None, 1) for line in out.splitlines())
    assert listed["rendezvous.Q"].strip() == "1,1,100,1,1,10"
    assert listed["docking.R"].strip() == "1000000,1000000,1000000"
    assert listed["thrusters.thrust_N"].strip() == "0.5" and listed["thrusters.mass_kg"].strip() == "14"
    for name in ("rendezvous.terminal_weight", "rendezvous_objective", "recovery", "rendezvous.N",
                 "rendezvous_use_setpoint"):
        assert name in listed
    out = subprocess.run([str(flight_exe), "--list-params", "--set", "rendezvous_objective=one_norm",
                          "--set", "recovery=off", "--set", "approach.Q=2,2,2,3,3,3"],
                         capture_output=True, text=True, check=True).stdout
    assert "one_norm" in out and "2,2,2,3,3,3" in out
    for bad, named in (("rendezvous.Q=1,2", "rendezvous.Q"), ("docking.terminal_weight=riccati", "riccati"),
                       ("rendezvous.N=2.5", "rendezvous.N"), ("mass=3", "mass")):
        r = subprocess.run([str(flight_exe), "--list-params", "--set", bad], capture_output=True, text=True)
        assert r.returncode == 2 and named in r.stderr.splitlines()[0], r.stderr


def _rvd_run(*args):
    return subprocess.run([sys.executable, "-m", "rvd_pil.host_sim.cli", *args, "-q"], capture_output=True, text=True,
                          cwd=ROOT, timeout=600)


def test_misspelled_keys_are_one_line_errors_naming_key_and_file(tmp_path, flight_exe):
    bad = _scenario(tmp_path, "misspelled", [("force_n = 0.5 ", "forcen = 0.5 ")])
    r = _rvd_run(str(bad), "--ideal", "--truth", "cw")
    assert r.returncode == 2 and "forcen" in r.stderr and str(bad) in r.stderr
    assert "Traceback" not in r.stderr
    bad = _scenario(tmp_path, "misspelled_guidance", extra='\n[guidance]\n"rendezvous.NN" = 20\n')
    r = _rvd_run(str(bad), "--ideal", "--truth", "cw", "--out", str(tmp_path / "refused"))
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "rendezvous.NN" in lines[0] and str(bad) in lines[0]
