"""Obstacles: ellipsoidal keep-out zones around debris or other spacecraft, in the target's LVLH frame.

An obstacle is the ellipsoid {r : (r - r_obs)' S (r - r_obs) <= 1} with S = R diag(a^-2, b^-2, c^-2) R',
R the rotation LVLH <- obstacle body (a constant attitude; `q_lvlh_body`, w first), semi-axes a, b, c
[m] along body x, y, z (Jewison, Erwin and Saenz-Otero's ellipsoidal keep-out zone, as used by
Dong, Ghiglino and others' "fast MPC with moving obstacle avoidance"). The clearance of a chaser
position r is (r - r_obs)' S (r - r_obs): >= 1 outside, < 1 inside.

Motion of its centre, from its state at scenario time 0 (`position_lvlh_m`, `velocity_lvlh_mps`):
- "constant_velocity": r_obs(t) = r0 + v0 t, the model of the fast-MPC paper above;
- "cw": the natural (unforced) Clohessy-Wiltshire motion of a body near the target.

When the flight software is told about it:
- from `appear_time_s` on (an obstacle that appears suddenly, e.g. debris released or first
  detected then; before that it does not exist for the truth either);
- and, when `sensing_range_m` > 0, only once the chaser has come within that range of its
  centre (it stays known from then on).

Scenario TOML: one `[[obstacles]]` table per obstacle with the keys of `Obstacle`; see
rvd_pil/host_sim/scenarios/case1_crossing_obstacle.toml.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .cw import cw_stm
from .frames import quaternion_to_matrix

MOTIONS = ("constant_velocity", "cw")


class ObstacleError(ValueError):
    """An obstacle entry is invalid; the message names where."""


@dataclass(frozen=True)
class Obstacle:
    id: int = 0
    semi_axes_m: tuple[float, float, float] = (1.0, 1.0, 1.0)      # a, b, c along body x, y, z
    q_lvlh_body: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  # LVLH <- body, (w, x, y, z)
    position_lvlh_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # centre at t = 0
    velocity_lvlh_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    motion: str = "constant_velocity"                              # or "cw"
    appear_time_s: float = 0.0                                     # exists (and may be sensed) from then on
    sensing_range_m: float = 0.0                                   # > 0: sensed only within this range

    def rotation(self) -> np.ndarray:
        q = np.asarray(self.q_lvlh_body, float)
        return quaternion_to_matrix(q / np.linalg.norm(q))

    def shape_matrix(self) -> np.ndarray:
        """S in LVLH (3x3, symmetric positive definite)."""
        r = self.rotation()
        return r @ np.diag(1.0 / np.asarray(self.semi_axes_m, float) ** 2) @ r.T

    def state(self, t_s: float, mean_motion_rad_s: float) -> np.ndarray:
        """[r_obs; v_obs] of its centre at scenario time t_s (LVLH, m and m/s)."""
        x0 = np.concatenate((np.asarray(self.position_lvlh_m, float), np.asarray(self.velocity_lvlh_mps, float)))
        if self.motion == "cw":
            return cw_stm(mean_motion_rad_s, t_s) @ x0
        return np.concatenate((x0[0:3] + x0[3:6] * float(t_s), x0[3:6]))

    def exists(self, t_s: float) -> bool:
        return float(t_s) >= self.appear_time_s

    def clearance(self, r_lvlh_m, t_s: float, mean_motion_rad_s: float) -> float:
        """(r - r_obs(t))' S (r - r_obs(t)): < 1 inside the keep-out zone."""
        d = np.asarray(r_lvlh_m, float) - self.state(t_s, mean_motion_rad_s)[0:3]
        return float(d @ self.shape_matrix() @ d)


class ObstacleField:
    """The scenario's obstacles with the sensing logic: `sensed(t, r_chaser)` lists those the
    flight software is told about (latching once within the sensing range)."""

    def __init__(self, obstacles, mean_motion_rad_s: float):
        self.obstacles = tuple(obstacles)
        self.n = float(mean_motion_rad_s)
        self._first_seen: dict[int, float] = {}
        self._shape = {o.id: o.shape_matrix() for o in self.obstacles}

    def __len__(self) -> int:
        return len(self.obstacles)

    def shape(self, obstacle: Obstacle) -> np.ndarray:
        return self._shape[obstacle.id]

    def clearance(self, obstacle: Obstacle, r_lvlh_m, t_s: float) -> float:
        d = np.asarray(r_lvlh_m, float) - obstacle.state(t_s, self.n)[0:3]
        return float(d @ self._shape[obstacle.id] @ d)

    def sensed(self, t_s: float, r_chaser_lvlh_m) -> list[tuple[Obstacle, np.ndarray, float]]:
        """(obstacle, [r; v] now, time first seen) of every obstacle known to the chaser at t_s."""
        out = []
        for o in self.obstacles:
            if not o.exists(t_s):
                continue
            x = o.state(t_s, self.n)
            if o.id not in self._first_seen:
                if o.sensing_range_m > 0.0 and np.linalg.norm(x[0:3] - np.asarray(r_chaser_lvlh_m, float)) > o.sensing_range_m:
                    continue
                self._first_seen[o.id] = float(t_s)
            out.append((o, x, self._first_seen[o.id]))
        return out


