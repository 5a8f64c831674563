"""`cito-bench targets`' figure: executed error against solve time and against the goal's distance, and the goals on
the table. ROS-free."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from cito_ros.studies.targets import OFFSET_AMPLITUDE_RAD
from cito_ros.studies.targets_report import goal_distance_m, offset_verdicts, steady_reach_m


def plot(records: list[dict[str, Any]], path: Path, where: dict[str, Any] | None = None) -> Path:
    """Executed error against solve time per model, successes filled, success rate in the legend, the
    successes that an offset of the tracked reference takes beyond 2 cm crossed; against the goal's
    distance from the arm base, the steady push reach and the push reach marked; and, with the goals' region
    (`where`), a map of the table: the region, the cube's start, each goal (filled: a success)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"cccm": "tab:red", "scm": "tab:orange", "vscm": "tab:blue"}
    refusals = [r for r in records if r.get("refused") and r["perturbation"] == "none"]
    records = [r for r in records if not r.get("failed") and not r.get("refused") and r["perturbation"] == "none"]
    panels = [("solve time (s)", lambda r: r["solve_time_s"], "log"),
              ("goal's distance from the arm base (m)", goal_distance_m, "linear")]
    push_reach_m = None if where is None else where["push_reach_m"]
    figure, axes = plt.subplots(1, len(panels) + (where is not None), figsize=(7.5 * (len(panels) + 1), 5),
                                squeeze=False)
    for axis, (label, x_of, xscale) in zip(axes[0], panels):
        for model in dict.fromkeys(r["contact_model"] for r in records):
            rows = [r for r in records if r["contact_model"] == model]
            wins, refused = sum(r["success"] for r in rows), sum(r["contact_model"] == model for r in refusals)
            rate = f"{wins}/{len(rows)} posed succeed" + (f", {refused} refused" if refused else "")
            for success in (True, False):
                chosen = [r for r in rows if r["success"] == success]
                axis.scatter([x_of(r) for r in chosen], [max(100 * r["position_error_m"], 1e-3) for r in chosen],
                             color=colors.get(model, "gray"), facecolors=colors.get(model, "gray") if success else "none",
                             s=30, label=f"{model.upper()} ({rate})" if success else None)
        fragile = [r for r in records if r["success"] and not all(offset_verdicts(r))]
        if fragile:
            axis.scatter([x_of(r) for r in fragile], [max(100 * r["position_error_m"], 1e-3) for r in fragile],
                         color="black", marker="x", s=14, linewidths=0.8,
                         label=f"success, but > 2 cm with the reference off by up to {OFFSET_AMPLITUDE_RAD:g} rad")
        axis.axhline(2.0, color="gray", linewidth=0.8, linestyle="--")
        axis.set_xscale(xscale)
        axis.set_yscale("log")
        axis.set_xlabel(label)
        axis.set_ylabel("executed position error (cm), virtual force off")
        axis.legend(fontsize=8)
        axis.grid(True, which="both", alpha=0.3)
    axes[0][0].set_title("random pushes: error executed on the robot against solve time (filled: success)")
    steady = min((steady_reach_m(r) for r in records), default=None)
    if steady is not None:
        axes[0][1].axvspan(steady, push_reach_m or steady, color="gray", alpha=0.15)
        axes[0][1].axvline(steady, color="black", linewidth=1.0)
        axes[0][1].set_title(f"against the goal's distance: beyond the steady push reach ({steady:.3f} m, shaded"
                             + (f" to the push reach {push_reach_m:.3f} m" if push_reach_m else "") + "): strikes")
    if where is not None:
        map_of_goals(axes[0][len(panels)], records, refusals, where, colors)
    for axis in axes[0]:
        axis.title.set_fontsize(9)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def map_of_goals(axis, records: list[dict[str, Any]], refusals: list[dict[str, Any]], where: dict[str, Any],
                 colors: dict[str, str]) -> None:
    """The table seen from above: the region goals are drawn from (the table top within the push reach), the
    cube's start, and every goal, filled where its plan succeeded, its marker the face it needs; the refused
    goals crossed."""
    import matplotlib.patches as patches

    (x_low, y_low), (x_high, y_high) = where["table_low_m"], where["table_high_m"]
    axis.add_patch(patches.Rectangle((x_low, y_low), x_high - x_low, y_high - y_low, fill=False, color="gray"))
    axis.add_patch(patches.Circle((0.0, 0.0), where["push_reach_m"], fill=False, color="black", linestyle="--",
                                  label=f"push reach {where['push_reach_m']:.3f} m"))
    axis.scatter([0.0], [0.0], color="black", marker="s", s=40, label="arm base")
    axis.scatter(*where["object_start_m"], color="gray", marker="s", s=80, alpha=0.5, label="cube start")
    markers = {"near": "o", "side": "^", "far": "v"}
    for model in dict.fromkeys(r["contact_model"] for r in records):
        for face, marker in markers.items():
            for success in (True, False):
                rows = [r for r in records if r["contact_model"] == model and r.get("face", "near") == face
                        and r["success"] == success]
                if rows:
                    color = colors.get(model, "gray")
                    axis.scatter([r["target_position_m"][0] for r in rows], [r["target_position_m"][1] for r in rows],
                                 color=color, facecolors=color if success else "none", marker=marker, s=30,
                                 label=f"{model.upper()}, {face} face, {'success' if success else 'miss'}")
    if refusals:
        axis.scatter([r["target_position_m"][0] for r in refusals], [r["target_position_m"][1] for r in refusals],
                     color="gray", marker="x", s=30, label="refused")
    axis.set_xlim(min(x_low, -0.05) - 0.05, x_high + 0.05)
    axis.set_ylim(y_low - 0.05, y_high + 0.05)
    axis.set_aspect("equal")
    axis.set_xlabel("goal x (m, arm base frame)")
    axis.set_ylabel("goal y (m)")
    axis.set_title("goals on the table (the region: the table top within the push reach)")
    axis.legend(fontsize=7, loc="lower left")
    axis.grid(True, alpha=0.3)
