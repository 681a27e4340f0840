"""flight_sw's solver against DAQP on the flight CPUs (rvd_pil/bench/target_solvers.py): both cross-built,
the same QPs solved under QEMU, each solve priced by the cycle model.

Independent truths: every answer of both solvers, read back from the emulated process, agrees with
ProxSuite's objective on the host (soft rows, the interior point's rendezvous QP and the active set's
docking and approach QPs), and a QP made infeasible through the dynamics (an LP's reach, exceeded)
is called infeasible by the reference and by both; the emulated flight_sw takes the active-set path on the same QPs as the
native build does (a change count, zero interior-point iterations) and the interior point on the
rendezvous; every solve is one priced region; the table's ratios are the quotients of its medians.
Hostile input: a truncated or foreign QP file stops each driver with its message, nothing solved."""
from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest

from rvd_pil import flight_sw
from support.qp_forms import approach_qp, docking_qp, rendezvous_qp, save_qp_set, with_reach_row
from support.user_mode import cross_target_or_skip

pytestmark = pytest.mark.qemu


@pytest.fixture(scope="module")
def qps():
    rng = np.random.default_rng(17)
    beyond_reach = with_reach_row(docking_qp(5, rng), 3, np.eye(6)[0], 0.05)  # infeasible through the dynamics
    return [docking_qp(5, rng), docking_qp(5, rng), docking_qp(12, rng), approach_qp(5, rng), approach_qp(5, rng),
            rendezvous_qp(15, rng), beyond_reach]


@pytest.fixture(scope="module")
def measured(qps, tmp_path_factory):
    from rvd_pil.bench import target_solvers
    from rvd_pil.qemu import cycles, plugin
    cross_target_or_skip("rpi3"), cross_target_or_skip("q7s")
    if plugin.build_profile() is None:
        pytest.skip("block-profile plugin not built: run `python -m rvd_pil.qemu prepare` (or set RVD_QEMU_FETCH=1)")
    if shutil.which(cycles.LLVM_MCA) is None:
        pytest.skip("llvm-mca-15 missing: tools/install-deps pil")
    work = tmp_path_factory.mktemp("target_solvers")
    return work, target_solvers.measure(qps, ["rpi3", "q7s"], work=work)


def test_both_solvers_answer_every_qp_on_both_targets_as_the_reference(measured, qps):
    _, result = measured
    for target in ("rpi3", "q7s"):
        for solver in ("flight_sw", "daqp"):
            rows = result[target][solver]
            assert len(rows) == len(qps)
            assert [r["phase"] for r in rows] == [qp.phase for qp in qps]
            bad = [(k, r["status"]) for k, r in enumerate(rows) if not r["agrees"]]
            assert not bad, (target, solver, bad)
            # the QP beyond reach: the reference, DAQP (exit flag -1) and flight_sw all call it infeasible
            assert [r["feasible"] for r in rows] == [True] * 6 + [False]
            assert rows[-1]["status"] == ("-1" if solver == "daqp" else "infeasible")
            # one priced region per solve, with its instructions and a modelled time in its bounds
            for r in rows:
                assert r["instructions"] > 1000
                assert 0.0 < r["us_low"] <= r["us_nominal"] <= r["us_high"]


def test_the_emulated_solver_takes_the_native_solvers_path(measured, qps):
    """The same method on the target as natively: the active set (changes, no interior-point
    iterations) on docking and approach, the interior point on the rendezvous."""
    work, _ = measured
    from rvd_pil.qemu import build, targets, user
    t = targets.load("rpi3")
    exe = build.find_executable(build.build_dir(t), "rvd_solve_qp_file").path
    out = user.run(t, exe, [str(work / "ocp.bin")], timeout_s=300).stdout.splitlines()
    assert len(out) == len(qps)
    moved = 0
    for line, qp in zip(out, qps):
        words = line.split()
        changes, iterations = int(words[5]), int(words[7])
        native = flight_sw.OcpSolver(qp.nx, qp.nu, qp.nc, qp.ns if qp.idxs else None,
                                     mode="interior_point" if qp.phase == "rendezvous" else "converged",
                                     tol=1e-8, warm_start=False)
        native.cold_slack_floor = getattr(flight_sw.GuidanceParams(), qp.phase).solver_cold_slack_floor  # the tool's
        native.setup(*qp.args()[:-1], **qp.kw())
        r = native.solve(*qp.args(), **qp.kw())
        if qp.phase == "rendezvous":
            assert iterations > 0 and changes == 0 and r.iterations > 0
            assert abs(iterations - r.iterations) <= 1, line
        else:
            assert iterations == 0 and r.iterations == 0
            assert abs(changes - r.active_set_changes) <= 1, line
            moved += changes > 0
    assert moved >= 3  # QPs whose optimum is not the unconstrained one
    assert out[-1].split()[3] == "infeasible"


