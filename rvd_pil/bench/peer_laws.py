"""Our Fast MPC beside its peer guidance laws (examples/guidance), per target, phase and horizon: instructions
per solve, the cycle model's estimated target time, iterations, accuracy against our solver on the same QP,
and the closed loop's delta-v; with the ratios to our Fast MPC.

    python -m rvd_pil.bench.peer_laws                      quick: Case 1 (disturbed), three horizon sets, q7s and rpi3,
                                                   and the determinism checks (ideal Case 1 twice per target)
    python -m rvd_pil.bench.peer_laws --laws lq_ecg        only some peers (fast_mpc is always there)
    python -m rvd_pil.bench.peer_laws --targets rpi3 --no-checks
    python -m rvd_pil.bench.peer_laws --horizon-sets default   only the default horizons 30/15/12 (checks fly them too)
    python -m rvd_pil.bench.peer_laws --check-timeout-s 0      the peers' ideal checks to docking (default: cut at 3000 s)
    python -m rvd_pil.bench.peer_laws --full               the PIL campaign's scenarios (Case 1 and two random starts)
    python -m rvd_pil.bench.peer_laws --report-only        the page from the runs already made

Each law is one PIL campaign (rvd_pil/bench/campaign.py: cross-built statically, run under QEMU user mode with the
instruction counter and the block profiler, priced by the cycle model) in reports/peers/<law>/, with the
same scenarios, horizon sets and noise seed as our MPC's. Each is the campaign `make pil GUIDANCE=<law folder>
PIL_OUT=reports/peers/<law> PIL_ARGS="--scenarios case1_vbar --no-system"` makes (that command's runs are
reused here, and these there). Accuracy: the CVXPYgen peers solve our MPC's
own phase QPs (examples/guidance/cvxpygen_common): each is flown once more natively with law.shadow = 1,
which solves every QP of the run also with our Fast MPC (reference settings) and records the difference
of the first delta-v, of the objective (our OCP objective evaluated at both solutions) and the peer's
violation of the QP's hard rows and dynamics. The LQ + command governor solves another problem (no
horizon; its horizons are the MPC's, ignored): its figures are listed under each horizon for the
ratios, and accuracy does not apply. The same holds for cw_target, the plug-in interface's example
(CW targeting and a glideslope, no optimisation): the floor of what a guidance step can cost.

Writes reports/peers/peers.html (one page), peers.csv and peers.json.
"""
from __future__ import annotations

import argparse
import html
import json
import math
import sys
from pathlib import Path

import pandas as pd

from rvd_pil import paths

LAWS = {"lq_ecg": "examples/guidance/lq_ecg", "cvxpygen_qoco": "examples/guidance/cvxpygen_qoco",
        "cvxpygen_osqp": "examples/guidance/cvxpygen_osqp", "cw_target": "examples/guidance/cw_target"}
DEFAULT_LAWS = ("lq_ecg", "cvxpygen_qoco", "cvxpygen_osqp", "cw_target")
# Laws flown only for the first seconds of each scenario (simulated time; their checks too). OSQP stops at
# its 4000-iteration cap on every rendezvous QP (examples/guidance/README.md): 35-48 s of emulation per
# step, and it never leaves the rendezvous, so a whole run would take hours and measure nothing more.
FLIGHT_TIME_S = {"cvxpygen_osqp": 90.0}
SAME_QP = {"cvxpygen_qoco", "cvxpygen_osqp"}
OURS = "fast_mpc"


def run_campaign(law: str, out: Path, targets: list[str], scenarios: list[str], checks: bool,
                 horizon_sets: str = "all", check_timeout_s: float | None = None) -> int:
    from rvd_pil.bench import campaign

    args = ["--targets", ",".join(targets), "--scenarios", ",".join(scenarios), "--no-system", "--out", str(out)]
    if law in FLIGHT_TIME_S:
        cut = FLIGHT_TIME_S[law]
        args += ["--flight-time-s", f"{cut:g}"]
        check_timeout_s = min(check_timeout_s or cut, cut)
    if check_timeout_s is not None and law != OURS:
        args += ["--check-timeout-s", f"{check_timeout_s:g}"]
    if horizon_sets != "all":
        args += ["--horizon-sets", horizon_sets]
    if not checks:
        args.append("--no-checks")
    if law != OURS:
        args += ["--guidance", str(paths.require_checkout("the peer guidance laws (examples/guidance)") / LAWS[law])]
    return campaign.main(args)


