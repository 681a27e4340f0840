"""Study files: parsing and validation.

A study file (TOML) names the grid of runs and what to report; see rvd_pil/studies/README.md for the
format. `load(path, quick=False)` returns a validated `Study`; anything wrong raises StudyError
with the file and the key (`rvd_pil/studies/x.toml: model.truth: expected one of cw, nonlinear, got 'CW'`).
Validation reads the file and the scenarios only: it writes nothing.
"""
from __future__ import annotations

import copy
import itertools
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .settings import GLOBAL_SCALARS, PHASE_SCALARS, PHASES, SOLVER_MODES

MODES = ("in-process", "native", "qemu-user")
TRUTHS = ("cw", "nonlinear")
DELAYS = ("none", "reported", "estimated")
REPORTS = ("sensitivity", "robustness", "timing", "runs")
HOST = "host"
STUDY_DIR = Path(__file__).resolve().parent


class StudyError(ValueError):
    """A study file is invalid: `str(e)` is one line naming the file and the key."""

    def __init__(self, source: str, key: str, message: str):
        self.source, self.key, self.message = source, key, message
        super().__init__(f"{source}: {key}: {message}" if key else f"{source}: {message}")


# ---- the schema: a tree of tables whose leaves are value checkers --------------------------------
class _Leaf:
    def check(self, value, where: str, err) -> Any:
        raise NotImplementedError

    def describe(self) -> str:
        raise NotImplementedError


class Str(_Leaf):
    def __init__(self, choices=None, pattern=None):
        self.choices, self.pattern = choices, pattern

    def check(self, value, where, err):
        if not isinstance(value, str):
            err(where, f"expected {self.describe()}, got {value!r}")
        if self.choices and value not in self.choices:
            err(where, f"expected one of {', '.join(self.choices)}, got {value!r}")
        if self.pattern and not re.fullmatch(self.pattern, value):
            err(where, f"expected {self.describe()}, got {value!r}")
        return value

    def describe(self):
        if self.choices:
            return "one of " + ", ".join(self.choices)
        return "a name of letters, digits, '_' and '-'" if self.pattern else "a string"


class Bool(_Leaf):
    def check(self, value, where, err):
        if not isinstance(value, bool):
            err(where, f"expected true or false, got {value!r}")
        return value

    def describe(self):
        return "true or false"


class Int(_Leaf):
    def __init__(self, lo=None, hi=None):
        self.lo, self.hi = lo, hi

    def check(self, value, where, err):
        if isinstance(value, bool) or not isinstance(value, int):
            err(where, f"expected {self.describe()}, got {value!r}")
        if (self.lo is not None and value < self.lo) or (self.hi is not None and value > self.hi):
            err(where, f"expected {self.describe()}, got {value!r}")
        return value

    def describe(self):
        if self.lo is not None and self.hi is not None:
            return f"an integer in {self.lo}..{self.hi}"
        return f"an integer >= {self.lo}" if self.lo is not None else "an integer"


class Num(_Leaf):
    def __init__(self, lo=None, positive=False):
        self.lo, self.positive = lo, positive

    def check(self, value, where, err):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            err(where, f"expected {self.describe()}, got {value!r}")
        if (self.positive and value <= 0) or (self.lo is not None and value < self.lo):
            err(where, f"expected {self.describe()}, got {value!r}")
        return float(value)

    def describe(self):
        if self.positive:
            return "a number > 0"
        return f"a number >= {self.lo:g}" if self.lo is not None else "a finite number"


class ListOf(_Leaf):
    def __init__(self, item: _Leaf, length=None):
        self.item, self.length = item, length

    def check(self, value, where, err):
        if not isinstance(value, list) or (self.length is not None and len(value) != self.length):
            err(where, f"expected {self.describe()}, got {value!r}")
        return [self.item.check(v, f"{where}[{i}]", err) for i, v in enumerate(value)]

    def describe(self):
        n = f"{self.length} " if self.length else ""
        return f"a list of {n}values, each {self.item.describe()}"