def test_the_table_sets_each_cell_side_by_side(measured, capsys):
    from rvd_pil.bench import target_solvers
    _, result = measured
    rows = target_solvers.table(result)
    cells = {(r["target"], r["phase"], r["N"]) for r in rows}
    assert cells == {(t, p, n) for t in ("rpi3", "q7s") for p, n in
                     (("rendezvous", 15), ("approach", 5), ("docking", 5), ("docking", 12))}
    for r in rows:
        assert r["ratio_us_median"] == pytest.approx(r["daqp_us_median"] / r["flight_sw_us_median"])
        assert r["ratio_insns_median"] == pytest.approx(r["daqp_insns_median"] / r["flight_sw_insns_median"])
        assert r["flight_sw_bad"] == 0 and r["daqp_bad"] == 0
        # the infeasible docking 5 QP is judged, not timed: the medians are over the feasible two
        expect = (3, 1) if (r["phase"], r["N"]) == ("docking", 5) else (r["flight_sw_count"], 0)
        assert (r["flight_sw_count"], r["flight_sw_infeasible"]) == expect
    target_solvers.print_table(rows)
    out = capsys.readouterr().out
    assert out.count("docking") == 4 and "ratio = DAQP / flight_sw" in out


def test_the_command_line_writes_its_table(qps, tmp_path, measured, capsys):
    from rvd_pil.bench import target_solvers
    path = tmp_path / "two.npz"
    save_qp_set(path, qps[:2])
    assert target_solvers.main(["--qp-set", str(path), "--cells", "docking:5", "--targets", "rpi3",
                                "--out", str(tmp_path)]) == 0
    saved = json.loads((tmp_path / "target-solvers.json").read_text())
    assert [(r["target"], r["phase"], r["N"]) for r in saved["table"]] == [("rpi3", "docking", 5)]
    assert len(saved["solves"]["rpi3"]["flight_sw"]) == 2
    assert (tmp_path / "target-solvers.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # without a set: the host benchmark's synthetic MPC QPs, each answer checked as above
    assert target_solvers.main(["--cells", "docking:5", "--per-cell", "2", "--targets", "rpi3"]) == 0
    out = capsys.readouterr().out
    assert "2 QPs of the synthetic MPC set" in out
    assert re.search(r"^rpi3\s+docking\s+5 .* 0/2 / 0/2$", out, re.M), out
    with pytest.raises(SystemExit):
        target_solvers.main(["--qp-set", str(path), "--cells", "docking"])
    with pytest.raises(SystemExit):
        target_solvers.main(["--qp-set", str(path), "--cells", "rendezvous:45"])  # none in the set
    assert "no QP of" in capsys.readouterr().err


@pytest.mark.parametrize("solver", ["flight_sw", "daqp"])
def test_a_truncated_or_foreign_qp_file_stops_the_driver_with_its_reason(measured, solver, tmp_path):
    from rvd_pil.bench import target_solvers
    from rvd_pil.qemu import build, targets, user
    work, _ = measured
    t = targets.load("rpi3")
    exe = build.find_executable(build.build_dir(t), "rvd_solve_qp_file").path if solver == "flight_sw" \
        else target_solvers.build_daqp_driver(t)
    good = (work / ("ocp.bin" if solver == "flight_sw" else "condensed.bin")).read_bytes()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(good[: len(good) // 2])
    proc = user.run(t, exe, [str(cut)], timeout_s=120)
    assert proc.returncode == 2 and "file ends early" in proc.stderr
    foreign = tmp_path / "foreign.bin"
    foreign.write_bytes(b"NOTAQPFILE" + good[10:])
    proc = user.run(t, exe, [str(foreign)], timeout_s=120)
    assert proc.returncode == 2 and "magic" in proc.stderr and "qp 0" not in proc.stdout


def test_a_qp_the_solver_would_refuse_stops_the_flight_sw_driver_before_any_solve(measured, qps, tmp_path):
    """A soft-row index beyond its stage's rows, or a NaN in the data: the driver names the QP and
    what is wrong (OcpQp::validate) instead of solving it."""
    import dataclasses
    from rvd_pil.bench import target_solvers
    from rvd_pil.qemu import build, targets, user
    t = targets.load("rpi3")
    exe = build.find_executable(build.build_dir(t), "rvd_solve_qp_file").path
    soft = qps[3]  # an approach QP: soft cone rows
    bad_index = dataclasses.replace(soft, idxs=[list(k) for k in soft.idxs])
    bad_index.idxs[1][0] = soft.C[1].shape[0] + 5
    nan_d = dataclasses.replace(soft, d=[np.array(d, float) for d in soft.d])
    nan_d.d[2][0] = np.nan
    for qp, why in ((bad_index, "idxs[1]"), (nan_d, "NaN or Inf")):
        path = tmp_path / "bad.bin"
        target_solvers.write_ocp_file(path, [qps[0], qp])
        proc = user.run(t, exe, [str(path)], timeout_s=120)
        assert proc.returncode == 2 and "QP 1:" in proc.stderr and why in proc.stderr, proc.stderr
        assert proc.stdout.startswith("qp 0 status solved") and "qp 1" not in proc.stdout
