"""Guidance settings of one run, in one place: the flight executable's command-line options, which
the native and QEMU runs pass to the executable and the in-process runs to flight_sw.FlightApp (the
same parser), so every path flies the same guidance.

Names follow the flight executable (flight_sw/app/main.cpp): per phase N (--horizon), Ts_s
(--period), lambda, los_half_angle_deg, u_max_mps (--set <phase>.<name>); solver, max_iter, tol,
barrier, deadline_fraction; and the scalar parameters that --set accepts (--list-params).
"""
from __future__ import annotations

from dataclasses import dataclass, field

PHASES = ("rendezvous", "approach", "docking")
PHASE_SCALARS = ("lambda", "los_half_angle_deg", "u_max_mps")  # besides N and Ts_s
GLOBAL_SCALARS = ("orbit_altitude_m", "keepout_radius_m", "approach_stop_m", "dock_tolerance_m", "v_max_mps",
                  "rendezvous_setpoint_offset_m", "approach_setpoint_offset_m", "docking_setpoint_offset_m",
                  "docking_stop_penalty", "rendezvous_switch_margin_m", "approach_switch_margin_m",
                  "keepout_rate_cap_factor", "port_body_x_m", "port_body_y_m", "port_body_z_m")
SOLVER_MODES = ("converged", "fixed_barrier")


def _default_phase_values() -> dict[str, tuple]:
    from rvd_pil import flight_sw

    p = flight_sw.GuidanceParams()
    return {"N": tuple(int(p.phase(ph).N) for ph in _phase_enums()),
            "Ts_s": tuple(float(p.phase(ph).Ts_s) for ph in _phase_enums())}


def _phase_enums():
    from rvd_pil import flight_sw

    return (flight_sw.Phase.Rendezvous, flight_sw.Phase.Approach, flight_sw.Phase.Docking)


@dataclass(frozen=True)
class GuidanceSettings:
    horizon: tuple[int, int, int]
    period_s: tuple[float, float, float]
    deadline_fraction: float = 0.5
    solver: str | None = None       # None: the flight software's default
    max_iter: int | None = None
    tol: float | None = None
    barrier: float | None = None
    # --set NAME=VALUE pairs, sorted by name (e.g. ("approach.lambda", 20.0), ("keepout_radius_m", 150.0))
    params: tuple[tuple[str, float], ...] = field(default_factory=tuple)

    @classmethod
    def from_table(cls, table: dict) -> "GuidanceSettings":
        """From a study's (validated) [guidance] table; N and Ts_s default to the flight software's."""
        defaults = _default_phase_values()
        horizon = tuple(int(table.get(ph, {}).get("N", defaults["N"][i])) for i, ph in enumerate(PHASES))
        period = tuple(float(table.get(ph, {}).get("Ts_s", defaults["Ts_s"][i])) for i, ph in enumerate(PHASES))
        params = {}
        for ph in PHASES:
            for name in PHASE_SCALARS:
                if name in table.get(ph, {}):
                    params[f"{ph}.{name}"] = float(table[ph][name])
        for name in GLOBAL_SCALARS:
            if name in table:
                params[name] = float(table[name])
        opt = lambda k, conv: conv(table[k]) if k in table else None  # noqa: E731
        return cls(horizon=horizon, period_s=period, deadline_fraction=float(table.get("deadline_fraction", 0.5)),
                   solver=opt("solver", str), max_iter=opt("max_iter", int), tol=opt("tol", float),
                   barrier=opt("barrier", float), params=tuple(sorted(params.items())))

    def to_dict(self) -> dict:
        return {"horizon": list(self.horizon), "period_s": list(self.period_s),
                "deadline_fraction": self.deadline_fraction, "solver": self.solver, "max_iter": self.max_iter,
                "tol": self.tol, "barrier": self.barrier, "params": {k: v for k, v in self.params}}

    def flight_args(self) -> list[str]:
        """The flight executable's options for these settings (floats as repr: strtod reads them back exactly)."""
        args = ["--horizon", ",".join(str(n) for n in self.horizon),
                "--period", ",".join(repr(float(t)) for t in self.period_s),
                "--deadline-fraction", repr(float(self.deadline_fraction))]
        if self.solver is not None:
            args += ["--solver", self.solver]
        if self.max_iter is not None:
            args += ["--max-iter", str(self.max_iter)]
        if self.tol is not None:
            args += ["--tol", repr(float(self.tol))]
        if self.barrier is not None:
            args += ["--barrier", repr(float(self.barrier))]
        for name, value in self.params:
            args += ["--set", f"{name}={float(value)!r}"]
        return args
