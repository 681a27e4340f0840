"""Guidance with obstacles (flight_sw/guidance/obstacles.hpp) in closed loop against the impulsive CW
plant: the chaser's true path, sampled every second between commands, keeps every obstacle's clearance
(r - r_obs)' S (r - r_obs) >= 1, computed here by rvd_pil.host_sim.obstacles from the obstacles' own motion.
Without obstacle rows the same geometry is violated (so the test can fail)."""
import math

import numpy as np
import pytest

from rvd_pil import flight_sw as fsw
from rvd_pil.host_sim.cw import cw_stm
from rvd_pil.host_sim.obstacles import Obstacle, ObstacleField


def fly(params, case, obstacles, max_steps=400, tell=True):
    """Closed loop: each step the guidance is told the obstacles' current states, then the plant
    coasts the commanded impulse through the period. Returns (min clearance per id, docked, dv total)."""
    n = params.mean_motion_rad_s()
    field = ObstacleField(obstacles, n)
    c = fsw.dissertation_case(case)
    x, t = np.array(c["x0"], float), 0.0
    g = fsw.Guidance(params)
    worst = {o.id: math.inf for o in obstacles}
    dv = 0.0
    docked = False
    for k in range(max_steps):
        if tell:
            told = [fsw.Obstacle(o.id, xo[:3], xo[3:], np.array(o.semi_axes_m), np.array(o.q_lvlh_body), t, seen)
                    for o, xo, seen in field.sensed(t, x[:3])]
            g.set_obstacles(told, t, x[:3])
        cmd = g.step(fsw.NavInput(k, t, x, c["q_lvlh_body"], c["omega_body_rad_s"]))
        if cmd.phase == fsw.Phase.Docked:
            docked = True
            break
        xp = np.r_[x[:3], x[3:] + cmd.dv_alloc_mps]
        dv += float(np.linalg.norm(cmd.dv_alloc_mps))
        for tau in np.arange(0.0, cmd.period_s + 1e-9, 1.0):
            r = (cw_stm(n, tau) @ xp)[:3]
            for o in obstacles:
                if o.exists(t + tau):
                    worst[o.id] = min(worst[o.id], field.clearance(o, r, t + tau))
        x = cw_stm(n, cmd.period_s) @ xp
        t += cmd.period_s
    return worst, docked, dv, g


# Case 1's rendezvous path crosses x ~ -315 m, y ~ -950 m about 400 s in, at ~3 m/s along +y: a
# 40 m sphere drifting across it there; and an ellipsoid parked on the approach axis at 70 m.
CROSSING = [Obstacle(id=1, semi_axes_m=(40.0, 40.0, 40.0), position_lvlh_m=(-395.0, -950.0, 0.0),
                     velocity_lvlh_mps=(0.2, 0.0, 0.0)),
            Obstacle(id=2, semi_axes_m=(3.0, 5.0, 3.0), position_lvlh_m=(0.0, 70.0, 0.0))]


@pytest.fixture(scope="module")
def params():
    p = fsw.GuidanceParams()
    p.obstacle_capacity = fsw.MAX_OBSTACLES
    return p


def test_without_obstacle_rows_case1_flies_through_the_crossing_obstacle():
    worst, docked, _, _ = fly(fsw.GuidanceParams(), 1, CROSSING, tell=False)
    assert docked and min(worst.values()) < 1.0, worst


def test_case1_docks_around_a_crossing_obstacle_with_clearance_of_at_least_one(params):
    worst, docked, dv, g = fly(params, 1, CROSSING)
    assert docked
    assert all(v >= 1.0 for v in worst.values()), worst
    assert g.held_obstacle_ids and g.obstacles_dropped == 0 and g.obstacles_rejected == 0
    print(f"case 1 with a crossing obstacle: dv {dv:.3f} m/s, min clearance {worst}")




def test_the_papers_3d_scenario_reaches_the_holding_distance_clear_of_both_moving_spheres():
    """Dong, Ghiglino et al.'s Table 1 scenario (rvd_pil/bench/obstacles_dong3d.py): without obstacle rows the
    path runs through both spheres; with them it stays out of both and still reaches 2.3 m."""
    from rvd_pil.bench import obstacles_dong3d as seed

    blind = seed.fly(seed.params(False, False), seed.OBSTACLES)
    assert blind["reached"] and min(blind["clearance"].values()) < 1.0
    seen = seed.fly(seed.params(False, True), seed.OBSTACLES)
    assert seen["reached"] and min(seen["clearance"].values()) >= 1.0, seen["clearance"]


def test_a_suddenly_appearing_obstacle_is_avoided_with_the_rotating_hyperplane():
    """A 40 m sphere appears 300 s in, ~900 m ahead on Case 1's rendezvous path: the rotating
    hyperplane (first facing the chaser, turning towards the target at 0.002 rad/s) keeps it clear.
    The direct linearization, started from a plan through the sphere's centre, does not here (its
    planes flip from stage to stage until the plan has left the centre): printed, not asserted."""
    sudden = [Obstacle(id=5, semi_axes_m=(40.0, 40.0, 40.0), position_lvlh_m=(-240.0, -300.0, 0.0),
                       appear_time_s=300.0)]
    blind_worst, _, _, _ = fly(fsw.GuidanceParams(), 1, sudden, tell=False)
    assert blind_worst[5] < 1.0
    figures = {}
    for method in (fsw.ObstacleMethod.RotatingHyperplane, fsw.ObstacleMethod.DirectLinearization):
        p = fsw.GuidanceParams()
        p.obstacle_capacity = fsw.MAX_OBSTACLES
        p.obstacle_method = method
        worst, docked, dv, _ = fly(p, 1, sudden)
        assert docked
        figures[method] = (worst[5], dv)
    assert figures[fsw.ObstacleMethod.RotatingHyperplane][0] >= 1.0, figures
    print(f"sudden obstacle: blind clearance {blind_worst[5]:.3f}; " +
          ", ".join(f"{m}: clearance {c:.3f}, dv {dv:.2f} m/s" for m, (c, dv) in figures.items()))
