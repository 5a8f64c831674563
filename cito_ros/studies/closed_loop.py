"""`cito-bench closed-loop`: pushes executed open loop and closed loop on simulated robots whose worlds are not
the planner's model. ROS-free: the executor's own code in lock step with the world, no DDS (through the nodes,
`--ros`: cito_ros.cli.closed_loop_ros).

Goals: a `targets` distribution (seeded; cito_ros.studies.targets; forward by default, or any), judged apart by
zone: inside the steady push reach, and beyond it (reached only by a strike: the near-reach share, best effort);
the closed loop's also by the face a push towards the goal needs. Worlds (WORLDS): the
cube's friction x0.5 or x1.5 and its mass x0.5 or x2, each with the cube off by 15 mm along x and along y and
by 0.1 rad (the signs seeded per goal), a camera with 1 mm and 0.01 rad of noise and 30 ms of latency. Each goal
in each world is executed twice (cito_ros.execution.episode):

- open loop: planned from where the planner was told the cube is (the scene's pose), executed by a joint
  trajectory controller with the plan's efforts as feed-forward;
- closed loop: the executor, from what it measures, its feedback policy replanned as it goes, in process, in
  lock step with the world (every replan's compute time passes on the world's clock before it takes effect).

Success is judged at rest on the world's truth: the cube upright (never tipped past its edge) and within 2 cm and
0.15 rad, and within 2 cm and 0.1 rad. Cubes that tipped over are counted in the report.
"""
from __future__ import annotations

import math
import statistics
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from cito_ros.execution.episode import run_closed_loop, run_open_loop
from cito_ros.execution.executor import Ending
from cito_ros.execution.goal import ExecuteGoal
from cito_ros.execution.world import Mismatch, SimulatedWorld
from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene, start_configuration
from cito_ros.planner import push_limits
from cito_ros.planner.builder import warm_up
from cito_ros.planner.results import ZONES, zone
from cito_ros.settings import Settings
from cito_ros.studies.targets import Goal

OFFSET_M, OFFSET_YAW_RAD = 0.015, 0.1
SENSING = dict(pose_noise_m=0.001, yaw_noise_rad=0.01, latency_s=0.03)
WORLDS = tuple(Mismatch(f"friction x{f:g}, mass x{m:g}", f, m, **SENSING) for f in (0.5, 1.5) for m in (0.5, 2.0))
MODES = ("open_loop", "closed_loop")
PLACES = {"short": "short of it", "past": "past it (a pull back needed)", "beside": "beside it",
          "turned": "at the place but turned", "tipped": "tipped over", "refused": "refused, never pushed"}


def world_for(mismatch: Mismatch, goal: Goal) -> Mismatch:
    """The world's cube offset for a goal: 15 mm along x and y and 0.1 rad, the signs seeded by the goal."""
    signs = np.random.default_rng(1000 + goal.index).choice([-1.0, 1.0], 3)
    return replace(mismatch, offset_m=(signs[0] * OFFSET_M, signs[1] * OFFSET_M),
                   offset_yaw_rad=signs[2] * OFFSET_YAW_RAD)


def steady_margin_m(goal: Goal, settings: Settings) -> float:
    """The goal's steady_reach_margin_m in the planner's model (the zone it is judged in), whether or not the planner
    poses a push to it."""
    scene = Scene(contact_model("vscm", settings.contact_models), settings.scene)
    return push_limits.steady_reach_margin_m(scene, scene.initial_state(start_configuration(goal.beta)),
                                             goal.target_position_m)


def poses(goal: Goal, world_mismatch: Mismatch, settings: Settings) -> dict[str, list[float]]:
    """An episode's record of where its cube truly starts (the scene's pose plus the world's offset) and its goal:
    x, y (m) and yaw (rad) each."""
    told = settings.scene.object
    return {"start_pose": [told.position_m[0] + world_mismatch.offset_m[0], told.position_m[1] +
                           world_mismatch.offset_m[1], told.yaw_rad + world_mismatch.offset_yaw_rad],
            "target_pose": [*map(float, goal.target_position_m[:2]), float(goal.target_yaw_rad)]}


