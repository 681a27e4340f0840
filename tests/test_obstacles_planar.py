"""Dong, Ghiglino et al.'s 2-D scenario through the whole harness: the planar truth of an air-bearing
table, the native flight executable over Zenoh with the chaser's attitude and torque on the link, the
holding radius and the entry cone in the MPC, judged on the truth.

- test case A, ideal (no noise, impulsive): docks, every obstacle's clearance >= 1, the chaser faces
  the target's port at contact, the torque it commanded turned it there;
- test case B, disturbed (sensor and attitude noise, thrust error, finite burns): docks, clearance >= 1;
- the in-process path flies test case A as the executable does;
- after Gupta, Sarna et al.: docking round a platform past two stationary debris (which the
  obstacle-blind guidance flies through).
"""
import math

import numpy as np

from rvd_pil.host_sim import scenario
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.record import load_run
from rvd_pil.host_sim.server import ServerConfig


def assert_docked_clear(summary):
    assert summary.end == "docked", summary.end
    s = summary.safety
    assert s["verdict"] == "safe", s["episodes"]
    for oid, f in s["figures"]["obstacles"].items():
        assert f["min_clearance"] >= 1.0, (oid, f)


def test_case_a_ideal_docks_facing_the_port_around_the_moving_obstacles(tmp_path):
    summary, run_dir = run_pil("dong_2d_case_a", sensor_noise=False, thrust_noise=False, impulsive=True,
                               config=ServerConfig(delay_model="none"), run_dir=tmp_path / "a")
    assert_docked_clear(summary)
    meta, steps = load_run(run_dir)
    assert meta["truth"] == "planar"
    last = steps.iloc[-1]
    target_angle = 2.0 * math.atan2(last["target_qz"], last["target_qw"])
    error = (last["chaser_angle_rad"] - target_angle - math.pi + math.pi) % (2 * math.pi) - math.pi
    assert abs(error) < math.radians(2.0), math.degrees(error)  # started 90 deg off
    torque = steps["torque_z_nm"].to_numpy(dtype=float)
    assert np.nanmax(np.abs(torque)) <= scenario.load("dong_2d_case_a").planar.torque_max_nm
    assert np.nanmax(np.abs(torque)) > 0.01  # the first steps turn it hard
    # Within the holding radius' minimum only at the end, on the axis: no contact with the target body.
    assert summary.safety["figures"]["min_range_com_m"] >= 0.40


def test_case_b_disturbed_docks_around_the_moving_obstacles(tmp_path):
    summary, _ = run_pil("dong_2d_case_b", seed=2, sensor_noise=True, thrust_noise=True, impulsive=False,
                         config=ServerConfig(delay_model="none"), run_dir=tmp_path / "b")
    assert_docked_clear(summary)


def test_the_in_process_path_flies_the_planar_scenario_as_the_executable_does(tmp_path):
    from rvd_pil.studies.inprocess import run_in_process
    from rvd_pil.studies.settings import GuidanceSettings

    sc = scenario.load("dong_2d_case_a")
    native, native_dir = run_pil(sc, sensor_noise=False, thrust_noise=False, impulsive=True,
                                 config=ServerConfig(delay_model="none"), run_dir=tmp_path / "native")
    settings = GuidanceSettings(horizon=(15, 15, 15), period_s=(2.0, 2.0, 2.0))  # the scenario's own
    inproc, inproc_dir = run_in_process(sc, settings, sensor_noise=False, thrust_noise=False, impulsive=True,
                                        config=ServerConfig(delay_model="none"), run_dir=tmp_path / "inproc")
    assert inproc.end == native.end == "docked"
    _, a = load_run(native_dir)
    _, b = load_run(inproc_dir)
    cols = ["truth_x_m", "truth_y_m", "chaser_angle_rad", "torque_z_nm", "dv_x_mps", "dv_y_mps"]
    assert np.array_equal(a[cols].to_numpy(), b[cols].to_numpy(), equal_nan=True)  # the last row has no command


def test_docking_round_a_platform_past_stationary_debris(tmp_path):
    """After Gupta, Sarna et al.: the platform's circle (the fixed holding radius) and two debris on the
    way; without the obstacle rows the same guidance flies through the debris."""
    summary, _ = run_pil("gupta_debris_docking", sensor_noise=False, thrust_noise=False, impulsive=True,
                         config=ServerConfig(delay_model="none"), run_dir=tmp_path / "rows")
    assert_docked_clear(summary)
    assert summary.safety["figures"]["min_range_com_m"] >= 2.5 - 1e-3  # round the platform, never into it
    blind, _ = run_pil("gupta_debris_docking", sensor_noise=False, thrust_noise=False, impulsive=True,
                       config=ServerConfig(delay_model="none"), run_dir=tmp_path / "blind",
                       flight_args=["--obstacles", "off"])
    assert min(o["min_clearance"] for o in blind.safety["figures"]["obstacles"].values()) < 1.0
