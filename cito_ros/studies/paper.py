"""The paper's nine cases (3 contact models x beta 5, 6, 7): Tables I-IV side by side with the paper's,
plus the executed error (Table V), and the plans of those cases and of the first targets goals by hash.
ROS-free; the cases run as a sweep (cito_ros.studies.sweep).
"""
from __future__ import annotations

import csv
import statistics
from pathlib import Path

import numpy as np

from cito_ros.planner.plan import plan_push
from cito_ros.planner.results import phase_table
from cito_ros.settings import Settings, load_settings
from cito_ros.studies import sweep
from cito_ros.studies.targets import PERTURBATIONS, plan_perturbed
from cito_ros.studies.targets_report import stability, stability_table

# The paper's Tables I-IV, by initial distance (beta 7, 6, 5) and contact model.
PAPER = {
    "physical_inaccuracy_Ns": {7: (0.1121, 2.0400, 1.2137), 6: (0.0238, 1.4914, 1.2676), 5: (0.0373, 0.0381, 0.0001)},
    "planned_position_error_m": {7: (0.1052, 0.0285, 0.0185), 6: (0.1979, 0.0318, 0.0291), 5: (0.1924, 0.1908, 0.0836)},
    "planned_orientation_error_rad": {7: (0.7067, 0.0238, 0.0533), 6: (0.4022, 0.0586, 0.0654), 5: (0.3475, 0.4547, 0.0415)},
    "solve_time_s": {7: (43.09, 41.07, 111.22), 6: (44.52, 27.87, 16.28), 5: (112.77, 23.98, 60.49)},
}
PAPER_MODELS = ("cccm", "scm", "vscm")
PAPER_DISTANCE = {7: 0.11, 6: 0.17, 5: 0.30}
TABLES = (
    ("I", "Physical inaccuracy", "physical_inaccuracy_Ns", "N s", 4),
    ("II", "Final position error (planned, with the virtual force)", "planned_position_error_m", "m", 4),
    ("III", "Final orientation error (planned)", "planned_orientation_error_rad", "rad", 4),
    ("IV", "Computation time", "solve_time_s", "s", 2),
    ("V", "Executed position error (virtual force off, as on the robot; not in the paper)", "position_error_m",
     "m", 4),
)
PAPER_CASES = tuple((model, beta) for model in PAPER_MODELS for beta in (5, 6, 7))


def paper_case(model: str, beta: int, settings: Settings, perturbation: str = "none") -> dict:
    """One of the nine cases: the plan's summary. A perturbation (cito_ros.studies.targets.PERTURBATIONS) moves
    the default target along x or every start joint angle by a hair."""
    if perturbation == "none":  # the default target, as the paper's tables have always been planned
        result = plan_push(model, beta, settings=settings)
    else:
        x, y = settings.scene.object.position_m
        result = plan_perturbed(model, beta, (x + settings.task.push_distance_m, y), 0.0, settings, perturbation)
    return {"pipeline": settings.pipeline, **result.summary(), "beta": beta, "perturbation": perturbation}


def paper_benchmark(pipeline: str = "paper", *, perturb: bool = False, workers: int | None = None,
                    address: str | None = None, out: Path | None = None) -> list[dict]:
    """Solve the paper's nine cases (3 contact models x beta 5, 6, 7) with a pipeline: 'paper' is
    exactly the paper's problem (Tables I-IV), 'physical' the planner's own; with `perturb`, each case
    again under each perturbation of cito_ros.studies.targets.PERTURBATIONS. A sweep (cito_ros.studies.sweep)."""
    settings = sweep.settings_for(load_settings().with_overrides({"pipeline": pipeline}), workers)
    perturbations = PERTURBATIONS if perturb else ("none",)
    jobs = [(f"{pipeline}-{model}-beta{beta}" + ("" if name == "none" else f"-{name}"), paper_case,
             (model, beta, settings, name)) for name in perturbations for model, beta in PAPER_CASES]
    return sweep.run_sweep(jobs, workers=workers, address=address, out=out, label="paper cases")


