"""Build a plug-in guidance law from its folder: the law's C/C++ sources and a manifest, `law.toml`,
linked with the flight software's harness into `rvd_flight_sw_<name>` by the same CMake build (and
so the same toolchain) as the flight executable: natively in build/native, or statically for a cross
target in build/cross/<target> (build/ of the checkout, or an installed package's cache folder:
rvd_pil.paths).

    name = "cw_target"                  # letters, digits, '_'; the executable is rvd_flight_sw_<name>
    description = "CW two-impulse targeting"
    sources = ["cw_target.c"]           # relative to the folder; .c, .cc, .cpp, .cxx
    include_dirs = ["."]                # optional, relative to the folder
    defines = ["MY_OPTION=1"]           # optional compile definitions

    [params]                            # optional: defaults of the law's own parameters, handed to it
    gain = 0.5                          # in rvd_guidance_config.params (--set law.NAME=VALUE wins)

    [generate]                          # optional: a script that writes generated C before the build
    script = "generate.py"              # relative to the folder; run with this Python
    args = ["--solver", "QOCO"]         # its options

The law implements flight_sw/include/rvd_guidance.h and defines rvd_guidance_law_entry().

A law with [generate] has part of its sources written at build time (e.g. a code-generated solver):
the script is run as `python SCRIPT --out build/generated/<name> ARGS...` before every build, keeps
its own cache in that folder (it returns at once when nothing it depends on changed) and writes
`<out>/sources.json`: {"sources": [...], "include_dirs": [...], "defines": [...]}, absolute paths,
which the build adds to the manifest's. Generated code is never committed.
"""
from __future__ import annotations

import fcntl
import json
import re
import subprocess
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from rvd_pil import paths

MANIFEST = "law.toml"
SOURCE_SUFFIXES = (".c", ".cc", ".cpp", ".cxx")
_KEYS = {"name", "description", "sources", "include_dirs", "defines", "params", "generate"}


class LawBuildError(RuntimeError):
    """A law folder that cannot be built; the message is one line naming the file (and key)."""


@dataclass(frozen=True)
class LawManifest:
    folder: Path
    name: str
    description: str = ""
    sources: tuple[Path, ...] = ()
    include_dirs: tuple[Path, ...] = ()
    defines: tuple[str, ...] = ()
    params: dict = field(default_factory=dict)
    generate_script: Path | None = None  # [generate] script, run before the build
    generate_args: tuple[str, ...] = ()

    @property
    def program(self) -> str:
        return f"rvd_flight_sw_{self.name}"

    def flight_args(self) -> list[str]:
        """The manifest's parameter defaults as flight options (before the user's, which win)."""
        out = []
        for k, v in self.params.items():
            out += ["--set", f"law.{k}={v!r}"]
        return out