def run_accuracy(law: str, out: Path, scenarios: list[str], horizon_sets) -> None:
    """Native shadow runs: every QP of the closed loop solved by the peer and by our Fast MPC."""
    from rvd_pil.host_sim.guidance_build import build_native
    from rvd_pil.host_sim.pil import run_pil
    from rvd_pil.bench.campaign import _scenario

    exe, manifest = build_native(paths.require_checkout("the peer guidance laws (examples/guidance)") / LAWS[law])
    for horizons in horizon_sets:
        for label in scenarios:
            run_dir = out / f"{label.replace(':', '')}-N{'-'.join(map(str, horizons))}"
            if (run_dir / "meta.json").exists() and json.loads((run_dir / "meta.json").read_text()).get("status") == "finished":
                continue
            if run_dir.exists():
                import shutil

                shutil.rmtree(run_dir)
            summary, _ = run_pil(_scenario(label), seed=0, flight_exe=str(exe),
                                 flight_args=[*manifest.flight_args(), "--set", "law.shadow=1",
                                              "--horizon", ",".join(map(str, horizons))],
                                 run_dir=run_dir, meta={"horizons": list(horizons), "scenario_label": label})
            print(f"  accuracy {law} {label} N{horizons}: {summary.end}, dv {summary.dv_total_mps:.3f} m/s", flush=True)


def accuracy_table(out: Path) -> pd.DataFrame:
    rows = []
    for meta_path in sorted(out.glob("*/meta.json")):
        meta = json.loads(meta_path.read_text())
        steps = pd.read_csv(meta_path.parent / "steps.csv", usecols=["step", "phase"])
        vals = pd.read_csv(meta_path.parent / "law_values.csv")
        wide = vals.pivot_table(index="step", columns="name", values="value").reset_index().merge(steps, on="step")
        if "ref_du_mps" not in wide:
            continue
        for phase, g in wide.groupby("phase"):
            if int(phase) not in (1, 2, 3):
                continue
            ok = g[(g["ref_ok"] == 1) & (g["peer_failed"] == 0)]
            rows.append({"phase": {1: "rendezvous", 2: "approach", 3: "docking"}[int(phase)],
                         "N": int(meta["horizons"][int(phase) - 1]), "scenario": meta.get("scenario_label"),
                         "qps": len(g), "compared": len(ok),
                         "du_max_mps": ok["ref_du_mps"].max(), "du_median_mps": ok["ref_du_mps"].median(),
                         "dobj_rel_max": ok["ref_dobj_rel"].abs().max(), "viol_max": ok["peer_viol"].max()})
    return pd.DataFrame(rows)