def episode(goal: Goal, mismatch: Mismatch, mode: str, model: str, settings: Settings,
            clock_s: dict[str, float] | None = None) -> dict[str, Any]:
    """One goal in one world, open or closed loop: the episode's record; closed loop, its plans' and replans' compute
    times on the world's clock as measured or as clock_s fixes them (run_closed_loop)."""
    warm_up(settings)  # as the executor node does before it serves: no plan's compute time pays for the reaches
    world_mismatch = world_for(mismatch, goal)
    world = SimulatedWorld(settings, world_mismatch, start_configuration(goal.beta), seed=goal.index)
    target = ExecuteGoal(tuple(goal.target_position_m), goal.target_yaw_rad, model)
    if mode == "open_loop":
        told = settings.scene.object
        result = run_open_loop(settings, target, world, (tuple(told.position_m), told.yaw_rad))
    else:
        result = run_closed_loop(settings, target, world, clock_s)
    record = {"goal": goal.index, "world": mismatch.name, "mode": mode, "contact_model": model,
              "offset_m": list(world_mismatch.offset_m), "offset_yaw_rad": world_mismatch.offset_yaw_rad,
              "face": goal.face, "clock_s": clock_s, "steady_reach_margin_m": steady_margin_m(goal, settings),
              **poses(goal, world_mismatch, settings),
              **result.as_dict()}
    return {**record, "place": place(record, settings.task)}


def jobs(goals: list[Goal], model: str, settings: Settings, worlds=WORLDS, clock_s: dict[str, float] | None = None
         ) -> list:
    return [(f"goal{goal.index:03d}-{world.name}-{mode}", episode, (goal, world, mode, model, settings, clock_s))
            for goal in goals for world in worlds for mode in MODES]


def _stats(values: list[float]) -> dict[str, float | None]:
    values = [v for v in values if math.isfinite(v)]
    return {"median": float(statistics.median(values)) if values else None,
            "p90": float(np.percentile(values, 90)) if values else None}


def refused(record: dict[str, Any]) -> bool:
    """Whether the episode ended before any push, its goal refused (in process the ending says so, through the nodes
    the executor's cause)."""
    return Ending.INVALID_REQUEST.value in (record.get("ending"), record.get("cause")) and not record["pushes"]


def place(record: dict[str, Any], task) -> str:
    """Where an episode's cube came to rest against its goal, in the frame of the push from where it truly started:
    "goal" (a success); "tipped"; "turned" (within the position tolerance, the yaw not); else "beside" (more across
    the push than along it), "past" (beyond the goal: only a pull back, a push on another face, brings it back) or
    "short"; "refused" where no push was planned."""
    if record["success"] or record["tipped"]:
        return "goal" if record["success"] else "tipped"
    if refused(record):
        return "refused"
    if record["position_error_m"] < task.success_position_error_m:
        return "turned"
    ahead, across = push_frame_offset_cm(record)
    return "beside" if abs(across) > abs(ahead) else "past" if ahead > 0 else "short"