def load_manifest(folder: str | Path) -> LawManifest:
    folder = Path(folder).resolve()
    path = folder / MANIFEST
    if not folder.is_dir():
        raise LawBuildError(f"{folder}: not a folder with a guidance law ({MANIFEST} and sources)")
    if not path.is_file():
        raise LawBuildError(f"{path}: no manifest (a guidance law folder holds {MANIFEST} and its sources)")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise LawBuildError(f"{path}: not valid TOML: {exc}") from None
    unknown = sorted(set(data) - _KEYS)
    if unknown:
        raise LawBuildError(f"{path}: unknown key(s) {unknown}; expected some of {sorted(_KEYS)}")
    name = data.get("name")
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,31}", name):
        raise LawBuildError(f"{path}: name must be 1-32 letters, digits and '_' starting with a letter, got {name!r}")

    def strings(key: str) -> list[str]:
        v = data.get(key, [])
        if not isinstance(v, list) or not all(isinstance(x, str) and x for x in v):
            raise LawBuildError(f"{path}: {key} must be a list of strings, got {v!r}")
        return v

    sources = []
    for s in strings("sources"):
        p = (folder / s).resolve()
        if not p.is_file():
            raise LawBuildError(f"{path}: sources: {s} does not exist")
        if p.suffix not in SOURCE_SUFFIXES:
            raise LawBuildError(f"{path}: sources: {s} is not a C or C++ source ({', '.join(SOURCE_SUFFIXES)})")
        sources.append(p)
    includes = []
    for s in strings("include_dirs"):
        p = (folder / s).resolve()
        if not p.is_dir():
            raise LawBuildError(f"{path}: include_dirs: {s} is not a folder")
        includes.append(p)
    defines = strings("defines")
    for d in defines:
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(=[A-Za-z0-9_.+-]*)?", d):
            raise LawBuildError(f"{path}: defines: {d!r} is not NAME or NAME=VALUE")
    params = data.get("params", {})
    if not isinstance(params, dict):
        raise LawBuildError(f"{path}: [params] must be a table of numbers")
    for k, v in params.items():
        if not re.fullmatch(r"[A-Za-z0-9_.]{1,23}", k):
            raise LawBuildError(f"{path}: params: {k!r} is not a parameter name (1-23 letters, digits, '_', '.')")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise LawBuildError(f"{path}: params: {k} must be a number, got {v!r}")
    gen = data.get("generate")
    script, gen_args = None, ()
    if gen is not None:
        if not isinstance(gen, dict) or set(gen) - {"script", "args"} or not isinstance(gen.get("script"), str):
            raise LawBuildError(f"{path}: [generate] takes script = \"FILE.py\" and optional args = [...]")
        script = (folder / gen["script"]).resolve()
        if not script.is_file() or script.suffix != ".py":
            raise LawBuildError(f"{path}: generate: script {gen['script']} is not a Python file")
        gen_args = gen.get("args", [])
        if not isinstance(gen_args, list) or not all(isinstance(x, str) for x in gen_args):
            raise LawBuildError(f"{path}: generate: args must be a list of strings, got {gen_args!r}")
    elif not sources:
        raise LawBuildError(f"{path}: sources: at least one source file is needed")
    return LawManifest(folder=folder, name=name, description=str(data.get("description", "")),
                       sources=tuple(sources), include_dirs=tuple(includes), defines=tuple(defines),
                       params={k: float(v) for k, v in params.items()}, generate_script=script,
                       generate_args=tuple(gen_args))


