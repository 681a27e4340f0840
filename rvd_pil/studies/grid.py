"""The grid of a study: every run it asks for, and the content key that names each run.

A run is a point: (mode, target, CPU, model switches, guidance settings, scenario with all its
parameters, noise seed, repeat index). Its key is a hash of that content together with what
computes it (the executable or in-process module hash, the plugin, the simulator's source and the
numerical libraries), so the same inputs always map to the same key and any change that could
change a record gives a new one. Sweeps that share a point (a baseline setting in several sweeps)
share its run.
"""
from __future__ import annotations

import copy
import functools
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from rvd_pil.host_sim import scenario as scenarios

from .settings import GuidanceSettings
from .spec import HOST, Study, StudyError, _merge, _set_path


@dataclass(frozen=True)
class RunPoint:
    sweep: str
    axes: tuple                     # ((path, value), ...) of the sweep point, for the report
    mode: str
    target: str                     # "host" for in-process and native runs
    cpu: str | None                 # CPU override (None: the target's own)
    model: tuple                    # sorted (name, value) pairs: truth, noise switches, delay, ...
    guidance: GuidanceSettings
    scenario_label: str             # "case1_vbar", "random:7", or the file as written
    scenario: str                   # the Scenario's parameters as canonical JSON
    seed: int
    repeat: int
    cmd_timeout_s: float

    def content(self) -> dict:
        """Everything of the point that determines its record (not the sweep it was listed in)."""
        return {"mode": self.mode, "target": self.target, "cpu": self.cpu, "model": dict(self.model),
                "guidance": self.guidance.to_dict(), "scenario": json.loads(self.scenario), "seed": self.seed,
                "repeat": self.repeat}


@functools.lru_cache(maxsize=None)
def check_flight_options(options: tuple[str, ...]) -> None:
    """The flight application's own check of the settings: it is built from the same options the
    executable gets (ValueError with the flight software's message when it refuses them)."""
    from rvd_pil import flight_sw

    flight_sw.FlightApp(["--run", "check", *options])


def canonical(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)


def run_key(point: RunPoint, engine: dict) -> str:
    """Content key of a run: 24 hex digits of SHA-256 over the point and its engine identity."""
    return hashlib.sha256(canonical({"point": point.content(), "engine": engine}).encode()).hexdigest()[:24]


def _scenario_list(config: dict, study: Study, where: str, overrides: dict, cache: dict,
                   overrides_key: str) -> list[tuple[str, str]]:
    """(label, canonical JSON of the Scenario) for the sweep's scenarios, overrides applied."""
    spec = config.get("scenarios", {})
    src = str(study.source)
    items: list[tuple[str, object]] = []
    for i, name in enumerate(spec.get("names", [])):
        key = f"{where}scenarios.names[{i}]"
        looks_like_file = name.endswith(".toml") or "/" in name
        path = (study.source.parent / name) if looks_like_file and not Path(name).is_absolute() else Path(name)
        try:
            scen = scenarios.load(path if looks_like_file else name)
        except scenarios.ScenarioError as exc:
            msg = str(exc)
            if looks_like_file and not path.is_file():
                msg = f"scenario file {name} does not exist (looked at {path})"
            raise StudyError(src, key, msg) from None
        items.append((name, scen))
    rnd = spec.get("random")
    if rnd is not None:
        base_name = rnd.get("base", "case1_vbar")
        try:
            base = scenarios.load(base_name)
        except scenarios.ScenarioError as exc:
            raise StudyError(src, f"{where}scenarios.random.base", str(exc)) from None
        kw = {}
        if "range_m" in rnd:
            kw["range_m"] = tuple(rnd["range_m"])
        if "velocity_sigma_mps" in rnd:
            kw["velocity_sigma_mps"] = rnd["velocity_sigma_mps"]
        first = rnd.get("first", 1)
        for seed in range(first, first + rnd["count"]):
            ck = ("random", seed, base_name, canonical(kw))
            if ck not in cache:
                cache[ck] = scenarios.random_scenario(seed, base, **kw)
            label = f"random:{seed}" if not kw and base_name == "case1_vbar" else f"random:{seed}:{base_name}"
            items.append((label, cache[ck]))
    out = []
    for label, scen in items:
        if overrides:
            merged = _merge(scen.to_dict(), overrides)
            try:
                scen = scenarios.from_dict(merged, source=f"{label} with these values")
            except scenarios.ScenarioError as exc:
                raise StudyError(src, overrides_key, str(exc)) from None
        out.append((label, canonical(scen.to_dict())))
    return out


def expand(study: Study) -> list[RunPoint]:
    """Every point of every sweep (a point shared by two sweeps is listed in both)."""
    src = str(study.source)
    points: list[RunPoint] = []
    cache: dict = {}
    for sw in study.sweeps:
        where = f"{sw.where}." if sw.where else ""
        for axes in sw.points():
            config = copy.deepcopy(sw.config)
            scen_over = copy.deepcopy(config.get("scenarios", {}).get("overrides", {}))
            for path, value in axes.items():
                if path.startswith("scenario."):
                    _set_path(scen_over, path[len("scenario."):], value)
                else:
                    _set_path(config, path, value)
            varied = [a for a in axes if not a.startswith("scenario.")]
            try:
                guidance = GuidanceSettings.from_table(config.get("guidance", {}))
                check_flight_options(tuple(guidance.flight_args()))
            except ValueError as exc:
                key = f"{where}vary" if any(a.startswith("guidance.") for a in varied) else f"{where}guidance"
                raise StudyError(src, key, str(exc).rstrip("; ")) from None
            scen_axes = [a for a in axes if a.startswith("scenario.")]
            over_key = f"{where}vary.{scen_axes[0]}" if scen_axes else f"{where}scenarios.overrides"
            scen = _scenario_list(config, study, where, scen_over, cache, over_key)
            if not scen:
                raise StudyError(src, f"{where}scenarios", "no scenarios (names and random are empty): "
                                                           "the grid has no runs")
            ex, noise = config["execution"], config["noise"]
            targets = ex.get("targets") or [HOST]
            cpus = ex.get("cpus") or [None]
            model = tuple(sorted(config["model"].items()))
            for target in targets:
                for cpu in cpus:
                    for label, scen_json in scen:
                        for seed in range(noise["first_seed"], noise["first_seed"] + noise["repeats"]):
                            for rep in range(ex["repeat"]):
                                points.append(RunPoint(
                                    sweep=sw.name, axes=tuple(axes.items()), mode=ex["mode"], target=target,
                                    cpu=cpu, model=model, guidance=guidance, scenario_label=label,
                                    scenario=scen_json, seed=seed, repeat=rep, cmd_timeout_s=ex["cmd_timeout_s"]))
    if not points:
        raise StudyError(src, "", "the grid has no runs")
    return points


def distinct_runs(points: list[RunPoint]) -> int:
    """How many runs the points need (points with the same content share a run)."""
    return len({canonical(p.content()) for p in points})
