"""Safety monitor: judges a run on the truth, not on what the flight software believes.

Every limit the three-phase guidance is meant to hold is evaluated on the true relative state at
every sample of the truth path (rvd_pil.host_sim.simulator.StepResult.path_*: at most `path_sample_s` apart
and at every burn start and end, so a violation in the middle of a finite burn is seen), and on the
commanded and realised delta-v of every period:

    limit               applies                           exceeded when (truth)
    collision           always                            |rho| < collision_radius_m
    keepout             always                            |rho| < r1 and outside the approach corridor
                                                          (magnitude: min(r1 - |rho|, corridor excursion))
    approach_corridor   approach and docking phases       outside the approach corridor
    overshoot           approach phase                    axial distance a.rho < r2
    docking_cone        docking phase                     outside the docking cone (apex at the port)
    docking_speed       docking phase                     |v|_inf > v_max
    thrust_command      always                            commanded |dv|_inf > u_max of the phase
    thrust_realised     always                            realised |dv|_inf > u_max (1 + 3 sigma_w)
    contact_speed       at the docked declaration         |v - v_port| > contact_speed_max_mps
    contact_lateral     at the docked declaration         offset from the docking axis > contact_lateral_max_m
    obstacle            while the obstacle exists         clearance (r - r_obs)' S (r - r_obs) < 1, per obstacle
                                                          (magnitude: 1 - clearance; rvd_pil.host_sim.obstacles)

The corridors are the guidance's four-sided pyramids (faces h_j = e_j cos(a) - x_body sin(a),
e_j in {+-y_body, +-z_body}, unit rows, so max_j h_j.p is the distance outside a face in metres):
the approach corridor of half-angle 15 deg with its apex at the target's centre of mass, the
docking cone of 8 deg with its apex at the port. The phase of a period is the one its command
belongs to (the constraint set the guidance promised for that period); the state is always truth.

An exceedance is an episode (from the first sample over the limit to the first sample back under
it) with its worst magnitude, where and when it happened and how long it lasted. Each episode is
an event in the run record: `safety_violation` when its worst magnitude is beyond the limit's
stated tolerance, `safety_excursion` when it stays within it (e.g. a docking-cone crossing of a
millimetre, the size a pulse dropped below the minimum impulse bit leaves uncorrected), and
`safety_initial_violation` when the limit was already exceeded at the run's first sample (a random
start inside the keep-out sphere): the scenario's, not the guidance's. The run's verdict is "safe"
when there is no violation, "started_unsafe" when the only ones are initial, else "unsafe". `SafetyMonitor.summary()` goes into the record's
metadata under "safety": the verdict, the limits with their sources, and per limit the number of
violations and excursions and the worst one.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .frames import quaternion_to_matrix

PHASES = {1: "rendezvous", 2: "approach", 3: "docking", 4: "docked"}
MAX_EPISODES = 200  # violations listed one by one in the summary (all are counted and in events.csv)


@dataclass(frozen=True)
class SafetyLimits:
    """The limits a run is judged against (the scenario's [safety] table). SI units, LVLH frame.
    Defaults are the guidance's own (flight_sw/guidance/README.md) unless said otherwise."""

    keepout_radius_m: float = 200.0           # r1
    approach_half_angle_deg: float = 15.0     # approach corridor, apex at the target CoM
    overshoot_distance_m: float = 30.0        # r2: the approach phase stays beyond a.rho >= r2
    docking_half_angle_deg: float = 8.0       # docking cone, apex at the port
    docking_speed_max_mps: float = 0.1        # v_max, |v|_inf in the docking phase
    collision_radius_m: float = 0.3           # a sphere around the target body (6U: 0.37 m diagonal / 2 + margin)
    contact_speed_max_mps: float = 0.1        # relative speed to the port at the docked declaration
    contact_lateral_max_m: float = 0.07       # offset from the docking axis at contact
    u_max_mps: tuple[float, float, float] = (0.1786, 0.1786, 0.0357)  # |dv|_inf per period, per phase
    thrust_error_sigmas: float = 3.0          # realised dv may exceed u_max by this many sigma_w
    # Tolerances: an exceedance no larger than these is an excursion, not a violation.
    geometry_tolerance_m: float = 0.001       # keep-out, corridor, overshoot: the QP solutions' own accuracy
    docking_cone_tolerance_m: float = 0.02
    docking_speed_tolerance_mps: float = 0.001
    thrust_command_tolerance_mps: float = 1e-9


LIMIT_SOURCES = {
    "collision": "target body: half the 6U's 0.37 m diagonal plus margin (collision_radius_m)",
    "keepout": "keep-out sphere r1 outside the approach corridor: dissertation sec. 3.1.3, eqs. 3.5-3.6; "
               "tolerance (also corridor, overshoot): 1 mm, the accuracy of the QP solutions at the planes",
    "obstacle": "ellipsoidal keep-out zone of each obstacle, (r - r_obs)' S (r - r_obs) >= 1 (Dong et al., fast MPC "
                "with moving obstacle avoidance, eq. 6); magnitude 1 - clearance, no tolerance",
    "approach_corridor": "line-of-sight corridor of the approach phase, 4-sided pyramid: dissertation sec. 3.2, eq. 3.3",
    "overshoot": "overshoot plane r2 of the approach phase (a hard constraint): dissertation eq. 3.9",
    "docking_cone": "docking line-of-sight cone, apex at the port (hard): dissertation eq. 3.12; "
                    "tolerance: measured crossings of a pulse below the minimum impulse bit",
    "docking_speed": "|v|_inf <= v_max in docking (hard): dissertation eq. 3.13; tolerance: the minimum "
                     "impulse bit's delta-v (0.36 mm/s) rounded up",
    "thrust_command": "|dv|_inf <= u_max per period: dissertation Table 3.1",
    "thrust_realised": "u_max (1 + k sigma_w) with sigma_w the Gauss-Markov thrust error's steady-state "
                       "standard deviation (dissertation Table 5.1)",
    "contact_speed": "relative speed to the port at contact <= v_max (the docking phase's own bound)",
    "contact_lateral": "offset from the docking axis at contact <= the docking cone's half-width at "
                       "r3 = 0.5 m (0.5 tan 8 deg = 7 cm)",
}
UNITS = {"collision": "m", "keepout": "m", "approach_corridor": "m", "overshoot": "m", "docking_cone": "m",
         "docking_speed": "m/s", "thrust_command": "m/s", "thrust_realised": "m/s", "contact_speed": "m/s",
         "contact_lateral": "m", "obstacle": "1"}


def pyramid_rows(q_lvlh_body, half_angle_rad: float) -> np.ndarray:
    """4 x 3 unit rows of the four-sided pyramid around body +x, in LVLH: p inside when rows @ p <= 0."""
    r = quaternion_to_matrix(q_lvlh_body)
    x, y, z = r[:, 0], r[:, 1], r[:, 2]
    c, s = math.cos(half_angle_rad), math.sin(half_angle_rad)
    return np.array([y * c - x * s, -y * c - x * s, z * c - x * s, -z * c - x * s])


@dataclass
class _Episode:
    limit: str
    phase: str
    start_step: int
    start_t_s: float
    worst: float = 0.0
    worst_t_s: float = 0.0
    worst_step: int = 0
    worst_state: tuple = ()
    end_step: int = 0
    end_t_s: float = 0.0
    initial: bool = False  # already exceeded at the run's first sample
    label: str = ""        # which one, for limits that exist several times (e.g. "obstacle id 3")


@dataclass
class _LimitStats:
    violations: int = 0
    excursions: int = 0
    initial: int = 0
    worst: float = 0.0
    worst_step: int | None = None
    worst_t_s: float | None = None
    worst_phase: str | None = None
    duration_s: float = 0.0


class SafetyMonitor:
    """Feed it every period (`period(...)`) and the docked declaration (`contact(...)`), then
    `finish()`; `events` lists the episodes, `summary()` the verdict and per-limit figures.

    `attitude(t)` returns the target's rvd_pil.host_sim.attitude.TargetState at time t (the truth's)."""

    def __init__(self, limits: SafetyLimits, attitude, sigma_w_percent: float = 0.0,
                 on_event=None, obstacles=None):
        """`obstacles`: a rvd_pil.host_sim.obstacles.ObstacleField (or None): its clearance is judged too."""
        self.limits = limits
        self.obstacles = obstacles if obstacles is not None and len(obstacles) else None
        self.attitude = attitude
        self.sigma_w = float(sigma_w_percent) / 100.0
        self.on_event = on_event  # called with (kind, episode) when an episode closes
        self.events: list[_Episode] = []
        self._kinds: list[str] = []
        self._open: dict[str, _Episode] = {}
        # The obstacle limit is judged (and listed) only in runs that have obstacles.
        self._stats = {name: _LimitStats() for name in UNITS if name != "obstacle" or self.obstacles is not None}
        self._a_app = math.radians(limits.approach_half_angle_deg)
        self._a_dock = math.radians(limits.docking_half_angle_deg)
        # Figures a reviewer asks for even when nothing was violated.
        self.figures = {
            "min_range_outside_corridor_m": math.inf,   # closest approach while outside the corridor
            "max_corridor_excursion_inside_r1_m": -math.inf,
            "min_axial_distance_approach_m": math.inf,
            "max_docking_cone_excursion_m": -math.inf,  # max over docking of max_j h_j (rho - port)
            "max_speed_inf_docking_mps": 0.0,
            "min_range_com_m": math.inf,
            "max_dv_cmd_inf_mps": [0.0, 0.0, 0.0],
            "max_dv_realised_inf_mps": [0.0, 0.0, 0.0],
            "contact": None,
            "samples": 0,
        }
        if self.obstacles is not None:
            # Per obstacle id: min clearance over the path, and when and where (truth).
            self.figures["obstacles"] = {str(o.id): {"min_clearance": math.inf, "t_s": None, "step": None,
                                                     "min_distance_m": math.inf}
                                         for o in self.obstacles.obstacles}

    # -- evaluation --------------------------------------------------------------------------
    def _exceed(self, limit: str, amount: float, phase: str, step: int, t_s: float, x, key: str | None = None) -> None:
        """Record that `limit` is exceeded by `amount` (> 0) at this sample, or ended (<= 0). `key`
        tells apart episodes of one limit that run at once (one per obstacle)."""
        key = key or limit
        ep = self._open.get(key)
        if amount > 0.0:
            if ep is None:
                ep = self._open[key] = _Episode(limit, phase, step, t_s, initial=self.figures["samples"] <= 1,
                                                label=key.replace(":", " id ") if key != limit else "")
            if amount > ep.worst:
                ep.worst, ep.worst_t_s, ep.worst_step = amount, t_s, step
                ep.worst_state = tuple(float(v) for v in x)
            ep.end_step, ep.end_t_s = step, t_s
        elif ep is not None:
            ep.end_step, ep.end_t_s = step, t_s
            self._close(key)

    def _tolerance(self, limit: str) -> float:
        lim = self.limits
        return {"docking_cone": lim.docking_cone_tolerance_m, "docking_speed": lim.docking_speed_tolerance_mps,
                "thrust_command": lim.thrust_command_tolerance_mps, "keepout": lim.geometry_tolerance_m,
                "approach_corridor": lim.geometry_tolerance_m, "overshoot": lim.geometry_tolerance_m}.get(limit, 0.0)

    def _close(self, key: str) -> None:
        ep = self._open.pop(key)
        limit = ep.limit
        st = self._stats[limit]
        if ep.worst <= self._tolerance(limit):
            kind = "safety_excursion"
            st.excursions += 1
        elif ep.initial:
            kind = "safety_initial_violation"
            st.initial += 1
        else:
            kind = "safety_violation"
            st.violations += 1
        st.duration_s += ep.end_t_s - ep.start_t_s
        if ep.worst > st.worst:
            st.worst, st.worst_step, st.worst_t_s, st.worst_phase = ep.worst, ep.worst_step, ep.worst_t_s, ep.phase
        self.events.append(ep)
        self._kinds.append(kind)
        if self.on_event is not None:
            self.on_event(kind, ep)

    def sample(self, phase_code: int, step: int, t_s: float, x) -> dict:
        """Evaluate one true state x = [rho; v] (LVLH) at time t_s during a period of `phase_code`.
        Returns the margins of this sample (negative = inside the limit)."""
        lim = self.limits
        x = np.asarray(x, float)
        rho, v = x[0:3], x[3:6]
        phase = PHASES.get(int(phase_code), "rendezvous")
        target = self.attitude(t_s)
        r = float(np.linalg.norm(rho))
        corridor = float(np.max(pyramid_rows(target.q_lvlh_body, self._a_app) @ rho))
        f = self.figures
        f["samples"] += 1
        f["min_range_com_m"] = min(f["min_range_com_m"], r)
        if corridor > 0.0:
            f["min_range_outside_corridor_m"] = min(f["min_range_outside_corridor_m"], r)
        if r < lim.keepout_radius_m:
            f["max_corridor_excursion_inside_r1_m"] = max(f["max_corridor_excursion_inside_r1_m"], corridor)
        self._exceed("collision", lim.collision_radius_m - r, phase, step, t_s, x)
        # Inside the sphere and outside the corridor: the distance to the safe set (out of the sphere,
        # or into the corridor), the smaller of the depth inside the sphere and the corridor excursion.
        self._exceed("keepout", min(lim.keepout_radius_m - r, corridor) if corridor > 0.0 else 0.0, phase, step,
                     t_s, x)
        in_app, in_dock = phase == "approach", phase in ("docking", "docked")
        self._exceed("approach_corridor", corridor if (in_app or in_dock) else 0.0, phase, step, t_s, x)
        axial = float(target.docking_axis_lvlh @ rho)
        if in_app:
            f["min_axial_distance_approach_m"] = min(f["min_axial_distance_approach_m"], axial)
        self._exceed("overshoot", lim.overshoot_distance_m - axial if in_app else 0.0, phase, step, t_s, x)
        cone = float(np.max(pyramid_rows(target.q_lvlh_body, self._a_dock) @ (rho - target.port_position_lvlh_m)))
        speed = float(np.max(np.abs(v)))
        if in_dock:
            f["max_docking_cone_excursion_m"] = max(f["max_docking_cone_excursion_m"], cone)
            f["max_speed_inf_docking_mps"] = max(f["max_speed_inf_docking_mps"], speed)
        self._exceed("docking_cone", cone if in_dock else 0.0, phase, step, t_s, x)
        self._exceed("docking_speed", speed - lim.docking_speed_max_mps if in_dock else 0.0, phase, step, t_s, x)
        margins = {"corridor_m": corridor, "axial_m": axial, "dock_cone_m": cone, "speed_inf_mps": speed, "range_m": r}
        if self.obstacles is not None:
            margins["obstacle_clearance"] = self._sample_obstacles(phase, step, t_s, x)
        return margins

    def _sample_obstacles(self, phase: str, step: int, t_s: float, x) -> float:
        """Clearance of every obstacle that exists at t_s; returns the smallest (inf when none)."""
        worst = math.inf
        per = self.figures["obstacles"]
        for o in self.obstacles.obstacles:
            if not o.exists(t_s):
                continue
            d = x[0:3] - o.state(t_s, self.obstacles.n)[0:3]
            c = float(d @ self.obstacles.shape(o) @ d)
            f = per[str(o.id)]
            if c < f["min_clearance"]:
                f.update(min_clearance=c, t_s=float(t_s), step=int(step))
            f["min_distance_m"] = min(f["min_distance_m"], float(np.linalg.norm(d)))
            worst = min(worst, c)
            self._exceed("obstacle", 1.0 - c, phase, step, t_s, x, key=f"obstacle:{o.id}")
        return worst

    def period(self, phase_code: int, step: int, path_t_s, path_lvlh, dv_cmd_lvlh_mps=None,
               dv_realised_lvlh_mps=None) -> dict:
        """One control period: the truth path samples and the period's delta-v. Returns the worst
        margins over the period (for the run record's per-step columns)."""
        worst = {"corridor_m": -math.inf, "axial_m": math.inf, "dock_cone_m": -math.inf, "speed_inf_mps": 0.0,
                 "range_m": math.inf}
        if self.obstacles is not None:
            worst["obstacle_clearance"] = math.inf
        for t, x in zip(path_t_s, path_lvlh):
            m = self.sample(phase_code, step, float(t), x)
            if self.obstacles is not None:
                worst["obstacle_clearance"] = min(worst["obstacle_clearance"], m["obstacle_clearance"])
            worst["corridor_m"] = max(worst["corridor_m"], m["corridor_m"])
            worst["axial_m"] = min(worst["axial_m"], m["axial_m"])
            worst["dock_cone_m"] = max(worst["dock_cone_m"], m["dock_cone_m"])
            worst["speed_inf_mps"] = max(worst["speed_inf_mps"], m["speed_inf_mps"])
            worst["range_m"] = min(worst["range_m"], m["range_m"])
        t_end = float(path_t_s[-1]) if len(path_t_s) else 0.0
        phase = PHASES.get(int(phase_code), "rendezvous")
        index = {"rendezvous": 0, "approach": 1}.get(phase, 2)
        u_max = float(self.limits.u_max_mps[index])
        x_end = path_lvlh[-1] if len(path_lvlh) else np.zeros(6)
        for limit, dv, allowed, key in (
                ("thrust_command", dv_cmd_lvlh_mps, u_max, "max_dv_cmd_inf_mps"),
                ("thrust_realised", dv_realised_lvlh_mps, u_max * (1.0 + self.limits.thrust_error_sigmas * self.sigma_w),
                 "max_dv_realised_inf_mps")):
            if dv is None:
                continue
            mag = float(np.max(np.abs(np.asarray(dv, float))))
            self.figures[key][index] = max(self.figures[key][index], mag)
            # A per-period quantity: each exceeding period is its own episode.
            self._exceed(limit, mag - allowed, phase, step, t_end, x_end)
            if limit in self._open:
                self._close(limit)
        return worst

    def contact(self, step: int, t_s: float, x) -> None:
        """The flight software declared docked at t_s: check the contact conditions on the truth."""
        lim = self.limits
        x = np.asarray(x, float)
        target = self.attitude(t_s)
        rel = x[0:3] - target.port_position_lvlh_m
        axis = target.docking_axis_lvlh
        lateral = float(np.linalg.norm(rel - (axis @ rel) * axis))
        speed = float(np.linalg.norm(x[3:6] - target.port_velocity_lvlh_mps))
        self.figures["contact"] = {"step": int(step), "t_s": float(t_s), "distance_to_port_m": float(np.linalg.norm(rel)),
                                   "axial_offset_m": float(axis @ rel), "lateral_offset_m": lateral,
                                   "relative_speed_mps": speed}
        for limit, amount in (("contact_speed", speed - lim.contact_speed_max_mps),
                              ("contact_lateral", lateral - lim.contact_lateral_max_m)):
            self._exceed(limit, amount, "docked", step, t_s, x)
            if limit in self._open:
                self._close(limit)

    def finish(self) -> None:
        """Close the episodes still open at the end of the run."""
        for limit in list(self._open):
            self._close(limit)

    # -- results -----------------------------------------------------------------------------
    @property
    def violations(self) -> int:
        return sum(s.violations for s in self._stats.values())

    def verdict(self) -> str:
        if self.violations:
            return "unsafe"
        return "started_unsafe" if any(s.initial for s in self._stats.values()) else "safe"

    def summary(self) -> dict:
        """JSON-ready: verdict, limits with sources and tolerances, per-limit statistics, figures."""
        lim = dataclasses.asdict(self.limits)
        per_limit = {}
        for name, st in self._stats.items():
            per_limit[name] = {"violations": st.violations, "excursions": st.excursions, "initial": st.initial,
                               "worst": st.worst,
                               "unit": UNITS[name], "worst_step": st.worst_step, "worst_t_s": st.worst_t_s,
                               "worst_phase": st.worst_phase, "duration_s": st.duration_s,
                               "tolerance": self._tolerance(name)}
        figures = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                   for k, v in self.figures.items()}
        if "obstacles" in figures:
            figures["obstacles"] = {i: {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                                        for k, v in f.items()} for i, f in figures["obstacles"].items()}
        episodes = [{"limit": ep.limit, **({"which": ep.label} if ep.label else {}), "kind": kind, "phase": ep.phase, "worst": ep.worst, "unit": UNITS[ep.limit],
                     "worst_step": ep.worst_step, "worst_t_s": ep.worst_t_s, "start_t_s": ep.start_t_s,
                     "end_t_s": ep.end_t_s}
                    for ep, kind in zip(self.events, self._kinds) if kind != "safety_excursion"][:MAX_EPISODES]
        return {"verdict": self.verdict(), "violations": self.violations, "episodes": episodes,
                "excursions": sum(s.excursions for s in self._stats.values()),
                "initial_violations": sum(s.initial for s in self._stats.values()),
                "limits": {k: (list(v) if isinstance(v, tuple) else v) for k, v in lim.items()},
                "sigma_w_percent": 100.0 * self.sigma_w, "sources": {k: v for k, v in LIMIT_SOURCES.items() if k in self._stats},
                "per_limit": per_limit, "figures": figures}


def describe(kind: str, ep: _Episode, unit: str) -> str:
    """Event detail text of an episode."""
    return (f"{ep.label or ep.limit}{' (already at the start)' if ep.initial else ''}: worst {ep.worst:.6g} {unit} at t = {ep.worst_t_s:.2f} s (step {ep.worst_step}, "
            f"{ep.phase}); from step {ep.start_step} t = {ep.start_t_s:.2f} s to step {ep.end_step} "
            f"t = {ep.end_t_s:.2f} s")
