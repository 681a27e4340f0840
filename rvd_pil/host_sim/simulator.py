"""The truth simulator the link server drives one control period at a time.

    sim = Simulator(load("case1_vbar"), truth="nonlinear", seed=7)
    nav = sim.measure()                                   # noisy LVLH state + target attitude
    result = sim.apply_command(pulse_widths_s, period_s=30.0, delay_s=0.012)

Truth models (`truth=`):
- "cw": the Clohessy-Wiltshire equations, propagated in closed form (rvd_pil.host_sim.cw). With
  impulsive=True, no noise and zero delay one period is exactly x+ = Phi(Ts) (x + [0; dv]),
  dv = sum_i pulse_i * F / m * axis_i: the flight software's own prediction model.
- "nonlinear": target and chaser in ECI under two-body + J2 (+ J3, J4 optional) + drag
  (rvd_pil.host_sim.dynamics), reported in the target's LVLH frame.
- "planar": an air-bearing table (a scenario with dynamics = "planar"; Dong, Ghiglino et al.'s eq. 4):
  the chaser translates under its thrusters alone (CW with n = 0, in the frame that moves with the
  target's centre of mass) and turns about z under the torque it is commanded, I theta'' = tau, held
  from the burn start to the period's end. It is the only truth of a planar scenario: asked for "cw"
  or "nonlinear" there (the exact reference, the full model), a Simulator flies "planar", which is
  both.

Time line of one period [t, t + Ts]: coast for the control delay, then all pulses start together;
each thruster pushes (1 + w_i/100) F along its LVLH axis for its pulse width (finite burn), or the
whole impulse is applied at the burn start (impulsive=True). Pulses below the minimum impulse bit
are dropped; a pulse that would outlast the period is cut at the period end (the next command
takes over) and reported as truncated. The thrust error w_i is sampled at the burn start and held
for the pulse (pulses last seconds, the error's correlation time is an hour).

Random streams: the seed feeds one SeedSequence, split into independent streams for the thrust
error and the sensor noise, so switching one off does not change the other's draws. One
measurement per step: calling measure() again before the next command returns the same one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import constants as k
from .attitude import TargetAttitude, TargetState
from .cw import cw_forced_response, cw_stm
from .dynamics import ForceModel, PairPropagator, Tolerances
from .frames import eci_to_lvlh, lvlh_basis, lvlh_to_eci, quaternion_about_z
from .noise import ThrustAmplitudeError
from .scenario import Scenario, load
from .thrusters import drop_below_mib, lvlh_delta_v, validate_pulses

TRUTH_MODELS = ("cw", "nonlinear", "planar")


@dataclass(frozen=True)
class Measurement:
    """What the navigation sensors report at step `step` (time t_s [s])."""

    step: int
    t_s: float
    position_lvlh_m: np.ndarray
    velocity_lvlh_mps: np.ndarray
    q_lvlh_body: np.ndarray       # target attitude, (w, x, y, z), LVLH <- body
    omega_body_rad_s: np.ndarray  # target body rate relative to LVLH, body axes
    # The chaser's own attitude (w, x, y, z), LVLH <- chaser body, and body rate: planar truth only.
    chaser_q_lvlh: np.ndarray | None = None
    chaser_omega_rad_s: np.ndarray | None = None

    @property
    def state(self) -> np.ndarray:
        """[position; velocity] (6,) in LVLH."""
        return np.concatenate((self.position_lvlh_m, self.velocity_lvlh_mps))


@dataclass(frozen=True)
class StepResult:
    """What happened during one control period (arrays are per thruster in command order
    +x, -x, +y, -y, +z, -z unless stated)."""

    step: int
    t_start_s: float
    t_end_s: float
    period_s: float
    delay_s: float
    pulse_commanded_s: np.ndarray
    pulse_applied_s: np.ndarray     # after the MIB drop and the period-end cut
    dropped_mib: np.ndarray         # bool: commanded but shorter than the MIB
    truncated: np.ndarray           # bool: cut at the period end
    thrust_error_percent: np.ndarray  # w_i during the burn (0 without thrust noise)
    force_n: np.ndarray             # realised force (1 + w_i/100) F_nom
    dv_thruster_mps: np.ndarray     # realised delta-v magnitude per thruster, force * pulse / mass
    dv_lvlh_mps: np.ndarray         # (3,) net delta-v in LVLH, sum dv_i * axis_i
    truth_before: np.ndarray        # (6,) LVLH state at t_start_s
    truth_after: np.ndarray         # (6,) LVLH state at t_end_s
    # The true path through the period, for safety checks between steps: times [s] from t_start_s
    # to t_end_s (both included) at most `path_sample_s` apart and at every burn start and end, and
    # the LVLH states there (M x 6).
    path_t_s: np.ndarray = None
    path_lvlh: np.ndarray = None
    # Planar truth: the torque about z held from the burn start to the period end [N m], and the
    # chaser's [angle (rad), rate (rad/s)] at the start and the end of the period.
    torque_nm: float = 0.0
    attitude_before: np.ndarray = None
    attitude_after: np.ndarray = None


class Simulator:
    """Truth simulator for one run. All inputs and outputs in SI units and the target LVLH frame."""

    def __init__(self, scenario: Scenario | str, truth: str = "cw", seed: int = 0, thrust_noise: bool = True,
                 sensor_noise: bool = True, impulsive: bool = False, j2: bool = True, drag: bool = True,
                 j3_j4: bool = False, atmosphere_rotation: bool = True,
                 cw_mean_motion_rad_s: float | None = None, tolerances: Tolerances = Tolerances(),
                 path_sample_s: float = 1.0):
        """`j2`, `drag`, `j3_j4`, `atmosphere_rotation` apply to the nonlinear truth only (the CW
        truth has no perturbations). `cw_mean_motion_rad_s` overrides the CW mean motion (default:
        sqrt(mu/a^3) of the scenario orbit), e.g. to match a flight software built with other
        constants. `path_sample_s`: longest spacing of the truth path samples each StepResult carries
        (the integrator's dense output in the nonlinear truth, closed form in CW); sampling never
        changes the trajectory itself."""
        self.scenario = load(scenario) if isinstance(scenario, str) else scenario
        if not (math.isfinite(path_sample_s) and path_sample_s > 0.0):
            raise ValueError(f"path_sample_s must be a finite number > 0, got {path_sample_s!r}")
        self.path_sample_s = float(path_sample_s)
        if truth not in TRUTH_MODELS:
            raise ValueError(f"truth must be one of {TRUTH_MODELS}, got {truth!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
        s = self.scenario
        if truth == "planar" and not s.is_planar:
            raise ValueError(f"truth 'planar' needs a planar scenario (dynamics = \"planar\"); {s.name} is orbital")
        if s.is_planar:
            if cw_mean_motion_rad_s is not None:
                raise ValueError(f"{s.name} is planar: there is no mean motion to override")
            truth = "planar"  # its only truth: exact and full model at once
        self.truth = truth
        self.seed = int(seed)
        self.impulsive = bool(impulsive)
        self.thrust_noise = bool(thrust_noise)
        self.sensor_noise = bool(sensor_noise)
        nonlinear = truth == "nonlinear"
        self.force_model = ForceModel(j2=bool(j2) and nonlinear, j3_j4=bool(j3_j4) and nonlinear,
                                      drag=bool(drag) and nonlinear,
                                      atmosphere_rotation=bool(atmosphere_rotation))
        if truth == "planar":
            self._n = 0.0
        elif cw_mean_motion_rad_s is not None:
            if nonlinear:
                raise ValueError("cw_mean_motion_rad_s applies to truth='cw' only")
            n = float(cw_mean_motion_rad_s)
            if not (math.isfinite(n) and n > 0.0):
                raise ValueError(f"cw_mean_motion_rad_s must be a finite number > 0, got {cw_mean_motion_rad_s!r}")
            self._n = n
        else:
            self._n = s.orbit.mean_motion_rad_s

        # The children are keyed by their index: the attitude sensor's stream leaves the others as they were.
        thrust_seq, sensor_seq, attitude_seq = np.random.SeedSequence(self.seed).spawn(3)
        self._sensor_rng = np.random.default_rng(sensor_seq)
        self._attitude_rng = np.random.default_rng(attitude_seq)
        self._thrust_error = (ThrustAmplitudeError(s.thrust_error, 6, np.random.default_rng(thrust_seq))
                              if self.thrust_noise else None)
        self._attitude = TargetAttitude(math.radians(s.target.initial_angle_deg),
                                        math.radians(s.target.spin_rate_deg_s), s.target.docking_port_body_m)
        self._t = 0.0
        self._step = 0
        self._measurement: Measurement | None = None
        x0 = np.concatenate((np.asarray(s.chaser.position_lvlh_m, float), np.asarray(s.chaser.velocity_lvlh_mps, float)))
        if nonlinear:
            self._pair = PairPropagator(self.force_model, s.target.ballistic_m2_kg, s.chaser.ballistic_m2_kg, tolerances)
            r_t, v_t = _circular_orbit_state(s.orbit)
            r_c, v_c = lvlh_to_eci(r_t, v_t, x0, self._target_normal_accel(r_t, v_t))
            self._y = np.concatenate((r_t, v_t, r_c - r_t, v_c - v_t))
        else:
            self._x = x0
        # Planar truth: the chaser's [angle about z (rad), rate (rad/s)] on the table.
        self._chaser_att = (np.array([math.radians(s.planar.chaser_table[2]), math.radians(s.planar.chaser_table[5])])
                            if truth == "planar" else None)

    # ---- state ------------------------------------------------------------------------------
    @property
    def t_s(self) -> float:
        """Simulation time [s] since the scenario start."""
        return self._t

    @property
    def step(self) -> int:
        """Index of the next control step (number of commands applied so far)."""
        return self._step

    @property
    def mean_motion_rad_s(self) -> float:
        """Mean motion n [rad/s] of the target orbit (the CW model's n in CW mode)."""
        return self._n

    @property
    def options(self) -> dict:
        """The effective model options, for run records."""
        return {"truth": self.truth, "seed": self.seed, "thrust_noise": self.thrust_noise,
                "sensor_noise": self.sensor_noise, "impulsive": self.impulsive, "j2": self.force_model.j2,
                "j3_j4": self.force_model.j3_j4, "drag": self.force_model.drag,
                "atmosphere_rotation": self.force_model.atmosphere_rotation and self.force_model.drag,
                "mean_motion_rad_s": self._n}

    def truth_lvlh(self) -> np.ndarray:
        """True chaser state [rho (m); rho_dot (m/s)] in the target LVLH frame."""
        if self.truth in ("cw", "planar"):
            return self._x.copy()
        return self._lvlh_from_pair(self._y)

    def chaser_attitude(self) -> np.ndarray | None:
        """Planar truth: the chaser's true [angle about z (rad), rate (rad/s)]; None otherwise."""
        return None if self._chaser_att is None else self._chaser_att.copy()

    def eci_state(self) -> dict[str, np.ndarray]:
        """ECI position [m] and velocity [m/s] of target and chaser (nonlinear truth only)."""
        if self.truth != "nonlinear":
            raise RuntimeError("eci_state() exists only for truth='nonlinear' (CW truth has no ECI orbit)")
        y = self._y
        return {"target_position_m": y[0:3].copy(), "target_velocity_mps": y[3:6].copy(),
                "chaser_position_m": y[0:3] + y[6:9], "chaser_velocity_mps": y[3:6] + y[9:12]}

    def target_state(self, t_s: float | None = None) -> TargetState:
        """Target attitude (quaternion LVLH <- body, body rate) and docking port at t_s [s]
        (default: now). The attitude is a known function of time, so any t_s is allowed."""
        return self._attitude.state(self._t if t_s is None else t_s)

    def range_to_com_m(self) -> float:
        """True distance [m] from the chaser to the target's centre of mass."""
        return float(np.linalg.norm(self.truth_lvlh()[0:3]))

    def range_to_port_m(self) -> float:
        """True distance [m] from the chaser to the docking port."""
        return float(np.linalg.norm(self.truth_lvlh()[0:3] - self.target_state().port_position_lvlh_m))

    def thrust_error_percent(self) -> np.ndarray:
        """Current thrust amplitude error w_i [%] of each thruster (zeros without thrust noise)."""
        return self._thrust_error.w_percent if self._thrust_error is not None else np.zeros(6)

    # ---- sensors ----------------------------------------------------------------------------
    def measure(self) -> Measurement:
        """The navigation measurement for the current step: truth + N(0, sigma) per LVLH axis
        (eqs. 5.6-5.7), plus the target attitude and rate (noise-free)."""
        if self._measurement is None:
            x = self.truth_lvlh()
            if self.sensor_noise:
                sens = self.scenario.sensors
                sigma = np.array([sens.sigma_position_m] * 3 + [sens.sigma_velocity_mps] * 3)
                x = x + sigma * self._sensor_rng.standard_normal(6)
            att = self.target_state()
            chaser_q = chaser_w = None
            if self._chaser_att is not None:
                angle, rate = self._chaser_att
                if self.sensor_noise:
                    pl = self.scenario.planar
                    angle += math.radians(pl.sigma_angle_deg) * self._attitude_rng.standard_normal()
                    rate += math.radians(pl.sigma_rate_deg_s) * self._attitude_rng.standard_normal()
                chaser_q, chaser_w = _frozen(quaternion_about_z(angle)), _frozen(np.array([0.0, 0.0, rate]))
            self._measurement = Measurement(step=self._step, t_s=self._t, position_lvlh_m=_frozen(x[0:3]),
                                            velocity_lvlh_mps=_frozen(x[3:6]), q_lvlh_body=_frozen(att.q_lvlh_body),
                                            omega_body_rad_s=_frozen(att.omega_body_rad_s),
                                            chaser_q_lvlh=chaser_q, chaser_omega_rad_s=chaser_w)
        return self._measurement

    def record_meta(self) -> dict:
        """Metadata for a run record: scenario (every parameter), seed and model options."""
        return {"scenario_name": self.scenario.name, "scenario": self.scenario.to_dict(), "seed": self.seed,
                "options": self.options}

    # ---- actuation --------------------------------------------------------------------------
    def apply_command(self, pulse_widths_s, period_s: float, delay_s: float = 0.0, torque_nm: float = 0.0) -> StepResult:
        """Fire the thrusters and advance the truth by one control period.

        pulse_widths_s: 6 pulse widths [s] for +x, -x, +y, -y, +z, -z; period_s: control period
        Ts [s]; delay_s: control delay [s] from the period start to the burn start, 0 <= delay <= Ts;
        torque_nm: planar truth, the torque about z held from the burn start to the period end (within
        the scenario's torque_max_nm). Invalid input raises ValueError and leaves the simulator unchanged."""
        pulses = validate_pulses(pulse_widths_s)
        period = float(period_s)
        delay = float(delay_s)
        torque = float(torque_nm)
        if torque != 0.0 and self._chaser_att is None:
            raise ValueError("torque_nm applies to the planar truth only")
        if self._chaser_att is not None and not (math.isfinite(torque) and
                                                 abs(torque) <= self.scenario.planar.torque_max_nm * (1.0 + 1e-9)):
            raise ValueError(f"torque_nm must be finite and within +-{self.scenario.planar.torque_max_nm} N m, got {torque_nm!r}")
        if not (math.isfinite(period) and period > 0.0):
            raise ValueError(f"period_s must be a finite number > 0, got {period_s!r}")
        if not (math.isfinite(delay) and 0.0 <= delay <= period):
            raise ValueError(f"delay_s must be within [0, period_s = {period}], got {delay_s!r}")

        applied, dropped = drop_below_mib(pulses, self.scenario.thrusters.minimum_impulse_bit_s)
        burn_window = period - delay
        truncated = applied > burn_window
        applied = np.minimum(applied, burn_window)

        # Work on copies; commit only when everything succeeded.
        gm = self._thrust_error
        gm_state = None if gm is None else gm.state.copy()
        rng_state = None if gm is None else gm.rng.bit_generator.state
        try:
            if gm is not None:
                gm.advance(delay)
            w = gm.w_percent if gm is not None else np.zeros(6)
            force = self.scenario.thrusters.force_n * (1.0 + w / 100.0)
            mass = self.scenario.chaser.mass_kg
            dv_thruster = force * applied / mass
            dv_lvlh = lvlh_delta_v(dv_thruster)
            before = self.truth_lvlh()
            path = _PathSampler(self.path_sample_s)
            if self.truth in ("cw", "planar"):  # planar: the CW model with n = 0
                new_state = self._cw_period(self._x, period, delay, applied, force / mass, dv_lvlh, path)
                after = new_state
            else:
                new_state = self._nonlinear_period(self._y, period, delay, applied, force / mass, dv_lvlh, path)
                after = self._lvlh_from_pair(new_state)
            path_t, path_x = path.result(self._t, before, after)
            if gm is not None:
                gm.advance(period - delay)
        except Exception:
            if gm is not None:
                gm.state = gm_state
                gm.rng.bit_generator.state = rng_state
            raise

        att_before = att_after = None
        if self._chaser_att is not None:  # theta'' = tau / I from the burn start on
            att_before = self._chaser_att.copy()
            angle, rate = att_before
            burn = period - delay
            alpha = torque / self.scenario.planar.chaser_inertia_kgm2
            angle += rate * period + 0.5 * alpha * burn * burn
            rate += alpha * burn
            att_after = np.array([angle, rate])
            self._chaser_att = att_after
        if self.truth in ("cw", "planar"):
            self._x = new_state
        else:
            self._y = new_state
        result = StepResult(step=self._step, t_start_s=self._t, t_end_s=self._t + period, period_s=period,
                            delay_s=delay, pulse_commanded_s=pulses, pulse_applied_s=applied, dropped_mib=dropped,
                            truncated=truncated, thrust_error_percent=w, force_n=force,
                            dv_thruster_mps=dv_thruster, dv_lvlh_mps=dv_lvlh, truth_before=before,
                            truth_after=after, path_t_s=path_t, path_lvlh=path_x, torque_nm=torque,
                            attitude_before=att_before, attitude_after=att_after)
        self._t += period
        self._step += 1
        self._measurement = None
        return result

    def advance(self, duration_s: float) -> StepResult:
        """Coast for duration_s [s]: a command with every thruster off (it counts as a step)."""
        return self.apply_command(np.zeros(6), duration_s)

    # ---- internals --------------------------------------------------------------------------
    def _burn_segments(self, applied: np.ndarray, accel_per_thruster: np.ndarray):
        """Yield (duration, LVLH acceleration) for the constant-thrust pieces of the burn."""
        t = 0.0
        for end in np.unique(applied[applied > 0.0]):
            on = applied >= end
            yield end - t, lvlh_delta_v(np.where(on, accel_per_thruster, 0.0))
            t = end

    def _cw_period(self, x, period, delay, applied, accel, dv_lvlh, path):
        n = self._n

        def coast(x0, t0, dt):
            path.add_segment(t0, dt, lambda tau: cw_stm(n, tau) @ x0)
            return cw_stm(n, dt) @ x0

        if self.impulsive:
            if delay == 0.0:
                # Exactly the flight software's prediction model: x+ = Phi(Ts) (x + [0; dv]).
                x1 = x + np.concatenate((np.zeros(3), dv_lvlh))
                path.add_segment(0.0, period, lambda tau: cw_stm(n, tau) @ x1)
                return cw_stm(n, period) @ x1
            x = coast(x, 0.0, delay)
            x = x + np.concatenate((np.zeros(3), dv_lvlh))
            return coast(x, delay, period - delay)
        if delay > 0.0:
            x = coast(x, 0.0, delay)
        burned = 0.0
        for dt, a in self._burn_segments(applied, accel):
            x0 = x
            path.add_segment(delay + burned, dt,
                             lambda tau, x0=x0, a=a: cw_stm(n, tau) @ x0 + cw_forced_response(n, tau) @ a)
            x = cw_stm(n, dt) @ x0 + cw_forced_response(n, dt) @ a
            burned += dt
        rest = period - delay - burned
        return coast(x, delay + burned, rest) if rest > 0.0 else x

    def _nonlinear_period(self, y, period, delay, applied, accel, dv_lvlh, path):
        prop = self._pair

        def leg(y0, t0, dt, thrust=None):
            if dt <= 0.0:
                return y0
            times = path.sample_times(dt)
            y1, ys = prop.propagate_sampled(y0, dt, times, thrust_lvlh_mps2=thrust)
            path.add_states(t0, times, [self._lvlh_from_pair(yi) for yi in ys])
            return y1

        y = leg(y, 0.0, delay)
        if self.impulsive:
            if dv_lvlh.any():
                y = y.copy()
                # A velocity jump dv in LVLH components is the same jump C^T dv in ECI (rho unchanged).
                y[9:12] += lvlh_basis(y[0:3], y[3:6]).T @ dv_lvlh
            return leg(y, delay, period - delay)
        burned = 0.0
        for dt, a in self._burn_segments(applied, accel):
            y = leg(y, delay + burned, dt, a)
            burned += dt
        return leg(y, delay + burned, max(period - delay - burned, 0.0))

    def _target_normal_accel(self, r_t, v_t) -> float:
        """Target perturbing acceleration along its orbit normal [m/s^2] (turns the LVLH frame)."""
        a = self.force_model.perturbation_accel(r_t, v_t, self.scenario.target.ballistic_m2_kg)
        return float(lvlh_basis(r_t, v_t)[2] @ a)

    def _lvlh_from_pair(self, y) -> np.ndarray:
        r_t, v_t = y[0:3], y[3:6]
        return eci_to_lvlh(r_t, v_t, r_t + y[6:9], v_t + y[9:12], self._target_normal_accel(r_t, v_t))


class _PathSampler:
    """Collects the true states of one period at most `max_spacing_s` apart, segment by segment
    (coast, each constant-thrust piece of a burn), so every burn start and end is a sample."""

    def __init__(self, max_spacing_s: float):
        self.max_spacing_s = max_spacing_s
        self._t: list[float] = []
        self._x: list[np.ndarray] = []

    def sample_times(self, duration_s: float) -> np.ndarray:
        """Sample times inside a segment, relative to its start: (0, duration], evenly spaced."""
        count = max(1, math.ceil(duration_s / self.max_spacing_s - 1e-9))
        return duration_s * np.arange(1, count + 1) / count

    def add_states(self, t0: float, times, states) -> None:
        self._t.extend(t0 + float(tau) for tau in times)
        self._x.extend(np.asarray(x, float) for x in states)

    def add_segment(self, t0: float, duration_s: float, state_at) -> None:
        if duration_s <= 0.0:
            return
        times = self.sample_times(duration_s)
        self.add_states(t0, times, [state_at(float(tau)) for tau in times])

    def result(self, t_start: float, before: np.ndarray, after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.array([0.0] + self._t) + t_start
        x = np.vstack([before] + self._x) if self._x else np.vstack([before, after])
        if not self._x:
            t = np.array([t_start, t_start])
        x[-1] = after  # the end state exactly as the period's result
        return t, x


def _frozen(a: np.ndarray) -> np.ndarray:
    """A read-only copy: a cached measurement must not be changed by whoever reads it."""
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def _circular_orbit_state(orbit) -> tuple[np.ndarray, np.ndarray]:
    """ECI position [m] and velocity [m/s] on the circular orbit (RAAN, inclination, argument of
    latitude from the scenario), speed sqrt(mu / a)."""
    a = orbit.semi_major_axis_m
    inc = math.radians(orbit.inclination_deg)
    raan = math.radians(orbit.raan_deg)
    u = math.radians(orbit.argument_of_latitude_deg)
    v = math.sqrt(k.MU_EARTH_M3_S2 / a)
    co, so, ci, si, cu, su = math.cos(raan), math.sin(raan), math.cos(inc), math.sin(inc), math.cos(u), math.sin(u)
    r_vec = a * np.array([co * cu - so * su * ci, so * cu + co * su * ci, su * si])
    v_vec = v * np.array([-co * su - so * cu * ci, -so * su + co * cu * ci, cu * si])
    return r_vec, v_vec
