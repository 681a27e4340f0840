"""The example plug-in law (examples/guidance/cw_target), written from flight_sw/include/rvd_guidance.h
alone: built from its folder with the harness, flown on Case 1, it docks; its named values reach the
record. Independent truth: the host's truth distance to the port at the end, and the law's own
named value t_go_s (the remaining transfer time it plans with) against the simulation clock."""
import re
from pathlib import Path

import pandas as pd
import pytest

from rvd_pil.host_sim.guidance_build import build_native
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.record import load_run
from rvd_pil.host_sim.server import ServerConfig

ROOT = Path(__file__).resolve().parent.parent
LAW = ROOT / "examples" / "guidance" / "cw_target"


def test_the_example_law_uses_only_the_public_header():
    includes = re.findall(r'#include\s*[<"]([^>"]+)[>"]', (LAW / "cw_target.c").read_text())
    assert "rvd_guidance.h" in includes
    assert not [i for i in includes if "/" in i or i.startswith("flight_sw")], includes


def test_the_example_law_docks_case1(tmp_path):
    exe, manifest = build_native(LAW)
    summary, run_dir = run_pil("case1_vbar", truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True,
                               flight_exe=str(exe), flight_args=manifest.flight_args(),
                               config=ServerConfig(delay_model="none"), run_dir=tmp_path / "cw_target")
    assert summary.end == "docked", summary.end
    assert summary.final_range_to_port_m < 0.75
    meta, steps = load_run(run_dir)
    assert meta["flight_config"]["law"] == "cw_target"
    values = pd.read_csv(run_dir / "law_values.csv")
    t_go = values[values["name"] == "t_go_s"].set_index("step")["value"]
    # Rendezvous: the transfer time left shrinks with the simulation clock (30 s periods).
    assert t_go.loc[0] == pytest.approx(manifest.params["transfer_s"])
    assert t_go.loc[10] == pytest.approx(manifest.params["transfer_s"] - 10 * 30.0)
    assert set(steps["phase"].dropna().astype(int)) == {1, 2, 3, 4}


def test_rvd_run_guidance_with_a_folder_without_a_law_is_one_line_exit_2(tmp_path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "rvd_pil.host_sim.cli", "case1_vbar", "--guidance", str(tmp_path), "-q"],
                       capture_output=True, text=True, cwd=ROOT, timeout=120)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and str(tmp_path / "law.toml") in lines[0], r.stderr