def generate(manifest: LawManifest) -> LawManifest:
    """Runs the law's [generate] script (a no-op for a law without one) and returns the manifest with
    the generated sources, include folders and defines added."""
    if manifest.generate_script is None:
        return manifest
    out = paths.build_root() / "generated" / manifest.name
    out.mkdir(parents=True, exist_ok=True)
    with open(out / ".rvd-generate.lock", "w") as lock:  # a campaign and a test may generate at once
        fcntl.flock(lock, fcntl.LOCK_EX)
        r = subprocess.run([sys.executable, str(manifest.generate_script), "--out", str(out), *manifest.generate_args],
                           capture_output=True, text=True, cwd=manifest.folder)
        if r.returncode != 0:
            last = (r.stderr or r.stdout).strip().splitlines()[-1:] or ["no output"]
            raise LawBuildError(f"{manifest.folder / MANIFEST}: generate: {manifest.generate_script.name} failed "
                                f"(exit {r.returncode}): {last[0]}")
        try:
            made = json.loads((out / "sources.json").read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise LawBuildError(f"{manifest.folder / MANIFEST}: generate: no valid {out / 'sources.json'}: {exc}") from None
    sources = tuple(Path(s) for s in made.get("sources", []))
    missing = [s for s in sources if not s.is_file()]
    if missing or not sources:
        raise LawBuildError(f"{manifest.folder / MANIFEST}: generate: the script listed no sources or missing ones "
                            f"({missing[:1]})")
    return LawManifest(folder=manifest.folder, name=manifest.name, description=manifest.description,
                       sources=manifest.sources + sources,
                       include_dirs=manifest.include_dirs + tuple(Path(d) for d in made.get("include_dirs", [])),
                       defines=manifest.defines + tuple(made.get("defines", [])), params=manifest.params,
                       generate_script=manifest.generate_script, generate_args=manifest.generate_args)


def _cmake_list(items) -> str:
    for x in items:
        if any(c in str(x) for c in '";$\n'):
            raise LawBuildError(f"path {x!s} has a character CMake lists cannot hold")
    return " ".join(f'"{x}"' for x in items)


def register(manifest: LawManifest, build_dir: Path) -> Path:
    """Writes <build_dir>/guidance/<name>.cmake so that the next configure adds the law's target."""
    out = Path(build_dir) / "guidance" / f"{manifest.name}.cmake"
    out.parent.mkdir(parents=True, exist_ok=True)
    text = (f"# Generated by rvd_pil/host_sim/guidance_build.py from {manifest.folder / MANIFEST}\n"
            f"rvd_add_guidance_law(NAME {manifest.name}\n"
            f"  SOURCES {_cmake_list(manifest.sources)}\n"
            + (f"  INCLUDE_DIRS {_cmake_list(manifest.include_dirs)}\n" if manifest.include_dirs else "")
            + (f"  DEFINES {_cmake_list(manifest.defines)}\n" if manifest.defines else "")
            + ")\n")
    if not out.is_file() or out.read_text() != text:
        out.write_text(text)
    return out


def _run(cmd: list[str], what: str, manifest: LawManifest) -> None:
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        lines = (r.stdout + r.stderr).splitlines()
        # a compiler's or linker's diagnostic first (a source may have "error" in its name)
        errors = [ln for ln in lines if "error:" in ln.lower()] or [ln for ln in lines if "error" in ln.lower()]
        first = errors[0].strip() if errors else (r.stderr or r.stdout).strip().splitlines()[-1:]
        raise LawBuildError(f"{manifest.folder / MANIFEST}: {what} failed: {first}")


def build_native(folder: str | Path, *, build_dir: Path | None = None, jobs: int = 2) -> tuple[Path, LawManifest]:
    """Builds the law natively; returns (executable, manifest)."""
    manifest = generate(load_manifest(folder))
    bdir = Path(build_dir or paths.build_root() / "native")
    bdir.mkdir(parents=True, exist_ok=True)
    # One builder per build directory at a time (the lock file rvd_pil/qemu/build.py uses for its trees).
    with open(bdir / ".rvd-build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        registration = register(manifest, bdir)
        try:
            _run(["cmake", "-S", str(paths.source_root()), "-B", str(bdir), "-DCMAKE_BUILD_TYPE=Release",
                  f"-DRVD_BUILD_TESTS={'ON' if paths.cpp_tests() else 'OFF'}"], "configure", manifest)
            _run(["cmake", "--build", str(bdir), f"-j{jobs}", "--target", manifest.program], "build", manifest)
        except LawBuildError:
            registration.unlink(missing_ok=True)  # a law that does not build stays out of the build tree
            raise
    exe = bdir / "flight_sw" / manifest.program
    if not exe.is_file():
        raise LawBuildError(f"{manifest.folder / MANIFEST}: the build made no {exe}")
    return exe, manifest


def build_cross(folder: str | Path, target, *, jobs: int = 2):
    """Builds the law statically for a cross target (rvd_pil.qemu.targets.Target); returns (Executable, manifest)."""
    from rvd_pil.qemu import build as qbuild

    manifest = generate(load_manifest(folder))
    registration = register(manifest, qbuild.build_dir(target))
    try:
        exe = qbuild.cross_build(target, manifest.program, jobs=jobs)
    except Exception as exc:  # the cross build's own error, as one line
        registration.unlink(missing_ok=True)
        raise LawBuildError(f"{manifest.folder / MANIFEST}: cross build for {target.name} failed: "
                            f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    return exe, manifest