def _vector(value, size: int, where: str) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != size:
        raise ObstacleError(f"{where}: expected a list of {size} numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            raise ObstacleError(f"{where}: expected finite numbers, got {value!r}")
        out.append(float(v))
    return tuple(out)


def _scalar(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise ObstacleError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def parse(entries: Any, source: str) -> tuple[Obstacle, ...]:
    """The `[[obstacles]]` array of a scenario: checked field by field (one-line errors)."""
    if not isinstance(entries, list):
        raise ObstacleError(f"{source} obstacles: must be an array of tables ([[obstacles]])")
    fields = {f.name: f for f in dataclasses.fields(Obstacle)}
    out = []
    for i, table in enumerate(entries):
        where = f"{source} [[obstacles]] #{i + 1}"
        if not isinstance(table, dict):
            raise ObstacleError(f"{where}: must be a table")
        unknown = set(table) - set(fields)
        if unknown:
            raise ObstacleError(f"{where}: unknown key(s) {sorted(unknown)}; expected some of {sorted(fields)}")
        values: dict[str, Any] = {}
        for key, value in table.items():
            default = getattr(Obstacle(), key)
            if key == "id":
                if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**32:
                    raise ObstacleError(f"{where} id: expected an integer 0..2^32-1, got {value!r}")
                values[key] = value
            elif key == "motion":
                if value not in MOTIONS:
                    raise ObstacleError(f"{where} motion: expected one of {list(MOTIONS)}, got {value!r}")
                values[key] = value
            elif isinstance(default, tuple):
                values[key] = _vector(value, len(default), f"{where} {key}")
            else:
                values[key] = _scalar(value, f"{where} {key}")
        values.setdefault("id", i + 1)
        out.append(Obstacle(**values))
    return tuple(out)


def validate(obstacles, *, chaser_position_lvlh_m, target_radius_m: float, mean_motion_rad_s: float,
             source: str) -> None:
    """Physically meaningless or impossible obstacles: one-line errors naming the obstacle.

    Overlapping the target: the target's collision sphere (radius `target_radius_m` about its centre
    of mass) reaches into the keep-out zone as placed at its appearance, i.e. the origin lies within
    the ellipsoid with every semi-axis grown by that radius (which contains their Minkowski sum).
    Containing the chaser's start: clearance < 1 at t = 0 for an obstacle that exists then."""
    seen = set()
    for o in obstacles:
        where = f"{source} obstacle id {o.id}"
        if o.id in seen:
            raise ObstacleError(f"{where}: id used twice")
        seen.add(o.id)
        if not all(a > 0.0 for a in o.semi_axes_m):
            raise ObstacleError(f"{where}: semi_axes_m must be > 0, got {list(o.semi_axes_m)}")
        qn = math.sqrt(sum(v * v for v in o.q_lvlh_body))
        if not 0.5 < qn < 2.0:
            raise ObstacleError(f"{where}: q_lvlh_body must be a unit quaternion (w, x, y, z), got {list(o.q_lvlh_body)}")
        if o.appear_time_s < 0.0:
            raise ObstacleError(f"{where}: appear_time_s must be >= 0, got {o.appear_time_s}")
        if o.sensing_range_m < 0.0:
            raise ObstacleError(f"{where}: sensing_range_m must be >= 0 (0: always sensed), got {o.sensing_range_m}")
        x = o.state(o.appear_time_s, mean_motion_rad_s)
        r = o.rotation()
        grown = r @ np.diag(1.0 / (np.asarray(o.semi_axes_m) + target_radius_m) ** 2) @ r.T
        if float(x[0:3] @ grown @ x[0:3]) < 1.0:
            raise ObstacleError(f"{where}: overlaps the target (its keep-out zone at t = {o.appear_time_s:g} s "
                                f"reaches within {target_radius_m:g} m of the target's centre of mass)")
        if o.exists(0.0):
            c = o.clearance(chaser_position_lvlh_m, 0.0, mean_motion_rad_s)
            if c < 1.0:
                raise ObstacleError(f"{where}: contains the chaser's start (clearance {c:.4g} < 1 at t = 0)")
