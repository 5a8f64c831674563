"""The user's three asks as measured studies: speed against error, numerical stability on
hard cases, and the cost of modelling more than the scene needs. Each returns records
(JSON-serialisable) and writes CSV / Markdown (and a plot) into an output folder.
"""
from __future__ import annotations

import csv
import itertools
import math
import statistics
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.settings import Settings, load_settings
from cito_ros.studies import benchmarks, sweep
from cito_ros.studies.cases import Case, load_cases, run_case

MODELS = ("cccm", "scm", "vscm")


def _median(values: Iterable[float | None]) -> float | None:
    present = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(present) if present else None


def write_csv(path: Path, records: list[dict[str, Any]]) -> Path:
    keys = list(dict.fromkeys(k for r in records for k in r if not isinstance(r[k], (dict, list))))
    with open(path, "w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=keys, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(records)
    return path


def _fmt(value: float | int | None, scale: float = 1.0, digits: int = 2) -> str:
    if value is None:
        return "-"
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    return f"{value * scale:.{digits}f}"


# ---------------------------------------------------------------------------------- hard cases

def hard_case(case: Case, model: str, repeat: int, settings: Settings) -> dict[str, Any]:
    """One hard case with one model; with repeat >= 2 run again, and `identical_on_repeat` says whether
    the plans were bit-identical."""
    record, result = run_case(case, model, settings)
    if repeat >= 2:
        again, second = run_case(case, model, settings)
        record["identical_on_repeat"] = (result is None and second is None) or (
            result is not None and second is not None
            and np.array_equal(result.knot_torques_Nm, second.knot_torques_Nm)
            and again["position_error_m"] == record["position_error_m"])
    return record


def hard_cases(models: Iterable[str] = MODELS, names: Iterable[str] | None = None, repeat: int = 1, *,
               workers: int | None = None, address: str | None = None, out: Path | None = None) -> list[dict[str, Any]]:
    """The cases of config/hard_cases.yaml with each contact model, as a sweep (cito_ros.studies.sweep)."""
    cases = load_cases()
    settings = sweep.settings_for(load_settings(), workers)
    jobs = [(f"{name}-{model}", hard_case, (cases[name], model, repeat, settings))
            for name in (names or cases) for model in models]
    return sweep.run_sweep(jobs, workers=workers, address=address, out=out, label="hard cases")


def hard_report(records: list[dict[str, Any]]) -> str:
    records, failed = sweep.split_failures(records)
    models = list(dict.fromkeys(r["contact_model"] for r in records))
    cases = list(dict.fromkeys(r["case"] for r in records))
    by = {(r["case"], r["contact_model"]): r for r in records}
    lines = ["### Per case: status (success), executed error / planned error (cm), solve time (s)", "",
             "| case | " + " | ".join(m.upper() for m in models) + " |", "|---|" + "---|" * len(models)]
    for case in cases:
        cells = []
        for model in models:
            r = by.get((case, model))
            if r is None:
                cells.append("")
                continue
            mark = "ok" if r["success"] else "fail"
            cells.append(f"{r['status']} ({mark}) {_fmt(r['position_error_m'], 100, 1)} / "
                         f"{_fmt(r['planned_position_error_m'], 100, 1)}, {r['solve_time_s']:.1f}")
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    lines += ["", "### Per contact model", "",
              "| model | success | median executed error (cm) | median planned error (cm) | median solve time (s) "
              "| all finite | MuJoCo warnings | identical on repeat |", "|---|---|---|---|---|---|---|---|"]
    for model in models:
        rows = [r for r in records if r["contact_model"] == model]
        posed = [r for r in rows if r["status"] != "invalid_request"]
        repeats = [r["identical_on_repeat"] for r in rows if "identical_on_repeat" in r]
        warned = sum(1 for r in rows if r.get("warnings"))
        lines.append(
            f"| {model.upper()} | {sum(r['success'] for r in rows)}/{len(rows)} | "
            f"{_fmt(_median(r['position_error_m'] for r in posed), 100)} | "
            f"{_fmt(_median(r['planned_position_error_m'] for r in posed), 100)} | "
            f"{_fmt(_median(r['solve_time_s'] for r in posed))} | "
            f"{'yes' if all(r['finite'] for r in rows) else 'NO'} | {warned} | "
            f"{('yes' if all(repeats) else 'NO') if repeats else 'not run'} |")
    invalid = sorted({(r["case"], r["message"]) for r in records if r["status"] == "invalid_request"})
    if invalid:
        lines += ["", "Cases that cannot be posed (status invalid_request, no exception):"]
        lines += [f"- {case}: {message}" for case, message in invalid]
    lines += [f"- {r['key']}: failed: {r['error']}" for r in failed]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- speed vs error

@dataclass(frozen=True)
class Variant:
    """A solver-effort setting: planner parameter overrides (dotted names) and case changes."""

    name: str
    overrides: Mapping[str, Any]
    scene: str | None = None
    knots: int | None = None
    models: tuple[str, ...] = MODELS


VARIANTS = (
    Variant("default", {}),
    Variant("no script", {"stages.scripted.enabled": False}),
    Variant("max_iter 10", {"solver.max_iter": 10, "stages.discovery.max_iter": 10}),
    Variant("one start", {"stages.starts": [0.3]}),
    Variant("least squares", {"stages.solver": "least_squares"}),
    Variant("ipopt", {"stages.solver": "ipopt"}),
    Variant("ipopt gauss-newton", {"stages.solver": "ipopt", "stages.ipopt_curvature": "gauss_newton"}),
    Variant("paper problem", {"pipeline": "paper"}),
    # iLQR's stages take the knot-wise expansion, not the gradient: the knot-restart differences change
    # only the IPOPT and least-squares paths, so they are compared on the paper's problem
    Variant("paper problem, forward differences", {"pipeline": "paper", "gradient.method": "forward_differences"}),
    Variant("timestep 2 ms", {}, scene="fine_step"),
    Variant("N = 10", {}, knots=10),
    Variant("N = 40", {}, knots=40),
)
SWEEP_CASES = (
    Case("paper beta=5", beta=5.0), Case("paper beta=6", beta=6.0), Case("paper beta=7", beta=7.0),
    Case("target (+0.20, +0.10)", beta=6.0, push=(0.20, 0.10, 0.0)),
    Case("target (+0.22, -0.08)", beta=6.0, push=(0.22, -0.08, 0.0)),
)


def variant_case(variant: Variant, case: Case, model: str, settings: Settings) -> dict[str, Any]:
    """One case with one model under a variant's settings."""
    run = replace(case, scene=variant.scene or case.scene, knots=variant.knots or case.knots)
    record, _ = run_case(run, model, settings.with_overrides(variant.overrides))
    return {"variant": variant.name, **record}


def speed_vs_error(variants: Iterable[Variant] = VARIANTS, cases: Iterable[Case] = SWEEP_CASES,
                   models: Iterable[str] = MODELS, *, workers: int | None = None, address: str | None = None,
                   out: Path | None = None) -> list[dict[str, Any]]:
    """Every variant, model and case, as a sweep (cito_ros.studies.sweep); solve times are those of one task."""
    settings = sweep.settings_for(load_settings(), workers)
    jobs = [(f"{v.name}-{m}-{c.name}", variant_case, (v, c, m, settings))
            for v in variants for m in models if m in v.models for c in cases]
    return sweep.run_sweep(jobs, workers=workers, address=address, out=out, label="speed vs error")


def speed_vs_error_summary(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (contact model, variant): medians over the cases, and whether it is on the model's
    Pareto front of (median solve time, median executed error) and of (time, median planned error).
    Failed solves (cito_ros.studies.sweep) and requests that cannot be posed (a variant's scene or knots may
    make one impossible) are left out; `cases` counts the rest."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in sweep.split_failures(records)[0]:
        if r["status"] == "invalid_request":
            continue
        groups.setdefault((r["contact_model"], r["variant"]), []).append(r)
    rows = [{"contact_model": model, "variant": variant,
             "median_solve_time_s": _median(r["solve_time_s"] for r in rs),
             "median_planned_position_error_m": _median(r["planned_position_error_m"] for r in rs),
             "median_position_error_m": _median(r["position_error_m"] for r in rs),
             "success_rate": sum(r["success"] for r in rs) / len(rs), "cases": len(rs)}
            for (model, variant), rs in groups.items()]
    for row in rows:
        peers = [p for p in rows if p["contact_model"] == row["contact_model"]]
        for error, flag in (("median_position_error_m", "pareto"), ("median_planned_position_error_m", "pareto_planned")):
            row[flag] = row[error] is not None and not any(
                p is not row and p[error] is not None
                and p["median_solve_time_s"] <= row["median_solve_time_s"] and p[error] <= row[error]
                and (p["median_solve_time_s"] < row["median_solve_time_s"] or p[error] < row[error]) for p in peers)
    return rows


def speed_vs_error_table(summary: list[dict[str, Any]], failed: list[dict[str, Any]] = ()) -> str:
    lines = ["| contact model | setting | median solve time (s) | median executed error (cm) | "
             "median planned error (cm) | success | Pareto (executed / planned) |", "|---|---|---|---|---|---|---|"]
    for row in sorted(summary, key=lambda r: (r["contact_model"], r["median_solve_time_s"])):
        front = " / ".join("*" if row[flag] else "-" for flag in ("pareto", "pareto_planned"))
        lines.append(f"| {row['contact_model'].upper()} | {row['variant']} | {_fmt(row['median_solve_time_s'])} | "
                     f"{_fmt(row['median_position_error_m'], 100)} | {_fmt(row['median_planned_position_error_m'], 100)} "
                     f"| {row['success_rate']:.0%} | {front} |")
    lines += [f"- {r['key']}: failed: {r['error']}" for r in failed]
    return "\n".join(lines) + "\n"


def speed_vs_error_plot(summary: list[dict[str, Any]], path: Path) -> Path:
    """Median solve time against median executed and planned error: a colour per contact model, a
    marker per setting (named once, in the legend: a dozen settings per model crowd the fast corner,
    where text labels overlap), each model's Pareto front circled and joined."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    colors = {"cccm": "tab:red", "scm": "tab:orange", "vscm": "tab:blue"}
    variants = list(dict.fromkeys(r["variant"] for r in sorted(summary, key=lambda r: r["median_solve_time_s"])))
    markers = dict(zip(variants, itertools.cycle("os^vDPX*<>hpd")))
    figure, axes = plt.subplots(1, 2, figsize=(14, 5.6), sharex=True)
    for axis, key, flag, title in ((axes[0], "median_position_error_m", "pareto",
                                    "executed error (virtual force off)"),
                                   (axes[1], "median_planned_position_error_m", "pareto_planned",
                                    "planned error (virtual force on)")):
        for model in MODELS:
            rows = sorted((r for r in summary if r["contact_model"] == model and r[key] is not None),
                          key=lambda r: r["median_solve_time_s"])
            for r in rows:
                axis.scatter(r["median_solve_time_s"], max(r[key], 1e-5) * 100, color=colors[model],
                             marker=markers[r["variant"]], s=44, zorder=3, alpha=0.85)
            front = [r for r in rows if r[flag]]
            axis.step([r["median_solve_time_s"] for r in front],
                      [max(r[key], 1e-5) * 100 for r in front], where="post", color=colors[model], alpha=0.6,
                      linewidth=1.5)
            axis.scatter([r["median_solve_time_s"] for r in front], [max(r[key], 1e-5) * 100 for r in front],
                         facecolors="none", edgecolors="black", s=130, linewidths=1.2, zorder=4)
        axis.set_xscale("log")
        axis.set_yscale("log")
        axis.set_xlabel("median solve time (s)")
        axis.set_ylabel(f"median {title} (cm)")
        axis.set_title(f"speed against {title}")
        axis.grid(True, which="both", alpha=0.3)
    handles = [Line2D([], [], color=colors[m], marker="o", linestyle="", label=m.upper()) for m in MODELS]
    handles += [Line2D([], [], color="gray", marker=markers[v], linestyle="", label=v) for v in variants]
    handles.append(Line2D([], [], marker="o", markerfacecolor="none", markeredgecolor="black", markersize=11,
                          linestyle="", label="the model's Pareto front\n(time vs this error)"))
    figure.legend(handles=handles, loc="center right", fontsize=8, frameon=False)
    figure.tight_layout(rect=(0, 0, 0.83, 1))
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


# ------------------------------------------------------------------------------- collisions

def scene_case(case: Case, model: str, settings: Settings) -> dict[str, Any]:
    record, _ = run_case(case, model, settings)
    return {"scene": case.scene, **record}


def collision_cost(repeats: int = 50, *, betas: tuple[int, ...] = (5, 6, 7), workers: int | None = None,
                   address: str | None = None, out: Path | None = None) -> dict[str, Any]:
    """The minimal scene (the pair list) against every geom pair colliding: rollout and gradient
    speed (in this process, first), and solve time and errors on the paper's cases of `betas` with
    each model (a sweep)."""
    settings = load_settings()
    scenes = {"minimal": settings.scene.source, "all collisions": "all_collisions"}
    timing = {}
    for label, scene_name in scenes.items():
        posed = build_problem(settings, PushRequest("vscm", scene=scene_name))
        scene, simulator, state, problem = posed.scene, posed.simulator, posed.initial_state, posed.problem
        controls = simulator.step_controls(simulator.knot_controls(benchmarks.benchmark_torques(simulator),
                                                                   np.full(simulator.n_knots, 100.0)))[None]
        calls = itertools.count()

        def gradient():  # a new point per call: no cache hits
            problem.derivatives(problem.initial_guess + 1e-3 * next(calls) * problem.scale)

        timing[label] = {
            "rollout_ms": benchmarks.median_ms(lambda: simulator.rollout_batch(state[None], controls), repeats),
            "gradient_ms": benchmarks.median_ms(gradient, max(5, repeats // 5)),
            "geoms_in_broad_phase": int(np.count_nonzero(scene.model.geom_contype | scene.model.geom_conaffinity)),
            "explicit_pairs": int(scene.model.npair),
        }
    cases = [Case(f"paper beta={b}", beta=float(b), scene=s) for s in scenes.values() for b in betas]
    solve_settings = sweep.settings_for(settings, workers)
    jobs = [(f"{case.scene}-{model}-{case.name}", scene_case, (case, model, solve_settings))
            for case in cases for model in MODELS]
    records, failed = sweep.split_failures(sweep.run_sweep(jobs, workers=workers, address=address, out=out,
                                                           label="collisions"))
    for label, scene_name in scenes.items():
        rows = [r for r in records if r["scene"] == scene_name]
        timing[label].update(
            median_solve_time_s=_median(r["solve_time_s"] for r in rows),
            median_planned_position_error_m=_median(r["planned_position_error_m"] for r in rows),
            median_position_error_m=_median(r["position_error_m"] for r in rows),
            successes=sum(r["success"] for r in rows), cases=len(rows))
    return {"scenes": timing, "runs": records, "failures": failed}


def collision_report(result: dict[str, Any]) -> str:
    scenes = result["scenes"]
    minimal, full = scenes["minimal"], scenes["all collisions"]
    lines = ["| | minimal (pair list) | all collisions | all / minimal |", "|---|---|---|---|"]
    for key, label, scale in (("geoms_in_broad_phase", "geoms in the broad phase", 1),
                              ("explicit_pairs", "explicit pairs", 1),
                              ("rollout_ms", "1 s rollout (ms, median)", 1),
                              ("gradient_ms", "full VSCM gradient (ms, median)", 1),
                              ("median_solve_time_s", "median solve time, paper cases (s)", 1),
                              ("median_position_error_m", "median executed error (cm)", 100),
                              ("median_planned_position_error_m", "median planned error (cm)", 100)):
        a, b = minimal[key], full[key]
        ratio = f"{b / a:.2f}" if isinstance(a, (int, float)) and a and b is not None else "-"
        lines.append(f"| {label} | {_fmt(a, scale)} | {_fmt(b, scale)} | {ratio} |")
    lines.append(f"| task successes | {minimal['successes']}/{minimal['cases']} | {full['successes']}/{full['cases']} | |")
    lines += [f"- {r['key']}: failed: {r['error']}" for r in result["failures"]]
    return "\n".join(lines) + "\n"