def paper_tables(results: list[dict]) -> str:
    """Markdown: Tables I-IV of the paper side by side with ours, plus the executed error, and how the
    perturbed cases' verdicts and errors compare (when there are any)."""
    results, failed = sweep.split_failures(results)
    results = [{"perturbation": "none", **r} for r in results]  # records resumed from before --perturb
    perturbed = stability(results, "beta")
    results = [r for r in results if r["perturbation"] == "none"]
    by_case = {(r["contact_model"], int(r["beta"])): r for r in results}
    lines = []
    for number, title, key, unit, digits in TABLES:
        lines += [f"### Table {number}: {title} [{unit}]", "",
                  "| phi0 (m) | beta | " + " | ".join(f"{m.upper()} ours | {m.upper()} paper" for m in PAPER_MODELS) + " |",
                  "|---|---|" + "---|---|" * len(PAPER_MODELS)]
        for beta in (7, 6, 5):
            cells = []
            for i, model in enumerate(PAPER_MODELS):
                ours = by_case.get((model, beta), {}).get(key)
                paper = PAPER.get(key, {}).get(beta, (None,) * 3)[i]
                cells += [f"{ours:.{digits}f}" if ours is not None else "-",
                          f"{paper:.{digits}f}" if paper is not None else "-"]
            lines.append(f"| {PAPER_DISTANCE[beta]:.2f} | {beta} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["Planned success (the paper's: planned error < 0.1 m): " + ", ".join(
        f"{r['contact_model']} beta={int(r['beta'])}: {'yes' if r['planned_success'] else 'no'}" for r in results),
        "", "Success (executed without the virtual force within 2 cm, 0.15 rad and the joint speed limits): " + ", ".join(
        f"{r['contact_model']} beta={int(r['beta'])}: {'yes' if r['success'] else 'no'} ({r['status']})" for r in results),
        "", f"Median solve time over the {len(results)} cases: {statistics.median(r['solve_time_s'] for r in results):.2f} s", "",
        "Where the solve time went:", "",
        phase_table({model.upper(): [r for r in results if r["contact_model"] == model] for model in PAPER_MODELS})]
    if perturbed:
        lines += ["", "The same requests with a hair of change:", "", stability_table(perturbed)]
    lines += [f"- {r['key']}: failed: {r['error']}" for r in failed]
    return "\n".join(lines)


def write_paper_outputs(results: list[dict], out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    markdown = out_dir / "paper_tables.md"
    markdown.write_text(paper_tables(results))
    table = out_dir / "paper_tables.csv"
    with open(table, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["contact_model", "beta", "perturbation", "initial_distance_m", "status", "success",
                         "planned_success", "iterations", "max_joint_speed_ratio"]
                        + [f"{key}{suffix}" for _, _, key, _, _ in TABLES for suffix in ("", "_paper")])
        for r in sweep.split_failures(results)[0]:
            beta = int(r["beta"])
            row = [r["contact_model"], beta, r.get("perturbation", "none"), r["initial_distance_m"], r["status"],
                   r["success"], r["planned_success"], r["iterations"], r["max_joint_speed_ratio"]]
            for _, _, key, _, _ in TABLES:
                paper = PAPER.get(key, {}).get(beta)
                row += [r[key], "" if paper is None else paper[PAPER_MODELS.index(r["contact_model"])]]
            writer.writerow(row)
    return [markdown, table]


def plan_hash(result) -> str:
    """sha256 of a plan's knot torques and contact controls: equal hashes, the same plan bit for bit."""
    import hashlib

    digest = hashlib.sha256(np.ascontiguousarray(result.knot_torques_Nm, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(result.knot_contact_control, dtype=np.float64).tobytes())
    return digest.hexdigest()


def hashed_paper_case(model: str, beta: int, settings: Settings) -> dict:
    result = plan_push(model, beta, settings=settings)
    return {"hash": plan_hash(result), "success": result.metrics.success,
            "position_error_m": result.metrics.position_error_m}


def hashed_goal(goal, model: str, settings: Settings) -> dict:
    from cito_ros.studies.targets import plan_perturbed

    result = plan_perturbed(model, goal.beta, goal.target_position_m, goal.target_yaw_rad, settings, "none")
    return {"hash": plan_hash(result), "success": result.metrics.success,
            "position_error_m": result.metrics.position_error_m}


def plan_hashes(goals: int = 10, *, workers: int | None = None, address: str | None = None) -> dict[str, dict]:
    """The plans of the paper's nine cases (both pipelines) and of the first `goals` targets goals (seed 0,
    every model), by hash: a change that must not change any plan keeps every hash."""
    from cito_ros.studies.targets import draw_goals

    jobs = []
    for pipeline in ("physical", "paper"):
        settings = sweep.settings_for(load_settings().with_overrides({"pipeline": pipeline}), workers)
        jobs += [(f"{pipeline}-{model}-beta{beta}", hashed_paper_case, (model, beta, settings))
                 for model, beta in PAPER_CASES]
    settings = sweep.settings_for(load_settings(), workers)
    jobs += [(f"goal{goal.index:03d}-{model}", hashed_goal, (goal, model, settings))
             for goal in draw_goals(goals, 0, settings)[0] for model in PAPER_MODELS]
    return {record["key"]: record for record in sweep.run_sweep(jobs, workers=workers, address=address,
                                                                 label="plan hashes")}
