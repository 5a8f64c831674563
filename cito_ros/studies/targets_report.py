"""`cito-bench targets`' report: success rates, errors and solve times per model, by reach zone, by the face a goal
needs and by the pushes a plan makes, the refusals apart, the perturbed pairs' stability; its markdown, CSV, JSON and
plot (cito_ros.studies.targets_plot). ROS-free."""
from __future__ import annotations

import csv
import statistics
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from cito_ros.planner.results import ZONES, phase_table, zone
from cito_ros.planner.task import quarter_turns
from cito_ros.studies.targets import FACES, OFFSET_AMPLITUDE_RAD


def offset_verdicts(record: dict[str, Any]) -> list[bool]:
    """Whether each of a record's executions with the reference off (offset_tracked_errors_m) ends within
    2 cm of the goal."""
    return [error < 0.02 for error in record.get("offset_tracked_position_errors_m", ())]


def _median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def _percentile(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def perturbed_pairs(records: list[dict[str, Any]], request: str = "goal") -> Iterator[tuple[dict, dict]]:
    """(perturbed record, its unperturbed one) for every perturbed record whose request (`request` names
    the field that tells the requests apart) was also solved unperturbed with the same model."""
    base = {(r[request], r["contact_model"]): r for r in records if r["perturbation"] == "none"}
    for r in records:
        if r["perturbation"] != "none" and (r[request], r["contact_model"]) in base:
            yield r, base[(r[request], r["contact_model"])]


def stable(perturbed: dict[str, Any], unperturbed: dict[str, Any]) -> bool:
    """Item 5 on one pair: the same verdict, the executed errors within 1 cm."""
    return perturbed["success"] == unperturbed["success"] and \
        abs(perturbed["position_error_m"] - unperturbed["position_error_m"]) <= 0.01


def stability(records: list[dict[str, Any]], request: str = "goal") -> dict[str, Any]:
    """Per model and perturbation: how often the verdict matched the unperturbed plan's, and how far the
    executed errors moved. `request` names the field that tells the requests apart."""
    out: dict[str, Any] = {}
    for r, b in perturbed_pairs(records, request):
        entry = out.setdefault(r["contact_model"], {}).setdefault(r["perturbation"], {"pairs": 0, "same_verdict": 0,
                                                                                     "within_1cm": 0, "max_change_m": 0.0})
        change = abs(r["position_error_m"] - b["position_error_m"])
        entry["pairs"] += 1
        entry["same_verdict"] += r["success"] == b["success"]
        entry["within_1cm"] += change <= 0.01
        entry["max_change_m"] = max(entry["max_change_m"], change)
    return out


def goal_distance_m(record: dict[str, Any]) -> float:
    """A record's goal distance from the arm base (horizontal; the base is the world origin)."""
    return float(np.hypot(*record["target_position_m"][:2]))


def steady_reach_m(record: dict[str, Any]) -> float:
    """The steady push reach a record's goal was judged against (its distance plus its margin)."""
    return goal_distance_m(record) + record["steady_reach_margin_m"]


def by_zone(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per model and reach zone (cito_ros.planner.results.zone: inside the steady push reach computed for each
    request, or beyond it): successes, executed errors, solve times, and the perturbed pairs that kept the
    verdict and moved at most 1 cm."""
    plain = [r for r in records if r["perturbation"] == "none"]
    pairs = list(perturbed_pairs(records))
    out: dict[str, Any] = {}
    for model in dict.fromkeys(r["contact_model"] for r in plain):
        for name in ZONES:
            rows = [r for r in plain if r["contact_model"] == model and zone(r["steady_reach_margin_m"]) == name]
            chosen = [(p, b) for p, b in pairs if p["contact_model"] == model
                      and zone(b["steady_reach_margin_m"]) == name]
            times, errors = [r["solve_time_s"] for r in rows], [r["position_error_m"] for r in rows]
            out.setdefault(model, {})[name] = {
                "goals": len(rows), "successes": sum(r["success"] for r in rows),
                "executed_position_error_m": {"median": statistics.median(errors) if errors else None,
                                              "p90": _percentile(errors, 90)},
                "solve_time_s": {"median": statistics.median(times) if times else None, "p90": _percentile(times, 90)},
                "perturbed_pairs": len(chosen), "pairs_stable": sum(stable(p, b) for p, b in chosen)}
    reaches = sorted({round(steady_reach_m(r), 4) for r in plain})
    return {"steady_reach_m": reaches, "models": out}


def by_face(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per model and face the goal needs (face_needed): successes, executed errors and solve times."""
    plain = [r for r in records if r["perturbation"] == "none"]
    out: dict[str, Any] = {}
    for model in dict.fromkeys(r["contact_model"] for r in plain):
        for face in FACES:
            chosen = [r for r in plain if r["contact_model"] == model and r.get("face", FACES[0]) == face]
            if not chosen:
                continue
            rows, refused = [r for r in chosen if not r.get("refused")], [r for r in chosen if r.get("refused")]
            times = [r["solve_time_s"] for r in rows]
            positions, orientations = [r["position_error_m"] for r in rows], [r["orientation_error_rad"] for r in rows]
            out.setdefault(model, {})[face] = {
                "goals": len(chosen), "successes": sum(r["success"] for r in rows), "refusals": len(refused),
                "refusal_time_s_max": max((r["refusal_time_s"] for r in refused), default=None),
                "executed_position_error_m": {"median": _median(positions), "p90": _percentile(positions, 90)},
                "executed_orientation_error_rad": {"median": _median(orientations),
                                                   "p90": _percentile(orientations, 90)},
                "solve_time_s": {"median": _median(times), "p90": _percentile(times, 90)}}
    return out


def by_pushes(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per model, reach zone and the pushes its plan makes (cito_ros.planner.sequence): successes, executed errors,
    solve times and the slowest success, of the posed goals."""
    posed = [r for r in records if r["perturbation"] == "none" and not r.get("refused")]
    groups: dict[tuple, list] = {}
    for r in sorted(posed, key=lambda r: (ZONES.index(zone(r["steady_reach_margin_m"])), r.get("pushes", 1))):
        groups.setdefault((r["contact_model"], zone(r["steady_reach_margin_m"]), r.get("pushes", 1)), []).append(r)
    return {model: [{"zone": name, "pushes": pushes, "goals": len(rows), "successes": sum(r["success"] for r in rows),
                     "error_m": [_median([r["position_error_m"] for r in rows]),
                                 _percentile([r["position_error_m"] for r in rows], 90)],
                     "solve_s": [_median([r["solve_time_s"] for r in rows]),
                                 _percentile([r["solve_time_s"] for r in rows], 90)],
                     "slowest_success_s": max((r["solve_time_s"] for r in rows if r["success"]), default=None)}
                    for (m, name, pushes), rows in groups.items() if m == model]
            for model in dict.fromkeys(r["contact_model"] for r in posed)}


def report(records: list[dict[str, Any]], refused: list[str], where: dict[str, Any] | None = None) -> dict[str, Any]:
    """Per model: success rates, error and time statistics of the unperturbed plans, and the stability
    of the perturbed ones; the same split by reach zone (by_zone) and by the face the goal needs (by_face);
    `where`, the goals' region (region), is drawn in the plot. A failed solve (an exception, a lost worker)
    counts as no success; a refused goal (the planner's check, its time and reason kept) counts as a goal without
    one, apart from the statistics of the plans."""
    failed = [r for r in records if r.get("failed")]
    refusals = [r for r in records if r.get("refused") and r["perturbation"] == "none"]
    everything = [r for r in records if not r.get("failed")]
    records = [r for r in everything if not r.get("refused")]
    per_model = {}
    plain = [r for r in records if r["perturbation"] == "none"]
    for model in dict.fromkeys(r["contact_model"] for r in plain):
        rows = [r for r in plain if r["contact_model"] == model]
        successes = [r for r in rows if r["success"]]
        executed = [r["position_error_m"] for r in rows]
        tracked_close = [abs(r["tracked_position_error_m"] - r["position_error_m"]) <= 0.02 for r in successes]
        offset_ok = [offset_verdicts(r) for r in successes]
        times = [r["solve_time_s"] for r in rows]
        lost = [r for r in failed if f"-{model}-none" in r["key"]]
        refused_here = [r for r in refusals if r["contact_model"] == model]
        goals = len(rows) + len(lost) + len(refused_here)
        turned = [r for r in rows if quarter_turns(r.get("requested_yaw_rad", r["target_yaw_rad"]), r["target_yaw_rad"])]
        per_model[model] = {
            "goals": goals,
            # goals whose yaw was taken as the cube's equivalent nearer its start (task.nearest_equivalent_yaw): none
            # of these would succeed with a marked cube, whose frame tells its quarter turns apart
            "equivalent_yaw_goals_successes": [len(turned), sum(r["success"] for r in turned)],
            "failed_solves": len(lost),
            "refusals": len(refused_here),
            "refusal_time_s_max": max((r["refusal_time_s"] for r in refused_here), default=None),
            "success_rate": len(successes) / goals,
            "planned_success_rate": sum(r["planned_success"] for r in rows) / len(rows),
            "max_joint_speed_ratio": max(r["max_joint_speed_ratio"] for r in rows),
            "executed_position_error_m": {"median": statistics.median(executed),
                                          "p90": _percentile(executed, 90)},
            "executed_orientation_error_rad": {"median": statistics.median(r["orientation_error_rad"] for r in rows),
                                               "p90": _percentile([r["orientation_error_rad"] for r in rows], 90)},
            "tracked_position_error_m": {"median": statistics.median(r["tracked_position_error_m"] for r in rows),
                                         "p90": _percentile([r["tracked_position_error_m"] for r in rows], 90)},
            "tracked_within_2cm_of_executed_in_successes": (sum(tracked_close) / len(tracked_close)
                                                            if tracked_close else None),
            # of the successes' executions with the reference off (OFFSETS each): how many end within 2 cm,
            # and how many successes do so under every offset
            "offset_executions_within_2cm": [sum(map(sum, offset_ok)), sum(map(len, offset_ok))],
            "successes_within_2cm_under_every_offset": [sum(bool(ok) and all(ok) for ok in offset_ok),
                                                        sum(bool(ok) for ok in offset_ok)],
            "solve_time_s": {"median": statistics.median(times), "p90": _percentile(times, 90), "max": max(times)},
            "iterations": {"median": statistics.median(r["iterations"] for r in rows),
                           "p90": _percentile([r["iterations"] for r in rows], 90)},
        }
    phases = phase_table({model.upper(): [r for r in plain if r["contact_model"] == model] for model in per_model})
    return {"models": per_model, "stability": stability(records), "phases": phases,
            "by_zone": by_zone(records), "by_face": by_face(everything), "by_pushes": by_pushes(records),
            "region": where, "refused_draws": len(refused),
            "refused_reasons": sorted(set(refused))[:5],
            "refusal_examples": [r["refused"] for r in refusals][:3],
            "failures": [(r["key"], r["error"]) for r in failed]}


def markdown(summary: dict[str, Any]) -> str:
    def cm(value):
        return "-" if value is None else f"{100 * value:.2f}"

    lines = ["| model | success | planned success | executed error median / p90 (cm) | executed orientation "
             "median / p90 (rad) | tracked error median / p90 (cm) | tracked within 2 cm of executed (successes) "
             f"| reference off by up to {OFFSET_AMPLITUDE_RAD:g} rad: executions / successes within 2 cm "
             "| max joint speed / limit | solve time median / p90 / max (s) | iterations median / p90 |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for model, m in summary["models"].items():
        e, o, tr = m["executed_position_error_m"], m["executed_orientation_error_rad"], m["tracked_position_error_m"]
        t, it = m["solve_time_s"], m["iterations"]
        close = m["tracked_within_2cm_of_executed_in_successes"]
        executions, sturdy = m["offset_executions_within_2cm"], m["successes_within_2cm_under_every_offset"]
        lines.append(f"| {model.upper()} | {m['success_rate']:.0%} ({round(m['success_rate'] * m['goals'])}/"
                     f"{m['goals']}) | {m['planned_success_rate']:.0%} | {cm(e['median'])} / {cm(e['p90'])} | "
                     f"{o['median']:.3f} / {o['p90']:.3f} | {cm(tr['median'])} / {cm(tr['p90'])} | "
                     f"{'-' if close is None else f'{close:.0%}'} | {executions[0]}/{executions[1]}, "
                     f"{sturdy[0]}/{sturdy[1]} | {m['max_joint_speed_ratio']:.2f} | "
                     f"{t['median']:.2f} / {t['p90']:.2f} / {t['max']:.2f} | {it['median']:.0f} / {it['p90']:.0f} |")
    if summary["stability"]:
        lines += ["", stability_table(summary["stability"])]
    lines += ["", zone_table(summary["by_zone"]), "", face_table(summary["by_face"]), "",
              pushes_table(summary["by_pushes"])]
    lines += ["", "Where the solve time went (cito_ros.planner.results.PHASE_METRICS):", "", summary["phases"]]
    for key, error in summary["failures"]:
        lines.append(f"- {key}: failed: {error}")
    for model, m in summary["models"].items():
        turned, won = m.get("equivalent_yaw_goals_successes", (0, 0))
        if turned:
            lines.append(f"{model.upper()}: {turned} posed goal(s) aimed at a yaw a quarter turn or more from the one "
                         f"drawn (the same pose of the cube, nearer its start: cito_ros.planner.task), {won} of them "
                         f"succeeded; with a marked cube none of those {won} would")
        if m["refusals"]:
            lines.append(f"{model.upper()}: {m['refusals']} goal(s) refused, the slowest answer in "
                         f"{m['refusal_time_s_max']:.3f} s (e.g. {summary['refusal_examples'][0]})")
    lines.append(f"Draws refused by the planner's checks and drawn again: {summary['refused_draws']}"
                 + (f" (e.g. {summary['refused_reasons'][0]})" if summary["refused_reasons"] else ""))
    return "\n".join(lines) + "\n"


def stability_table(by_model: dict[str, Any]) -> str:
    """Markdown of `stability`."""
    lines = ["| model | perturbation | same verdict | executed error within 1 cm | largest change (cm) |",
             "|---|---|---|---|---|"]
    for model, by in by_model.items():
        for name, s in by.items():
            lines.append(f"| {model.upper()} | {name} | {s['same_verdict']}/{s['pairs']} | "
                         f"{s['within_1cm']}/{s['pairs']} | {100 * s['max_change_m']:.2f} |")
    return "\n".join(lines)


def zone_table(split: dict[str, Any]) -> str:
    """Markdown of `by_zone`: one table per zone."""
    reaches = ", ".join(f"{r:.3f}" for r in split["steady_reach_m"])
    lines = []
    for name, title in (("steady", f"Goals inside the steady push reach ({reaches} m from the arm base)"),
                        ("strike", "Goals beyond it, reached only by a strike (best effort)")):
        lines += [f"{title}:", "", "| model | success | executed error median / p90 (cm) | solve median / p90 (s) "
                  "| perturbed pairs stable |", "|---|---|---|---|---|"]
        for model, entries in split["models"].items():
            entry = entries[name]
            t, e = entry["solve_time_s"], entry["executed_position_error_m"]
            times = "-" if t["median"] is None else f"{t['median']:.2f} / {t['p90']:.2f}"
            errors = "-" if e["median"] is None else f"{100 * e['median']:.2f} / {100 * e['p90']:.2f}"
            lines.append(f"| {model.upper()} | {entry['successes']}/{entry['goals']} | {errors} | {times} | "
                         f"{entry['pairs_stable']}/{entry['perturbed_pairs']} |")
        lines.append("")
    return "\n".join(lines).rstrip()


def face_table(split: dict[str, Any]) -> str:
    """Markdown of `by_face`."""
    def pair(entry, scale: float, digits: int) -> str:
        if entry["median"] is None:
            return "-"
        return f"{scale * entry['median']:.{digits}f} / {scale * entry['p90']:.{digits}f}"

    lines = ["By the face of the cube a push towards the goal needs (near: within 45 degrees of straight away from "
             "the arm; far: a pull back):", "", "| model | face | success | refused (slowest, s) | executed error "
             "median / p90 (cm) | orientation error median / p90 (rad) | solve median / p90 (s) |",
             "|---|---|---|---|---|---|---|"]
    for model, faces in split.items():
        for face, entry in faces.items():
            slowest = entry["refusal_time_s_max"]
            lines.append(f"| {model.upper()} | {face} | {entry['successes']}/{entry['goals']} | {entry['refusals']}"
                         + ("" if slowest is None else f" ({slowest:.3f})") + " | "
                         f"{pair(entry['executed_position_error_m'], 100, 2)} | "
                         f"{pair(entry['executed_orientation_error_rad'], 1, 3)} | "
                         f"{pair(entry['solve_time_s'], 1, 2)} |")
    return "\n".join(lines)


def pushes_table(split: dict[str, Any]) -> str:
    """Markdown of `by_pushes`."""
    lines = ["By reach zone and the pushes a plan makes (two: across the near face's normal, then along it; "
             "cito_ros.planner.sequence):", "", "| model | zone | pushes | success | executed error median / p90 "
             "(cm) | solve median / p90 (s) | slowest success (s) |", "|---|---|---|---|---|---|---|"]
    for model, rows in split.items():
        for e in rows:
            slowest = "-" if e["slowest_success_s"] is None else f"{e['slowest_success_s']:.2f}"
            lines.append(f"| {model.upper()} | {'inside the steady reach' if e['zone'] == ZONES[0] else 'beyond'} | "
                         f"{e['pushes']} | {e['successes']}/{e['goals']} | {100 * e['error_m'][0]:.2f} / "
                         f"{100 * e['error_m'][1]:.2f} | {e['solve_s'][0]:.2f} / {e['solve_s'][1]:.2f} | {slowest} |")
    return "\n".join(lines)


def write_outputs(records: list[dict[str, Any]], summary: dict[str, Any], out: Path) -> list[Path]:
    import json

    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "targets_runs.csv", out / "targets.md", out / "targets.json", out / "targets.png"]
    keys = list(dict.fromkeys(k for r in records for k in r if not isinstance(r[k], (dict, list))))
    with open(paths[0], "w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=keys, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(records)
    paths[1].write_text(markdown(summary))
    paths[2].write_text(json.dumps({"summary": summary, "runs": records}, indent=1))
    from cito_ros.studies.targets_plot import plot  # matplotlib only where a report is written

    plot(records, paths[3], summary.get("region"))
    return paths