def law_table(law: str, out: Path) -> pd.DataFrame:
    """Per target, phase and horizon: the campaign's solve statistics and the closed loops' delta-v."""
    from rvd_pil.bench import report

    metas, df = report.load_campaign(out)
    rows = report.solves(metas, df)
    if rows.empty:
        return pd.DataFrame()
    stats = report.stats_table(rows)
    dv, changes = [], []
    for m in metas:
        if m.get("kind") != "timing":
            continue
        values = out / m["dir"] / "law_values.csv"
        if values.exists():  # our MPC's active-set method reports its row changes by name
            vals = pd.read_csv(values)
            vals = vals[vals["name"] == "active_set_changes"]
            phases = df.loc[df["run"] == m["dir"], ["step", "phase"]]
            for ph, g in vals.merge(phases, on="step").groupby("phase"):
                if int(ph) in report.PHASES:
                    changes.append({"target": m["target"], "phase": report.PHASES[int(ph)],
                                    "N": int(m["horizons"][int(ph) - 1]), "as_mean": g["value"].mean(),
                                    "as_max": g["value"].max()})
        for i, phase in enumerate(report.PHASES.values()):
            dv.append({"target": m["target"], "phase": phase, "N": int(m["horizons"][i]), "run": m["dir"],
                       "dv_phase_mps": (m.get("dv_per_phase_mps") or {}).get(phase, math.nan),
                       "dv_total_mps": m.get("dv_total_mps"), "docked": bool(m.get("docked")),
                       "time_s": m.get("t_end_s"), "flight_time_s": m.get("flight_time_s") or math.nan,
                       "verdict": (m.get("safety") or {}).get("verdict", "?"),
                       "faults": int(m.get("law_faults") or 0) if not isinstance(m.get("law_faults"), dict) else
                       sum((m.get("law_faults") or {}).values())})
    dv = pd.DataFrame(dv).groupby(["target", "phase", "N"], as_index=False).agg(
        dv_phase_mps=("dv_phase_mps", "mean"), dv_total_mps=("dv_total_mps", "mean"),
        docked=("docked", "all"), time_s=("time_s", "mean"), runs=("run", "count"), flight_time_s=("flight_time_s", "max"),
        verdicts=("verdict", lambda v: ",".join(sorted(set(v)))))
    fails = rows.assign(failed=rows["guidance_status"].isin([2, 6])).groupby(["target", "phase_name", "N"],
                                                                              as_index=False)["failed"].sum()
    fails = fails.rename(columns={"phase_name": "phase", "failed": "safe_actions"})
    t = stats.merge(dv, on=["target", "phase", "N"], how="left").merge(fails, on=["target", "phase", "N"], how="left")
    if changes:
        ch = pd.DataFrame(changes).groupby(["target", "phase", "N"], as_index=False).agg(
            active_set_changes_mean=("as_mean", "mean"), active_set_changes_max=("as_max", "max"))
        t = t.merge(ch, on=["target", "phase", "N"], how="left")
    t.insert(0, "law", law)
    return t


def side_by_side(base: Path, laws: list[str]) -> pd.DataFrame:
    tables = []
    for law in [OURS, *laws]:
        out = base / law
        if not (out / "campaign.json").exists():
            print(f"{law}: no campaign in {out}", file=sys.stderr)
            continue
        t = law_table(law, out)
        if t.empty:
            continue
        if law in SAME_QP and (base / "accuracy" / law).exists():
            acc = accuracy_table(base / "accuracy" / law)
            if not acc.empty:
                acc = acc.groupby(["phase", "N"], as_index=False).agg(
                    qps_compared=("compared", "sum"), qps_flown=("qps", "sum"), du_max_mps=("du_max_mps", "max"),
                    du_median_mps=("du_median_mps", "median"), dobj_rel_max=("dobj_rel_max", "max"),
                    viol_max=("viol_max", "max"))
                t = t.merge(acc, on=["phase", "N"], how="left")
        tables.append(t)
    if not tables:
        return pd.DataFrame()
    t = pd.concat(tables, ignore_index=True)
    if "qps_compared" in t:  # the rest were not solved by the peer or by the reference: no difference to take
        t["accuracy_qps"] = [f"{c:.0f} of {n:.0f}" if c == c and n == n else None
                             for c, n in zip(t["qps_compared"], t.get("qps_flown", t["qps_compared"]))]
    ours = t[t["law"] == OURS].set_index(["target", "phase", "N"])
    for col, name in (("insns_mean", "insns_ratio"), ("target_ms_mean", "time_ratio"), ("insns_max", "insns_max_ratio"),
                      ("dv_phase_mps", "dv_phase_ratio")):
        t[name] = [r[col] / ours.loc[(r["target"], r["phase"], r["N"]), col]
                   if (r["target"], r["phase"], r["N"]) in ours.index else math.nan for _, r in t.iterrows()]
    order = {"rendezvous": 0, "approach": 1, "docking": 2}
    t["_o"] = t["phase"].map(order)
    t["_l"] = t["law"].map({OURS: 0, **{l: i + 1 for i, l in enumerate(laws)}})
    return t.sort_values(["target", "_o", "N", "_l"]).drop(columns=["_o", "_l"]).reset_index(drop=True)