class Open(_Leaf):
    """A table whose content is checked elsewhere (scenario parameter overrides)."""

    def check(self, value, where, err):
        if not isinstance(value, dict):
            err(where, f"expected a table, got {value!r}")
        return value

    def describe(self):
        return "a table"


NAME = r"[A-Za-z0-9_][A-Za-z0-9_.-]*"
_PHASE_TABLE = {"N": Int(1, 200), "Ts_s": Num(positive=True),
                **{k: Num(lo=0.0) if k != "los_half_angle_deg" else Num(positive=True) for k in PHASE_SCALARS}}
SCHEMA: dict[str, Any] = {
    "study": {"name": Str(pattern=NAME), "description": Str()},
    "execution": {"mode": Str(MODES), "targets": ListOf(Str()), "cpus": ListOf(Str()),
                  "repeat": Int(1, 1000), "cmd_timeout_s": Num(positive=True)},
    "model": {"truth": Str(TRUTHS), "sensor_noise": Bool(), "thrust_noise": Bool(), "impulsive": Bool(),
              "delay": Str(DELAYS), "j2": Bool(), "drag": Bool()},
    "guidance": {**{ph: dict(_PHASE_TABLE) for ph in PHASES}, "deadline_fraction": Num(positive=True),
                 "solver": Str(SOLVER_MODES), "max_iter": Int(1, 10000), "tol": Num(positive=True),
                 "barrier": Num(positive=True), **{k: Num() for k in GLOBAL_SCALARS}},
    "scenarios": {"names": ListOf(Str()),
                  "random": {"first": Int(0), "count": Int(0), "base": Str(),
                             "range_m": ListOf(Num(positive=True), 2), "velocity_sigma_mps": Num(lo=0.0)},
                  "overrides": Open()},
    "noise": {"repeats": Int(1, 100000), "first_seed": Int(0)},
    "report": {"kind": Str(REPORTS), "figures": ListOf(Str()), "metrics": ListOf(Str())},
}
SWEEP_TABLES = ("execution", "model", "guidance", "scenarios", "noise")  # a sweep may override these
VARY_ROOTS = ("model", "guidance", "scenario")  # and vary these ("scenario." = a scenario parameter)
DEFAULTS = {"execution": {"mode": "native", "repeat": 1, "cmd_timeout_s": 120.0},
            "model": {"truth": "nonlinear", "sensor_noise": True, "thrust_noise": True, "impulsive": False,
                      "delay": "none", "j2": True, "drag": True},
            "noise": {"repeats": 1, "first_seed": 0}}


def _walk(doc: dict, schema: dict, prefix: str, err) -> dict:
    """Checks keys and types of `doc` against `schema` (partial documents allowed)."""
    if not isinstance(doc, dict):
        err(prefix, f"expected a table, got {doc!r}")
    out = {}
    for key, value in doc.items():
        where = f"{prefix}.{key}" if prefix else key
        if key not in schema:
            err(where, f"unknown key; expected one of {', '.join(sorted(schema))}")
        sub = schema[key]
        out[key] = _walk(value, sub, where, err) if isinstance(sub, dict) else sub.check(value, where, err)
    return out


def _leaf_at(path: str):
    node: Any = SCHEMA
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node if isinstance(node, _Leaf) else None


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else copy.deepcopy(v)
    return out


def _flatten(table: dict, prefix: str = "") -> dict[str, Any]:
    """{"a": {"b": 1}, "c.d": 2} -> {"a.b": 1, "c.d": 2}"""
    out = {}
    for k, v in table.items():
        path = f"{prefix}.{k}" if prefix else k
        if isinstance(v, dict):
            out.update(_flatten(v, path))
        else:
            out[path] = v
    return out


def _set_path(doc: dict, path: str, value) -> None:
    parts = path.split(".")
    for p in parts[:-1]:
        doc = doc.setdefault(p, {})
    doc[parts[-1]] = value


