"""The HPIPM peer of the solver benchmark (rvd_pil/bench/hpipm.py, the C API of casadi's bundled HPIPM
through ctypes): its OCP form of our QPs (box bounds, masked missing sides, native soft rows, x0
eliminated) and its answers against ProxSuite's on small QPs of each guidance phase."""
import numpy as np
import pytest

pytest.importorskip("casadi", reason="HPIPM comes with casadi's wheel: pip install -e '.[test]' (make test installs it)")

from support.qp_forms import PHASES, solve_proxsuite  # noqa: E402

from rvd_pil.bench import hpipm  # noqa: E402


def test_ocp_form_masks_the_missing_sides():
    qp = PHASES["rendezvous"](6, np.random.default_rng(1))
    st = hpipm.ocp_form(qp)
    assert st[0]["nx"] == 0 and st[0]["A"].shape == (6, 0)  # x0 eliminated
    np.testing.assert_allclose(st[0]["b"], qp.A[0] @ qp.x0 + qp.b[0])
    for s in st[:-1]:  # |u|inf <= umax: two-sided input boxes, both sides real
        assert list(s["idxbu"]) == [0, 1, 2]
        assert s["lbu_mask"].tolist() == [1.0] * 3 and s["ubu_mask"].tolist() == [1.0] * 3
        np.testing.assert_allclose(s["ubu"], -s["lbu"])
    for s in st[1:]:  # the keep-out row (and the terminal cone): C x <= d, no lower side
        assert len(s["ug"]) >= 1
        assert s["lg_mask"].tolist() == [0.0] * len(s["ug"]) and s["ug_mask"].tolist() == [1.0] * len(s["ug"])
    last = st[-1]  # the soft terminal cone: 4 soft general rows, penalties on the upper slack as given
    assert len(last["idxs"]) == 4 and all(k >= len(last["idxbu"]) + len(last["idxbx"]) for k in last["idxs"])
    np.testing.assert_allclose(last["zu"], qp.zs[-1])


def test_docking_velocity_rows_become_state_boxes():
    qp = PHASES["docking"](5, np.random.default_rng(2))
    s = hpipm.ocp_form(qp)[2]
    assert list(s["idxbx"]) == [3, 4, 5]  # |v|inf <= vmax on the velocity states
    assert s["lbx_mask"].tolist() == [1.0] * 3 and s["ubx_mask"].tolist() == [1.0] * 3
    assert len(s["ug"]) == 4  # the cone rows stay general


@pytest.mark.parametrize("phase", sorted(PHASES))
def test_hpipm_agrees_with_proxsuite(phase):
    rng = np.random.default_rng(7)
    for _ in range(2):
        qp = PHASES[phase](8, rng)
        ref = solve_proxsuite(qp)
        assert ref.status == "solved"
        for mode, init, mu0 in (("speed", "cold", None), ("robust", "cold", None), ("robust", "rollout", "cost")):
            s = hpipm.HpipmSolver(qp, mode=mode, init=init, mu0=mu0)
            for _rep in range(2):  # a second solve starts over (cold, or from the same guess)
                st, it, t_us, x, u = s.solve()
                assert st == 0, (phase, mode, init, hpipm.STATUS.get(st), it)
                assert t_us > 0.0
                assert abs(qp.objective(x, u) - ref.objective) <= 1e-6 * max(1.0, abs(ref.objective)), (phase, mode, init)
                assert qp.violation(x, u) <= 1e-6
