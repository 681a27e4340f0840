"""Scenarios: initial conditions and vehicle/environment parameters, stored as flat TOML files in
`rvd_pil/host_sim/scenarios/` (installed with the package) and loaded with `load(name_or_path)`.

Defaults (used for any key a TOML file leaves out) follow the dissertation: two 14 kg 6U CubeSats,
chaser Cd 1.4, target Cd 2.0, six 0.5 N thrusters with a 10 ms minimum impulse bit, Table 5.1
thrust error, sigma 5 cm / 1 mm/s navigation noise, 200 min timeout. Choices the dissertation
leaves open, and ours:
- orbit: circular, 500 km altitude, 51.6 deg inclination (an ISS-like LEO), RAAN 0, argument of
  latitude 0 at t = 0;
- drag area 0.0366 m^2 for both vehicles: the 10 x 36.6 cm face of a 6U (10 x 22.6 x 36.6 cm)
  facing the flow, attitude held fixed in LVLH.

`random_scenario(seed)` draws the dissertation's Monte Carlo initial states (section 5.4).
Obstacles (ellipsoidal keep-out zones) are `[[obstacles]]` tables, checked at load time
(rvd_pil.host_sim.obstacles); a scenario without any has no obstacle anywhere.

`dynamics = "planar"` puts the run on an air-bearing table instead of an orbit (Dong, Ghiglino et
al.'s 2-D testbed, their eq. 4): x, y and the chaser's rotation about z, no gravity gradient, the
target moving at constant velocity and turning at a constant rate. The `[planar]` table gives the
table-frame states of target and chaser (Table 2's units: m, deg, m/s, deg/s), the chaser's
inertia and torque limit; the loader puts the chaser's relative state into `[chaser]` and the
target's angle and rate into `[target]` (so neither may be given there), and an obstacle with
`frame = "table"` has its state converted from the table frame as well. The guidance's "LVLH" is
then the frame that translates with the target's centre of mass with the table's axes (z up),
where the relative motion is a double integrator.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from . import constants as k
from .cw import drift_free_velocity
from .noise import GaussMarkovParams, SensorParams
from . import obstacles as obstacle_config
from .obstacles import Obstacle
from .safety import SafetyLimits
from .thrusters import ThrusterParams


class ScenarioError(ValueError):
    """A scenario file or value is invalid; the message names the file and the key."""


@dataclass(frozen=True)
class OrbitConfig:
    """Target orbit: circular, `altitude_m` above the sphere of radius constants.R_EARTH_M."""

    altitude_m: float = 500e3
    inclination_deg: float = 51.6
    raan_deg: float = 0.0
    argument_of_latitude_deg: float = 0.0

    @property
    def semi_major_axis_m(self) -> float:
        return k.R_EARTH_M + self.altitude_m

    @property
    def mean_motion_rad_s(self) -> float:
        """Two-body mean motion sqrt(mu / a^3) [rad/s]."""
        return math.sqrt(k.MU_EARTH_M3_S2 / self.semi_major_axis_m**3)

    @property
    def period_s(self) -> float:
        return 2.0 * math.pi / self.mean_motion_rad_s


@dataclass(frozen=True)
class ChaserConfig:
    """Chaser initial relative state in the target LVLH frame and its mass/drag properties."""

    position_lvlh_m: tuple[float, float, float] = (140.0, -1580.0, 60.0)
    velocity_lvlh_mps: tuple[float, float, float] = (-0.90, -0.32, 0.0)
    mass_kg: float = 14.0
    drag_coefficient: float = 1.4
    drag_area_m2: float = 0.0366

    @property
    def ballistic_m2_kg(self) -> float:
        """Cd * A / m [m^2/kg]."""
        return self.drag_coefficient * self.drag_area_m2 / self.mass_kg


@dataclass(frozen=True)
class TargetConfig:
    """Target mass/drag properties and attitude (see rvd_pil.host_sim.attitude)."""

    mass_kg: float = 14.0
    drag_coefficient: float = 2.0
    drag_area_m2: float = 0.0366
    initial_angle_deg: float = -90.0
    spin_rate_deg_s: float = 0.0
    docking_port_body_m: tuple[float, float, float] = (0.5, 0.0, 0.0)

    @property
    def ballistic_m2_kg(self) -> float:
        return self.drag_coefficient * self.drag_area_m2 / self.mass_kg


@dataclass(frozen=True)
class PlanarConfig:
    """An air-bearing table (`dynamics = "planar"`): table-frame states [x (m), y (m), angle (deg),
    x rate (m/s), y rate (m/s), angle rate (deg/s)], the chaser's inertia about z, its torque limit
    (held over a control period) and the attitude sensor's noise."""

    target_table: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    chaser_table: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    chaser_inertia_kgm2: float = 0.0
    torque_max_nm: float = 0.0
    sigma_angle_deg: float = 0.0
    sigma_rate_deg_s: float = 0.0

    def target_table_state(self, t_s: float) -> np.ndarray:
        """[x, y, vx, vy] of the target's centre of mass on the table at t_s (constant velocity)."""
        x, y, _, vx, vy, _ = self.target_table
        return np.array([x + vx * t_s, y + vy * t_s, vx, vy])


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str = ""
    timeout_s: float = 12000.0
    orbit: OrbitConfig = field(default_factory=OrbitConfig)
    chaser: ChaserConfig = field(default_factory=ChaserConfig)
    target: TargetConfig = field(default_factory=TargetConfig)
    thrusters: ThrusterParams = field(default_factory=ThrusterParams)
    thrust_error: GaussMarkovParams = field(default_factory=GaussMarkovParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    safety: SafetyLimits = field(default_factory=SafetyLimits)
    obstacles: tuple[Obstacle, ...] = ()  # ellipsoidal keep-out zones ([[obstacles]]; rvd_pil.host_sim.obstacles)
    dynamics: str = "orbital"             # or "planar": an air-bearing table (PlanarConfig)
    # A rendezvous to a holding distance instead of a docking (Dong et al.'s 3-D scenario, Weiss et al.'s):
    # the run ends, reached ("held"), once the true range to the target's centre of mass is at most this.
    # 0: a docking, ended by the flight software's docked declaration.
    hold_range_m: float = 0.0
    planar: PlanarConfig = field(default_factory=PlanarConfig)
    # [guidance]: flight software settings by their --set names (rvd_flight_sw --list-params), sent to it
    # with the vehicle at the start of a run; the flight software refuses a name it does not know.
    guidance: dict = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (JSON-ready) of every parameter, for run records. No obstacles: no "obstacles"
        key, so that records and content keys of obstacle-free scenarios stay what they were."""
        d = _plain(dataclasses.asdict(self))
        if not self.obstacles:
            del d["obstacles"]
        if self.dynamics == "orbital":  # likewise the table of a planar run
            del d["dynamics"], d["planar"]
        if not self.hold_range_m:  # and the end of a rendezvous to a holding distance
            del d["hold_range_m"]
        return d

    @property
    def is_planar(self) -> bool:
        return self.dynamics == "planar"

    def replace(self, **changes) -> "Scenario":
        """Copy with top-level fields replaced (e.g. chaser=dataclasses.replace(s.chaser, ...))."""
        return dataclasses.replace(self, **changes)


DYNAMICS = ("orbital", "planar")
_SECTIONS = {
    "planar": PlanarConfig,
    "orbit": OrbitConfig,
    "chaser": ChaserConfig,
    "target": TargetConfig,
    "thrusters": ThrusterParams,
    "thrust_error": GaussMarkovParams,
    "sensors": SensorParams,
    "safety": SafetyLimits,
}
_TOP_LEVEL = {"name", "description", "timeout_s", "obstacles", "guidance", "dynamics", "hold_range_m"}


def _plain(obj):
    if isinstance(obj, dict):
        return {key: _plain(v) for key, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def available() -> list[str]:
    """Names of the scenarios shipped with the package."""
    folder = resources.files("rvd_pil.host_sim") / "scenarios"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load(name_or_path: str | Path) -> Scenario:
    """Load a scenario by package name (e.g. "case1_vbar") or from a TOML file path."""
    text_source = str(name_or_path)
    path = Path(text_source)
    if path.suffix == ".toml" or path.exists() or "/" in text_source:
        if not path.is_file():
            raise ScenarioError(f"scenario file {path} does not exist")
        return from_toml(path.read_text(encoding="utf-8"), source=str(path))
    resource = resources.files("rvd_pil.host_sim") / "scenarios" / f"{text_source}.toml"
    if not resource.is_file():
        raise ScenarioError(f"unknown scenario {text_source!r}; available: {', '.join(available())} "
                            "(or give a path to a .toml file)")
    return from_toml(resource.read_text(encoding="utf-8"), source=f"rvd_pil/host_sim/scenarios/{text_source}.toml")


def from_toml(text: str, source: str = "<string>") -> Scenario:
    """Parse scenario TOML text (see the files in rvd_pil/host_sim/scenarios/ for the shape)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: not valid TOML: {exc}") from exc
    return from_dict(data, source=source)


def from_dict(data: dict[str, Any], source: str = "<dict>") -> Scenario:
    """Build and validate a Scenario from the dict shape of the TOML files."""
    unknown = set(data) - _TOP_LEVEL - set(_SECTIONS)
    if unknown:
        raise ScenarioError(f"{source}: unknown key(s) {sorted(unknown)}; expected {sorted(_TOP_LEVEL)} "
                            f"and sections {sorted(_SECTIONS)}")
    if "name" not in data:
        raise ScenarioError(f"{source}: missing 'name'")
    dynamics = data.get("dynamics", "orbital")
    if dynamics not in DYNAMICS:
        raise ScenarioError(f"{source} dynamics: expected one of {list(DYNAMICS)}, got {dynamics!r}")
    if dynamics == "planar":
        data = _planar_to_relative(data, source)
    elif "planar" in data:
        raise ScenarioError(f"{source}: a [planar] table needs dynamics = \"planar\"")
    parts = {}
    for section, cls in _SECTIONS.items():
        table = data.get(section, {})
        if not isinstance(table, dict):
            raise ScenarioError(f"{source}: [{section}] must be a table")
        parts[section] = _build_section(cls, table, f"{source} [{section}]")
    try:
        obstacles = obstacle_config.parse(data.get("obstacles", []), source)
    except obstacle_config.ObstacleError as exc:
        raise ScenarioError(str(exc)) from None
    scenario = Scenario(name=str(data["name"]), description=str(data.get("description", "")),
                        timeout_s=_number(data.get("timeout_s", 12000.0), f"{source} timeout_s"), obstacles=obstacles,
                        dynamics=dynamics, hold_range_m=_number(data.get("hold_range_m", 0.0), f"{source} hold_range_m"),
                        guidance=_guidance_section(data.get("guidance", {}), f"{source} [guidance]"), **parts)
    validate(scenario, source)
    return scenario


def _planar_to_relative(data: dict, source: str) -> dict:
    """A planar scenario's table-frame states as the relative ones every scenario has: the chaser's
    state minus the target's into [chaser], the target's angle and rate into [target], obstacles with
    frame = "table" shifted likewise (their velocity relative to the target's)."""
    planar = data.get("planar")
    if not isinstance(planar, dict) or "target_table" not in planar or "chaser_table" not in planar:
        raise ScenarioError(f"{source}: dynamics = \"planar\" needs a [planar] table with target_table and chaser_table")
    cfg = _build_section(PlanarConfig, planar, f"{source} [planar]")
    data = dict(data)
    chaser = dict(data.get("chaser", {}) or {})
    target = dict(data.get("target", {}) or {})
    for table, keys, name in ((chaser, ("position_lvlh_m", "velocity_lvlh_mps"), "chaser"),
                              (target, ("initial_angle_deg", "spin_rate_deg_s"), "target")):
        given = sorted(set(keys) & set(table))
        if given:
            raise ScenarioError(f"{source} [{name}] {given}: a planar scenario gives them in [planar] "
                                f"{name}_table (table frame)")
    tx, ty, ta, tvx, tvy, tw = cfg.target_table
    cx, cy, _, cvx, cvy, _ = cfg.chaser_table
    chaser.update(position_lvlh_m=[cx - tx, cy - ty, 0.0], velocity_lvlh_mps=[cvx - tvx, cvy - tvy, 0.0])
    target.update(initial_angle_deg=ta, spin_rate_deg_s=tw)
    data.update(chaser=chaser, target=target)
    obstacles = []
    for i, entry in enumerate(data.get("obstacles", []) or []):
        if isinstance(entry, dict) and "frame" in entry:
            entry = dict(entry)
            frame = entry.pop("frame")
            if frame not in ("table", "lvlh"):
                raise ScenarioError(f"{source} [[obstacles]] #{i + 1} frame: \"table\" or \"lvlh\", got {frame!r}")
            if frame == "table":
                p = _planar_vector(entry.get("position_lvlh_m", [0.0, 0.0, 0.0]), f"{source} [[obstacles]] #{i + 1}")
                v = _planar_vector(entry.get("velocity_lvlh_mps", [0.0, 0.0, 0.0]), f"{source} [[obstacles]] #{i + 1}")
                entry["position_lvlh_m"] = [p[0] - tx, p[1] - ty, p[2]]
                entry["velocity_lvlh_mps"] = [v[0] - tvx, v[1] - tvy, v[2]]
        obstacles.append(entry)
    if obstacles:
        data["obstacles"] = obstacles
    return data


def _planar_vector(value, where: str) -> list[float]:
    if not isinstance(value, list) or len(value) != 3:
        raise ScenarioError(f"{where}: expected a list of 3 numbers, got {value!r}")
    return [_number(v, where) for v in value]


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(f"{where}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ScenarioError(f"{where}: must be finite, got {value!r}")
    return v


def _build_section(cls, table: dict[str, Any], where: str):
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(table) - set(fields)
    if unknown:
        raise ScenarioError(f"{where}: unknown key(s) {sorted(unknown)}; expected some of {sorted(fields)}")
    values = {}
    for key, value in table.items():
        default = getattr(cls(), key)
        if isinstance(default, tuple):
            if not isinstance(value, list) or len(value) != len(default):
                raise ScenarioError(f"{where} {key}: expected a list of {len(default)} numbers, got {value!r}")
            values[key] = tuple(_number(v, f"{where} {key}") for v in value)
        else:
            values[key] = _number(value, f"{where} {key}")
    return cls(**values)


def settings_text(guidance: dict) -> str:
    """A scenario's [guidance] table as the config message's settings: NAME=VALUE;... with the flight
    software's --set names (numbers in full precision, lists comma-separated, booleans on/off)."""
    def text(v) -> str:
        if isinstance(v, bool):
            return "on" if v else "off"
        if isinstance(v, (list, tuple)):
            return ",".join(text(x) for x in v)
        if isinstance(v, float):
            return repr(v)
        return str(v)
    return ";".join(f"{k}={text(v)}" for k, v in guidance.items())


#: Bytes of settings the config message carries (schema/rvd_messages.toml, config.settings).
SETTINGS_BYTES = 512


def _guidance_section(table, where: str) -> dict:
    """The [guidance] table: NAME = number, on/off boolean, choice name or list of numbers."""
    if not isinstance(table, dict):
        raise ScenarioError(f"{where}: must be a table of flight software settings (NAME = VALUE)")
    out = {}
    for key, value in table.items():
        if not key or not all(c.isalnum() or c in "._" for c in key):
            raise ScenarioError(f"{where} {key!r}: a setting name has letters, digits, '.' and '_' "
                                "(see rvd_flight_sw --list-params)")
        if isinstance(value, dict):
            raise ScenarioError(f"{where} {key}: write dotted names (e.g. \"rendezvous.N\" = 30), not sub-tables")
        if isinstance(value, list):
            value = [_number(v, f"{where} {key}") for v in value]
        elif isinstance(value, str):
            if not value or any(c in value for c in ";=\n"):
                raise ScenarioError(f"{where} {key}: {value!r} is not a setting value")
        elif not isinstance(value, bool):
            value = _number(value, f"{where} {key}")
            value = int(value) if value == int(value) and abs(value) < 1e15 and isinstance(table[key], int) else value
        out[key] = value
    size = len(settings_text(out).encode())
    if size > SETTINGS_BYTES:
        raise ScenarioError(f"{where}: {size} bytes of settings as the config message carries them, at most "
                            f"{SETTINGS_BYTES} (\"phases.NAME\" sets one value in all three phases)")
    return out


def validate(s: Scenario, source: str = "<scenario>") -> None:
    """Raise ScenarioError if a value is physically meaningless."""
    def need(cond: bool, what: str):
        if not cond:
            raise ScenarioError(f"{source}: {what}")

    need(s.timeout_s > 0.0, f"timeout_s must be > 0, got {s.timeout_s}")
    need(s.hold_range_m >= 0.0, f"hold_range_m must be >= 0 (0: a docking), got {s.hold_range_m}")
    need(100e3 <= s.orbit.altitude_m <= 40000e3,
         f"orbit altitude_m must be 100-40000 km (LEO to just above GEO), got {s.orbit.altitude_m}")
    need(0.0 <= s.orbit.inclination_deg <= 180.0, f"orbit inclination_deg must be 0-180, got {s.orbit.inclination_deg}")
    for label, vehicle in (("chaser", s.chaser), ("target", s.target)):
        need(vehicle.mass_kg > 0.0, f"{label} mass_kg must be > 0")
        need(vehicle.drag_coefficient >= 0.0, f"{label} drag_coefficient must be >= 0")
        need(vehicle.drag_area_m2 >= 0.0, f"{label} drag_area_m2 must be >= 0")
    need(s.thrusters.force_n > 0.0, "thrusters force_n must be > 0")
    need(s.thrusters.minimum_impulse_bit_s >= 0.0, "thrusters minimum_impulse_bit_s must be >= 0")
    te = s.thrust_error
    need(te.tau_s > 0.0 and te.omega_n_rad_s > 0.0 and te.xi > 0.0,
         "thrust_error tau_s, omega_n_rad_s and xi must be > 0 (a stable Gauss-Markov model)")
    need(te.eta_w >= 0.0 and te.eta_v >= 0.0, "thrust_error eta_w, eta_v must be >= 0")
    need(s.sensors.sigma_position_m >= 0.0 and s.sensors.sigma_velocity_mps >= 0.0,
         "sensors sigma_position_m, sigma_velocity_mps must be >= 0")
    sf = s.safety
    for name in ("keepout_radius_m", "overshoot_distance_m", "docking_speed_max_mps", "collision_radius_m",
                 "contact_speed_max_mps", "contact_lateral_max_m"):
        need(getattr(sf, name) > 0.0, f"safety {name} must be > 0, got {getattr(sf, name)}")
    for name in ("approach_half_angle_deg", "docking_half_angle_deg"):
        need(0.0 < getattr(sf, name) < 89.0, f"safety {name} must be in (0, 89) deg, got {getattr(sf, name)}")
    need(sf.overshoot_distance_m < sf.keepout_radius_m, "safety overshoot_distance_m must be < keepout_radius_m")
    need(all(u > 0.0 for u in sf.u_max_mps), f"safety u_max_mps must be > 0 per phase, got {list(sf.u_max_mps)}")
    for name in ("thrust_error_sigmas", "geometry_tolerance_m", "docking_cone_tolerance_m", "docking_speed_tolerance_mps",
                 "thrust_command_tolerance_mps"):
        need(getattr(sf, name) >= 0.0, f"safety {name} must be >= 0, got {getattr(sf, name)}")
    if s.is_planar:
        pl = s.planar
        need(pl.chaser_inertia_kgm2 > 0.0, f"planar chaser_inertia_kgm2 must be > 0, got {pl.chaser_inertia_kgm2}")
        need(pl.torque_max_nm > 0.0, f"planar torque_max_nm must be > 0, got {pl.torque_max_nm}")
        need(pl.sigma_angle_deg >= 0.0 and pl.sigma_rate_deg_s >= 0.0, "planar sigma_angle_deg, sigma_rate_deg_s must be >= 0")
        need(s.guidance.get("relative_motion", "double_integrator") == "double_integrator",
             "a planar scenario's guidance has no orbit: relative_motion is \"double_integrator\" (the host sets it)")
        for o in s.obstacles:
            need(o.motion == "constant_velocity",
                 f"obstacle id {o.id}: on a table an obstacle moves at constant velocity, not {o.motion!r}")
    if s.obstacles:
        try:
            obstacle_config.validate(s.obstacles, chaser_position_lvlh_m=s.chaser.position_lvlh_m,
                                     target_radius_m=sf.collision_radius_m,
                                     mean_motion_rad_s=0.0 if s.is_planar else s.orbit.mean_motion_rad_s,
                                     source=source)
        except obstacle_config.ObstacleError as exc:
            raise ScenarioError(str(exc)) from None


def random_scenario(seed: int, base: str | Scenario = "case1_vbar", *, range_m: tuple[float, float] = (150.0, 2500.0),
                    velocity_sigma_mps: float = 0.5) -> Scenario:
    """A Monte Carlo initial state (dissertation section 5.4), everything else from `base`.

    Range uniform in 0.15-2.5 km; direction isotropic (uniform on the sphere; the dissertation does
    not say, and this does not favour any approach corridor); velocity = the drift-free,
    target-centred CW relative-orbit velocity at that position (rvd_pil.host_sim.cw.drift_free_velocity)
    + N(0, 0.5 m/s) per LVLH axis. The same seed gives the same scenario. `range_m` (low, high) and
    `velocity_sigma_mps` change the dispersions; the defaults are the dissertation's."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    lo, hi = (float(v) for v in range_m)
    if not (0.0 < lo <= hi and math.isfinite(hi)):
        raise ValueError(f"range_m must be (low, high) with 0 < low <= high, got {range_m!r}")
    if not (math.isfinite(float(velocity_sigma_mps)) and float(velocity_sigma_mps) >= 0.0):
        raise ValueError(f"velocity_sigma_mps must be a finite number >= 0, got {velocity_sigma_mps!r}")
    base_scenario = load(base) if not isinstance(base, Scenario) else base
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CE7A]))
    distance_m = rng.uniform(lo, hi)
    direction = rng.standard_normal(3)
    direction /= np.linalg.norm(direction)
    position = distance_m * direction
    velocity = (drift_free_velocity(base_scenario.orbit.mean_motion_rad_s, position)
                + rng.normal(0.0, float(velocity_sigma_mps), 3))
    chaser = dataclasses.replace(base_scenario.chaser, position_lvlh_m=tuple(float(v) for v in position),
                                 velocity_lvlh_mps=tuple(float(v) for v in velocity))
    return dataclasses.replace(
        base_scenario, name=f"random_{int(seed)}", chaser=chaser,
        description=(f"Monte Carlo initial state, seed {int(seed)}: range {distance_m:.1f} m, isotropic direction, "
                     f"drift-free velocity + N(0, {float(velocity_sigma_mps):g} m/s); target and vehicles as "
                     f"{base_scenario.name}"))