# ---- the validated study ---------------------------------------------------------------------------
@dataclass
class Sweep:
    name: str
    config: dict                      # the study's tables with this sweep's overrides applied
    axes: dict[str, list]             # dotted path -> values (cartesian product)
    where: str = ""                   # its place in the file for messages ("sweep[2]", "quick.sweep[0]")

    def points(self):
        """Each combination of the axes as {path: value} (one empty point without axes)."""
        names = list(self.axes)
        for values in itertools.product(*(self.axes[n] for n in names)):
            yield dict(zip(names, values))


@dataclass
class Study:
    name: str
    description: str
    source: Path
    quick: bool
    report: dict
    sweeps: list[Sweep]
    base: dict = field(repr=False)   # the validated tables before sweeps

    @property
    def label(self) -> str:
        return f"{self.name} (quick)" if self.quick else self.name


def resolve(name_or_path: str | Path) -> Path:
    """A study file by path, or by the name of one shipped in rvd_pil/studies/ (e.g. "ch5_robustness")."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists() or "/" in str(name_or_path):
        return p
    return STUDY_DIR / f"{name_or_path}.toml"


def available() -> list[str]:
    return sorted(p.stem for p in STUDY_DIR.glob("*.toml"))


def load(name_or_path: str | Path, quick: bool = False) -> Study:
    path = resolve(name_or_path)
    source = str(name_or_path) if Path(name_or_path).suffix == ".toml" or "/" in str(name_or_path) else str(path)

    def err(key: str, message: str):
        raise StudyError(source, key, message)

    if not path.is_file():
        hint = f"; shipped studies: {', '.join(available())}" if "/" not in str(name_or_path) else ""
        err("", f"study file does not exist{hint}")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        err("", f"not valid TOML: {exc}")
    except UnicodeDecodeError as exc:
        err("", f"not UTF-8 text: {exc}")
    quick_doc = doc.pop("quick", {})
    sweeps_doc = doc.pop("sweep", [])
    checked = _walk(doc, SCHEMA, "", err)
    if not isinstance(quick_doc, dict):
        err("quick", f"expected a table, got {quick_doc!r}")
    quick_sweeps = quick_doc.pop("sweep", None) if isinstance(quick_doc, dict) else None
    if "study" in quick_doc:
        err("quick.study", "the quick size keeps the study's name and description")
    checked_quick = _walk(quick_doc, SCHEMA, "quick", err)
    sweep_prefix = "sweep"
    if quick:
        checked = _merge(checked, checked_quick)
        if quick_sweeps is not None:
            sweeps_doc, sweep_prefix = quick_sweeps, "quick.sweep"
    if "study" not in checked or "name" not in checked["study"]:
        err("study.name", "missing (every study names itself)")
    base = _merge(DEFAULTS, {k: v for k, v in checked.items() if k not in ("study", "report")})
    report = _merge({"kind": "runs", "figures": [], "metrics": []}, checked.get("report", {}))
    _check_report(report, err)

    if not isinstance(sweeps_doc, list):
        err(sweep_prefix, "expected an array of tables ([[sweep]])")
    sweeps = []
    names = set()
    for i, sw in enumerate(sweeps_doc or [{}]):
        where = f"{sweep_prefix}[{i}]" if sweeps_doc else ""
        if not isinstance(sw, dict):
            err(where, f"expected a table, got {sw!r}")
        sw = dict(sw)
        name = sw.pop("name", "all" if not sweeps_doc else None)
        if not isinstance(name, str) or not re.fullmatch(NAME, name):
            err(f"{where}.name", "expected a name of letters, digits, '_' and '-'")
        if name in names:
            err(f"{where}.name", f"sweep {name!r} appears twice")
        names.add(name)
        vary = sw.pop("vary", {})
        unknown = set(sw) - set(SWEEP_TABLES)
        if unknown:
            err(f"{where}.{sorted(unknown)[0]}", f"unknown key; a sweep has name, vary and "
                                                 f"overrides of {', '.join(SWEEP_TABLES)}")
        overrides = _walk(sw, {k: SCHEMA[k] for k in SWEEP_TABLES}, where, err)
        config = _merge(base, overrides)
        axes = {}
        if not isinstance(vary, dict):
            err(f"{where}.vary", f"expected a table, got {vary!r}")
        for axis, values in _flatten(vary).items():
            key = f"{where}.vary.{axis}"
            if axis.split(".")[0] not in VARY_ROOTS:
                err(key, f"unknown axis; axes start with {', '.join(r + '.' for r in VARY_ROOTS)}")
            if not isinstance(values, list):
                err(key, f"expected a list of values to sweep, got {values!r}")
            if not values:
                err(key, "empty list: the grid has no runs")
            if axis.startswith("scenario."):
                for j, v in enumerate(values):
                    if isinstance(v, bool) or not isinstance(v, (int, float, list)):
                        err(f"{key}[{j}]", f"expected a number (or a list of numbers), got {v!r}")
                axes[axis] = values
                continue
            leaf = _leaf_at(axis)
            if leaf is None or axis.startswith(("scenarios.", "noise.", "execution.")):
                err(key, "unknown axis")
            axes[axis] = [leaf.check(v, f"{key}[{j}]", err) for j, v in enumerate(values)]
            if len(set(map(repr, axes[axis]))) != len(axes[axis]):
                err(key, "a value appears twice")
        _check_config(config, where, err)
        sweep = Sweep(name=name, config=config, axes=axes, where=where)
        if any(not a.startswith("scenario.") for a in axes):  # each combination must make sense too
            for point in sweep.points():
                combo = copy.deepcopy(config)
                for axis, value in point.items():
                    if not axis.startswith("scenario."):
                        _set_path(combo, axis, value)
                _check_config(combo, f"{where}.vary" if where else "vary", err)
        sweeps.append(sweep)
    return Study(name=checked["study"]["name"], description=checked["study"].get("description", ""),
                 source=path, quick=quick, report=report, sweeps=sweeps, base=base)


def _check_report(report: dict, err) -> None:
    from . import report as reports  # the catalogue of figures and metrics per report kind

    figures = reports.FIGURES[report["kind"]]
    for i, f in enumerate(report["figures"]):
        if f not in figures:
            err(f"report.figures[{i}]", f"unknown figure {f!r} for a {report['kind']} report; "
                                       f"known: {', '.join(figures) or 'none'}")
    from .metrics import RUN_METRICS

    for i, m in enumerate(report["metrics"]):
        if m not in RUN_METRICS:
            err(f"report.metrics[{i}]", f"unknown metric {m!r}; known: {', '.join(RUN_METRICS)}")


def _check_config(config: dict, where: str, err) -> None:
    """What needs more than one key: mode against targets and delay."""
    pre = f"{where}." if where else ""
    ex, model = config["execution"], config["model"]
    mode = ex["mode"]
    if mode == "qemu-user":
        from rvd_pil.qemu import targets as registry

        if not ex.get("targets"):
            err(f"{pre}execution.targets", "qemu-user needs at least one target (e.g. [\"q7s\"])")
        known = registry.names()
        for i, t in enumerate(ex["targets"]):
            if t not in known or t == HOST:
                err(f"{pre}execution.targets[{i}]", f"unknown target {t!r}; known: "
                                                    f"{', '.join(n for n in known if n != HOST)}")
        for i, cpu in enumerate(ex.get("cpus", [])):
            for t in ex["targets"]:
                try:
                    registry.load(t, cpu=cpu)
                except ValueError as exc:
                    err(f"{pre}execution.cpus[{i}]", str(exc))
    else:
        for key in ("targets", "cpus"):
            if ex.get(key) and ex[key] != [HOST] * len(ex[key]):
                err(f"{pre}execution.{key}", f"mode {mode!r} runs on this host; targets and cpus are for qemu-user")
        if model["delay"] == "estimated":
            err(f"{pre}model.delay", "'estimated' needs instruction counts: mode qemu-user")
    rnd = config.get("scenarios", {}).get("random")
    if rnd is not None and "count" not in rnd:
        err(f"{pre}scenarios.random.count", "missing (how many generated starts)")
    if rnd is not None and "range_m" in rnd and rnd["range_m"][0] > rnd["range_m"][1]:
        err(f"{pre}scenarios.random.range_m", f"expected [low, high] with low <= high, got {rnd['range_m']}")