def checks_table(base: Path, laws: list[str]) -> pd.DataFrame:
    """Each law's campaign checks (rvd_pil/bench/report.py): identical counts in two QEMU runs, agreement
    with the native build, block profiler against instruction counter; one row per law, target and check."""
    from rvd_pil.bench import report

    tables = []
    for law in [OURS, *laws]:
        out = base / law
        if not (out / "campaign.json").exists():
            continue
        metas, df = report.load_campaign(out)
        t = report.checks_table(report.checks(metas, df))
        if not t.empty:
            t.insert(0, "law", law)
            t["result"] = [r.text if hasattr(r, "text") else str(r) for r in t["result"]]
            tables.append(t)
    return pd.concat(tables, ignore_index=True) if tables else pd.DataFrame()


def plot_instructions(base: Path, t: pd.DataFrame, laws: list[str]) -> Path:
    """Instructions per solve per phase and horizon, one bar per law, one panel per target (log scale:
    the laws span five decades)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    targets = list(dict.fromkeys(t["target"]))
    order = [OURS, *laws]
    fig, axes = plt.subplots(len(targets), 1, figsize=(12, 3.6 * len(targets)), squeeze=False)
    for ax, target in zip(axes[:, 0], targets):
        g = t[t["target"] == target]
        groups = list(dict.fromkeys(zip(g["phase"], g["N"])))
        width = 0.8 / len(order)
        for i, law in enumerate(order):
            h = g[g["law"] == law].set_index(["phase", "N"])
            y = [h.loc[k, "insns_mean"] if k in h.index else np.nan for k in groups]
            if all(np.isnan(y)):
                continue
            cut = h["flight_time_s"].max() if "flight_time_s" in h else np.nan
            label = law + (f" (first {cut:g} s)" if cut == cut else "")
            ax.bar(np.arange(len(groups)) + (i - (len(order) - 1) / 2) * width, y, width, label=label)
        ax.set_yscale("log")
        ax.set_ylim(top=ax.get_ylim()[1] * 30)  # room for the legend above the tallest bars
        ax.set_xticks(np.arange(len(groups)), [f"{ph}\nN = {n}" for ph, n in groups], fontsize=8)
        ax.set_ylabel("instructions per step (mean)")
        ax.set_title(f"{target}: the guidance step under QEMU (filter + law), per phase and horizon", fontsize=10)
        ax.grid(axis="y", which="both", alpha=0.3)
        ax.legend(fontsize=7, ncol=len(order))
    fig.tight_layout()
    path = base / "peers-instructions.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _law_cell(r) -> str:
    cut = r.get("flight_time_s")
    return str(r["law"]) + (f" (first {cut:g} s only)" if cut is not None and not math.isnan(cut) else "")


def _f(v, fmt="{:.3g}") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "—"
    return fmt.format(v)


def write_page(base: Path, t: pd.DataFrame, laws: list[str], settings: dict, chk: pd.DataFrame | None = None) -> Path:
    cols = [("law", "law", "{}"), ("solves", "solves", "{:.0f}"), ("insns_mean", "instructions / solve (mean)", "{:,.0f}"),
            ("insns_max", "max", "{:,.0f}"), ("insns_ratio", "÷ Fast MPC", "{:.3g}"),
            ("target_ms_mean", "est. target ms (mean)", "{:.3f}"), ("target_ms_max", "max", "{:.3f}"),
            ("time_ratio", "÷ Fast MPC", "{:.3g}"), ("iterations_mean", "iterations (mean)", "{:.1f}"),
            ("iterations_max", "max", "{:.0f}"), ("accuracy_qps", "QPs compared (accuracy runs)", "{}"),
            ("active_set_changes_mean", "active-set changes (mean)", "{:.1f}"),
            ("active_set_changes_max", "max", "{:.0f}"), ("du_max_mps", "max |Δu₀ − ours| [m/s]", "{:.1e}"),
            ("dobj_rel_max", "max |ΔJ|/|J|", "{:.1e}"), ("viol_max", "max violation", "{:.1e}"),
            ("safe_actions", "safe actions", "{:.0f}"), ("dv_phase_mps", "Δv phase [m/s]", "{:.3f}"),
            ("dv_phase_ratio", "÷ Fast MPC", "{:.3g}"), ("dv_total_mps", "Δv run [m/s]", "{:.3f}"),
            ("docked", "docked", "{}"), ("verdicts", "safety", "{}")]
    parts = [f"<h1>Guidance peers beside our Fast MPC</h1><p>{html.escape(settings['what'])}</p>",
             "<p>Instructions: counted by the QEMU plugin between the flight software's markers around the law's step "
             "(navigation filter update and the law; identical from run to run). Estimated target time: the cycle "
             "model's nominal cycles / clock (not calibrated on hardware). Accuracy (CVXPYgen peers only: they solve "
             "our MPC's own QPs): native runs of the same scenarios with law.shadow = 1, every QP of the closed loop "
             "also solved by our Fast MPC at its reference settings (tol 1e-10), compared where both solved it (the native runs "
             "fly their own closed loop, on the host's measured delay, so their QPs are not the QEMU runs' and their count "
             "may differ); the LQ + command governor solves "
             "another, much smaller problem and cw_target (CW targeting and a glideslope) none at all (their rows are "
             "repeated under each horizon; they have none). Iterations: interior-point iterations (QOCOGEN, our "
             "rendezvous), ADMM iterations (OSQP), the governor's; our approach and docking QPs are solved by a dual "
             "active-set method, whose work is its row changes (rows entering or leaving the active set). Δv: the mean over "
             "the scenarios of the closed loop's realised Δv in that phase (and the whole run), flown with that "
             "horizon set. Safe actions: steps where the law commanded zero thrust because its solver did not "
             "report solved (or the harness did). A law marked 'first S s only' flew only that much of each scenario "
             "(too slow to fly it whole under emulation): its Δv is that of those seconds.</p>"]
    if (base / "peers-instructions.png").exists():
        parts.append("<img src='peers-instructions.png' alt='instructions per step, per law, phase and horizon' "
                     "style='max-width:100%'>")
    for target, g in t.groupby("target", sort=False):
        parts.append(f"<h2>{html.escape(str(target))}</h2>")
        for (phase, N), h in g.groupby(["phase", "N"], sort=False):
            parts.append(f"<h3>{phase}, N = {N}</h3><table><tr>" + "".join(f"<th>{html.escape(c[1])}</th>" for c in cols) + "</tr>")
            for _, r in h.iterrows():
                parts.append("<tr>" + "".join(f"<td>{html.escape(_f(r.get(c[0]), c[2]) if c[0] != 'law' else _law_cell(r))}</td>"
                                              for c in cols) + "</tr>")
            parts.append("</table>")
    if chk is not None and not chk.empty:
        parts.append("<h2>Checks of every law's campaign</h2><p>The ideal Case 1 (CW truth, no noise, impulsive) "
                     "flown natively and twice under QEMU per target: the instructions and the cycle model's cycles of "
                     "every step must repeat exactly.</p><table><tr>" +
                     "".join(f"<th>{html.escape(c)}</th>" for c in chk.columns) + "</tr>")
        for _, r in chk.iterrows():
            parts.append("<tr>" + "".join(f"<td>{html.escape(str(r[c]))}</td>" for c in chk.columns) + "</tr>")
        parts.append("</table>")
    style = ("<style>body{font-family:sans-serif;margin:2em;max-width:1600px}table{border-collapse:collapse;margin-bottom:1em}"
             "td,th{border:1px solid #bbb;padding:2px 6px;text-align:right;font-size:90%}th{background:#eee}"
             "td:first-child{text-align:left}</style>")
    page = base / "peers.html"
    page.write_text(f"<!doctype html><html><head><meta charset='utf-8'><title>Guidance peers</title>{style}</head>"
                    f"<body>{''.join(parts)}</body></html>")
    return page


def summary_lines(t: pd.DataFrame) -> list[str]:
    lines = []
    for target, g in t.groupby("target", sort=False):
        for law, h in g.groupby("law", sort=False):
            if law == OURS:
                continue
            lines.append(f"{target} {law}: instructions per solve ÷ Fast MPC " +
                         ", ".join(f"{r.phase[:4]} N{r.N} {_f(r.insns_ratio)}" for r in h.itertuples()) +
                         "; est. time ÷ Fast MPC " + ", ".join(f"{_f(r.time_ratio)}" for r in h.itertuples()))
    return lines


def main(argv=None) -> int:
    from rvd_pil.bench.campaign import DEFAULT_HORIZONS, HORIZON_SETS

    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.peer_laws", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    ap.add_argument("--laws", default=",".join(DEFAULT_LAWS),
                    help=f"comma-separated peers of {', '.join(LAWS)} (default {','.join(DEFAULT_LAWS)})")
    ap.add_argument("--targets", default="q7s,rpi3")
    ap.add_argument("--full", action="store_true", help="Case 1 and two seeded random starts (the PIL campaign's)")
    ap.add_argument("--no-checks", action="store_true", help="skip the determinism checks of every campaign")
    ap.add_argument("--check-timeout-s", type=float, default=None, metavar="S",
                    help="the peers' determinism checks fly the ideal Case 1 for at most S s of simulated time "
                         "(default: the campaign's for a plug-in law, 3000 s; 0: to docking or the scenario's timeout)")
    ap.add_argument("--out", type=Path, default=paths.reports_root() / "peers")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--horizon-sets", choices=("all", "default"), default="all",
                    help="the campaign's three horizon sets (default) or its default 30/15/12 only")
    a = ap.parse_args(argv)
    horizon_sets = HORIZON_SETS if a.horizon_sets == "all" else (DEFAULT_HORIZONS,)
    laws = [l for l in a.laws.split(",") if l]
    unknown = [l for l in laws if l not in LAWS]
    if unknown:
        print(f"unknown peer(s) {unknown}; known: {', '.join(LAWS)}", file=sys.stderr)
        return 2
    targets = [t for t in a.targets.split(",") if t]
    scenarios = ["case1_vbar", "random:1", "random:2"] if a.full else ["case1_vbar"]
    base = a.out
    base.mkdir(parents=True, exist_ok=True)
    if not a.report_only:
        for law in [OURS, *laws]:
            print(f"== {law}", flush=True)
            rc = run_campaign(law, base / law, targets, scenarios, not a.no_checks, a.horizon_sets,
                              a.check_timeout_s)
            if rc:
                print(f"{law}: campaign failed (exit {rc})", file=sys.stderr)
                return rc
            if law in SAME_QP:
                run_accuracy(law, base / "accuracy" / law, scenarios, horizon_sets)
    t = side_by_side(base, laws)
    if t.empty:
        print("no campaign results", file=sys.stderr)
        return 1
    settings = {"what": f"Targets {', '.join(targets)}; scenarios {', '.join(scenarios)} with the nonlinear truth, J2, "
                        f"drag, thrust and sensor noise (seed 0), finite burns, the control delay of the cycle model; "
                        f"horizon sets {', '.join('/'.join(map(str, h)) for h in horizon_sets)} (rendezvous/approach/docking)."}
    t.to_csv(base / "peers.csv", index=False)
    (base / "peers.json").write_text(json.dumps({"settings": settings, "rows": json.loads(t.to_json(orient="records"))}, indent=1))
    chk = checks_table(base, laws)
    if not chk.empty:
        chk.to_csv(base / "peers-checks.csv", index=False)
    plot_instructions(base, t, laws)
    page = write_page(base, t, laws, settings, chk)
    for line in summary_lines(t):
        print(line)
    for _, r in chk[chk["result"] != "PASS"].iterrows() if not chk.empty else ():
        print(f"check {r['result']}: {r['law']} {r['target']}: {r['what was checked']}: {r['figure']}")
    print(f"report: {page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