def report(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per zone, world and mode: successes (both tolerances), errors, replan rates and compute per replan."""
    records = [r for r in records if not r.get("failed")]
    out: dict[str, Any] = {}
    for name in ZONES:
        for world in dict.fromkeys(r["world"] for r in records):
            for mode in MODES:
                rows = [r for r in records if r["world"] == world and r["mode"] == mode
                        and zone(r["steady_reach_margin_m"]) == name]
                if not rows:
                    continue
                out.setdefault(name, {}).setdefault(world, {})[mode] = {
                    "episodes": len(rows), "success": sum(r["success"] for r in rows),
                    "tipped": sum(r.get("tipped", False) for r in rows),
                    "over_speed_limit": sum(r["max_joint_speed_ratio"] > 1.0 for r in rows),
                    "success_tight": sum(r["success_tight"] for r in rows),
                    "position_error_m": _stats([r["position_error_m"] for r in rows]),
                    "max_joint_speed_ratio": _stats([r["max_joint_speed_ratio"] for r in rows]),
                    "pushes": _stats([float(r["pushes"]) for r in rows]),
                    "replan_rate_hz": _stats([r["replan_rate_hz"] for r in rows]),
                    "replan_compute_s": _stats([r["replan_compute_s"] for r in rows]),
                    "replans": _stats([float(r["replans"]) for r in rows])}
    closed = [r for r in records if r["mode"] == "closed_loop"]
    cut = [r["pushes_cut"] for r in closed if "pushes_cut" in r]  # not counted through the nodes
    explained = {}  # per zone: successes by whether the first push was sturdy, and the misses by their cause
    for name in ZONES:
        rows = [r for r in closed if zone(r["steady_reach_margin_m"]) == name and r.get("cause")]
        durations = [r["duration_s"] for r in rows if "duration_s" in r]
        if rows:
            explained[name] = {
                "sturdy": {kind: {"episodes": sum(r["first_push_sturdy"] is flag for r in rows),
                                  "success": sum(r["success"] and r["first_push_sturdy"] is flag for r in rows)}
                           for kind, flag in (("sturdy", True), ("not_sturdy", False))},
                "miss_causes": dict(Counter(r["cause"] for r in rows if not r["success"]).most_common()),
                "miss_places": dict(Counter(r["place"] for r in rows if not r["success"] and "place" in r)
                                    .most_common()),
                "by_pushes": {n: {"episodes": sum(r["pushes"] == n for r in rows),
                                  "success": sum(r["success"] and r["pushes"] == n for r in rows)}
                              for n in sorted({r["pushes"] for r in rows})},
                "duration_s": _stats(durations) | {"max": max(durations)} if durations else None}
    faces = {}  # per face a push towards the goal needs (targets.face_needed): the any distribution's
    for face in dict.fromkeys(r["face"] for r in closed if "face" in r):
        rows = [r for r in closed if r.get("face") == face]
        faces[face] = {"episodes": len(rows), "success": sum(r["success"] for r in rows),
                       "refused": sum(map(refused, rows))}
    counted = [r for r in closed if "replans_taken" in r]  # not counted through the nodes
    taken = {"taken": sum(r["replans_taken"] for r in counted), "replans": sum(r["replans"] for r in counted)} \
        if counted else None
    return {"zones": out, "replan_rate_hz": _stats([r["replan_rate_hz"] for r in closed]), "replans_taken": taken,
            "clock_s": next((r["clock_s"] for r in closed if r.get("clock_s")), None),  # one per run (cito-bench)
            "replan_compute_s": _stats([r["replan_compute_s"] for r in closed]),
            "pushes_cut": {"pushes": sum(cut), "episodes": sum(n > 0 for n in cut)} if cut else None,
            "explained": explained, "faces": faces}


def push_frame_offset_cm(record: dict[str, Any]) -> tuple[float, float] | None:
    """Where the episode's cube came to rest from its goal, in cm along the push from where it truly started and
    across it (to the push's left); None for a record without the poses."""
    if not record.get("final_pose") or not record.get("start_pose"):
        return None
    start, target, final = (np.asarray(record[key][:2]) for key in ("start_pose", "target_pose", "final_pose"))
    along = (target - start) / max(float(np.linalg.norm(target - start)), 1e-9)
    off = final - target
    return 100 * float(off @ along), 100 * float(along[0] * off[1] - along[1] * off[0])


def plot(records: list[dict[str, Any]], path: Path, tolerance_m: float) -> Path:
    """One panel per world, the goals inside the steady reach: where each cube came to rest from its goal along and
    across its push, closed loop filled (a success green, a miss red), open loop hollow gray; the position
    tolerance drawn as a circle. A miss past the goal lies right of it, one beside it above or below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in records if not r.get("failed") and zone(r["steady_reach_margin_m"]) == "steady"
            and push_frame_offset_cm(r) is not None]
    worlds = list(dict.fromkeys(r["world"] for r in rows))
    figure, axes = plt.subplots(1, max(len(worlds), 1), figsize=(4.2 * max(len(worlds), 1), 4.8), squeeze=False)
    limit_cm = 6.0
    for axis, world in zip(axes[0], worlds, strict=False):
        for mode in MODES:
            chosen = [r for r in rows if r["world"] == world and r["mode"] == mode]
            for success in (True, False):
                points = np.array([push_frame_offset_cm(r) for r in chosen if r["success"] == success]).reshape(-1, 2)
                clipped = np.clip(points, -limit_cm, limit_cm)
                if mode == "closed_loop":
                    axis.scatter(clipped[:, 0], clipped[:, 1], s=22, color="tab:green" if success else "tab:red",
                                 label=f"closed loop, {'success' if success else 'miss'} ({len(points)})")
                else:
                    axis.scatter(clipped[:, 0], clipped[:, 1], s=18, facecolors="none", edgecolors="gray",
                                 linewidths=0.8, label=f"open loop, {'success' if success else 'miss'} ({len(points)})")
        axis.add_patch(plt.Circle((0.0, 0.0), 100 * tolerance_m, fill=False, linestyle="--", color="black"))
        axis.axhline(0.0, color="gray", linewidth=0.5)
        axis.axvline(0.0, color="gray", linewidth=0.5)
        axis.set_xlim(-limit_cm, limit_cm)
        axis.set_ylim(-limit_cm, limit_cm)
        axis.set_aspect("equal")
        axis.set_title(world, fontsize=9)
        axis.set_xlabel("past the goal along the push (cm)")
        axis.legend(fontsize=6, loc="lower left")
    axes[0][0].set_ylabel("beside it, to the push's left (cm)")
    figure.suptitle("where the cubes came to rest from their goals, inside the steady reach (dashed: the position "
                    "tolerance, a miss inside it is off in yaw; beyond 6 cm drawn at the edge)", fontsize=9)
    figure.tight_layout(rect=(0.0, 0.0, 1.0, 0.95))
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)
    return path


def _pushes_and_durations(explained: dict[str, Any]) -> str:
    """The explained line's tail: successes by the pushes an episode made, and how long the executions took (a
    summary from before these were counted has neither)."""
    text = ""
    if by_pushes := explained.get("by_pushes"):
        text += " Successes by the pushes an episode made: " + ", ".join(
            f"{n}: {e['success']} of {e['episodes']}" for n, e in by_pushes.items()) + "."
    if duration := explained.get("duration_s"):
        text += (f" The executions took a median {duration['median']:.1f} s (p90 {duration['p90']:.1f} s, the longest "
                 f"{duration['max']:.1f} s).")
    return text


def markdown(summary: dict[str, Any]) -> str:
    def cm(entry) -> str:
        return "-" if entry["median"] is None else f"{100 * entry['median']:.2f} / {100 * entry['p90']:.2f}"

    def whole(entry) -> str:  # a count's median ("-": not counted)
        return "-" if entry["median"] is None else f"{entry['median']:.0f}"

    lines = []
    for name, title in (("steady", "Goals inside the steady push reach"),
                        ("strike", "Goals beyond it (the near-reach share, reached only by a strike: best effort)")):
        if name not in summary["zones"]:
            continue
        lines += [f"{title}:", "", "| world | mode | success 2 cm / 0.15 rad | success 2 cm / 0.1 rad | error median / "
                  "p90 (cm) | pushes median | replans median | replan rate median (Hz) | compute per replan median "
                  "(ms) | max joint speed / limit median / p90 |", "|---|---|---|---|---|---|---|---|---|---|"]
        for world, modes in summary["zones"][name].items():
            for mode, e in modes.items():
                rate, compute = e["replan_rate_hz"]["median"], e["replan_compute_s"]["median"]
                speed = e["max_joint_speed_ratio"]
                lines.append(
                    f"| {world} | {mode.replace('_', ' ')} | {e['success']}/{e['episodes']} "
                    f"({e['success'] / e['episodes']:.0%}) | {e['success_tight']}/{e['episodes']} "
                    f"({e['success_tight'] / e['episodes']:.0%}) | {cm(e['position_error_m'])} | "
                    f"{whole(e['pushes'])} | {whole(e['replans'])} | "
                    f"{'-' if rate is None else f'{rate:.1f}'} | {'-' if compute is None else f'{1e3 * compute:.0f}'} | "
                    f"{speed['median']:.2f} / {speed['p90']:.2f} |")
        lines.append("")
    zone_names = {"steady": "inside the steady reach", "strike": "beyond it"}

    def where(count: str) -> str:  # "n in world, mode, zone; ..." of the groups that count some
        return "; ".join(f"{e[count]} in {world}, {mode.replace('_', ' ')}, {zone_names[zone]}"
                         for zone, zone_worlds in summary["zones"].items() for world, modes in zone_worlds.items()
                         for mode, e in modes.items() if e.get(count)) or "none"

    lines.append(f"Cubes tipped over (the true cube past its edge, never a success): {where('tipped')}.")
    lines.append("Episodes with a joint past its speed limit (the world's arm, above 1.0 of it at some step): "
                 f"{where('over_speed_limit')}.")
    if summary["pushes_cut"] is not None:
        cut = summary["pushes_cut"]
        lines.append(f"Pushes cut short with the cube off their path (executor.off_path_m): {cut['pushes']}, in "
                     f"{cut['episodes']} closed-loop episodes.")
    for name, e in summary.get("explained", {}).items():
        sturdy, fragile = e["sturdy"]["sturdy"], e["sturdy"]["not_sturdy"]
        causes = ", ".join(f"{cause.replace('_', ' ')} {n}" for cause, n in e["miss_causes"].items())
        places = ", ".join(f"{PLACES[place]} {n}" for place, n in e.get("miss_places", {}).items())
        lines.append(f"Closed loop {zone_names[name]}: the first push planned sturdy (PlanResult.sturdy) in "
                     f"{sturdy['episodes']} episodes, {sturdy['success']} of them successes; not sturdy in "
                     f"{fragile['episodes']}, {fragile['success']} successes. The misses by the executor's cause: "
                     f"{causes or 'none'}." + (f" Where their cubes came to rest against the goal, along the push "
                                              f"from where the cube started: {places}." if places else "")
                     + _pushes_and_durations(e))
    if faces := summary.get("faces"):
        lines.append("Closed loop by the face a push towards the goal needs (from where the cube starts): " + "; ".join(
            f"{face} {e['success']} of {e['episodes']} episodes ({e['refused']} refused before any push)"
            for face, e in faces.items()) + ".")
    rate, compute = summary["replan_rate_hz"], summary["replan_compute_s"]
    if clock := summary.get("clock_s"):
        lines.append(f"Compute on the world's clock fixed, not measured (--clock-s): {clock['plan']:g} s a plan, "
                     f"{clock['replan']:g} s a replan; the replan rates and compute above are those.")
    if rate["median"] is not None:
        lines.append(f"Replanning over every closed-loop episode: median rate {rate['median']:.1f} Hz (p90 of the "
                     f"episodes' medians {rate['p90']:.1f} Hz), median compute per replan {1e3 * compute['median']:.0f} "
                     f"ms." + (f" Taken: {taken['taken']} of {taken['replans']} replans (the others left the running "
                               f"plan in place)." if (taken := summary.get("replans_taken")) else ""))
    return "\n".join(lines) + "\n"
