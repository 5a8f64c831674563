"""The pictures: snapshots of planned motions (the paper's Figs. 4-6), VSCM stiffness
trajectories (Fig. 7), the contact law (Fig. 1), and virtual vs actual contact force.

Snapshots are rendered offscreen by MuJoCo's renderer; set MUJOCO_GL (osmesa or egl)
before mujoco is imported (cito-bench does).
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from cito_ros.contact_models import SmoothContactModel, contact_model  # noqa: E402
from cito_ros.planner import plan_push  # noqa: E402
from cito_ros.results import PlanResult  # noqa: E402
from cito_ros.scene import Scene  # noqa: E402
from cito_ros.settings import Settings, load_settings  # noqa: E402

COLORS = {"cccm": "tab:red", "scm": "tab:orange", "vscm": "tab:blue"}
SNAPSHOT_BETA = 7.0


def snapshot_times(result: PlanResult) -> list[float]:
    """Four instants as in Figs. 4-6: the start, first robot-object contact (or closest
    approach), halfway from there to the end, and the end (s)."""
    trajectory = result.trajectory
    times = trajectory.time_s[:-1]
    touching = np.nonzero(trajectory.contact_count > 0)[0]
    first = int(touching[0]) if touching.size else int(np.argmin(trajectory.signed_distance_m))
    return [0.005, float(times[first]), float((times[first] + trajectory.time_s[-1]) / 2), float(trajectory.time_s[-1])]


def render_snapshots(result: PlanResult, scene: Scene, width: int = 480, height: int = 360) -> list[tuple[float, np.ndarray]]:
    model = scene.model
    data = mujoco.MjData(model)
    option = mujoco.MjvOption()
    option.flags[mujoco.mjtVisFlag.mjVIS_CONTACTPOINT] = True
    option.flags[mujoco.mjtVisFlag.mjVIS_CONTACTFORCE] = True
    model.vis.scale.contactwidth, model.vis.scale.contactheight, model.vis.scale.forcewidth = 0.06, 0.02, 0.03
    model.vis.map.force = 0.05
    images = []
    renderer = mujoco.Renderer(model, height, width)
    try:
        for t in snapshot_times(result):
            step = int(round(t / (result.trajectory.time_s[1] - result.trajectory.time_s[0])))
            step = min(step, len(result.trajectory.time_s) - 1)
            data.qpos[scene.arm_qpos_adr] = result.trajectory.q[step]
            data.qvel[scene.arm_dof_adr] = result.trajectory.qdot[step]
            obj = scene.object_qpos_adr
            data.qpos[obj:obj + 3] = result.trajectory.object_position_m[step]
            data.qpos[obj + 3:obj + 7] = result.trajectory.object_quaternion[step]
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera="side", scene_option=option)
            images.append((t, renderer.render().copy()))
    finally:
        renderer.close()
    return images


def contact_law_figure(path: Path, settings: Settings) -> Path:
    """gamma(phi) = k exp(-(c/k) phi) for several k and c (Fig. 1)."""
    phi = np.linspace(-0.02, 0.3, 400)
    figure, axis = plt.subplots(figsize=(6.4, 4.2))
    configured_c = settings.contact_models.vscm.curvature
    for c, style in ((1e3, "--"), (configured_c, "-")):
        for k, color in ((10.0, "tab:green"), (50.0, "tab:orange"), (100.0, "tab:red")):
            gamma = SmoothContactModel(stiffness=k, curvature=c).gamma(phi, k)
            axis.plot(phi, gamma, style, color=color, label=f"k = {k:g} N, c = {c:g} N/m")
    axis.set_ylim(0, 120)
    axis.axvline(0, color="gray", linewidth=0.8)
    axis.set_xlabel("signed distance phi (m)")
    axis.set_ylabel("virtual normal force gamma (N)")
    axis.set_title("contact law gamma = k exp(-(c/k) phi)")
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def figures(out: Path, progress: Callable[[int, str], None] | None = None) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    settings = load_settings()
    written = [contact_law_figure(out / "contact_law.png", settings)]
    plans: dict[str, PlanResult] = {}
    runs = [("cccm", SNAPSHOT_BETA), ("scm", SNAPSHOT_BETA), ("vscm", 5.0), ("vscm", 6.0), ("vscm", SNAPSHOT_BETA)]
    vscm_by_beta = {}
    for index, (model, beta) in enumerate(runs):
        if progress:
            progress(index, f"planning {model} beta={beta:g}")
        result = plan_push(model, beta, settings=settings)
        if model == "vscm":
            vscm_by_beta[beta] = result
        if beta == SNAPSHOT_BETA:
            plans[model] = result
    if progress:
        progress(len(runs), "rendering")

    # snapshots, one row per contact model
    figure, axes = plt.subplots(3, 4, figsize=(16, 9.6))
    for row, model in enumerate(("cccm", "scm", "vscm")):
        result = plans[model]
        scene = Scene(contact_model(model, settings.contact_models), settings.scene)
        for column, (t, image) in enumerate(render_snapshots(result, scene)):
            axis = axes[row, column]
            axis.imshow(image)
            axis.set_xticks([])
            axis.set_yticks([])
            axis.set_title(f"{model.upper()}  t = {1000 * t:.0f} ms", fontsize=10)
        m = result.metrics
        axes[row, 0].set_ylabel(f"{model.upper()}\nexecuted {100 * m.position_error_m:.1f} cm\n"
                                f"planned {100 * m.planned_position_error_m:.1f} cm", fontsize=9)
    figure.suptitle(f"Returned plans executed without the virtual force, beta = {SNAPSHOT_BETA:g} "
                    "(MuJoCo contacts drawn as points and force arrows)")
    figure.tight_layout()
    written.append(out / "snapshots.png")
    figure.savefig(written[-1], dpi=90)
    plt.close(figure)

    # VSCM stiffness per knot (Fig. 7)
    figure, axis = plt.subplots(figsize=(6.4, 4.2))
    for beta, result in sorted(vscm_by_beta.items()):
        k = result.knot_variables["stiffness_N"]
        axis.step(result.knot_time_s, np.append(k, k[-1]), where="post",
                  label=f"beta = {beta:g} (phi0 = {result.initial_distance_m:.2f} m)")
    axis.set_xlabel("time (s)")
    axis.set_ylabel("stiffness k (N)")
    axis.set_ylim(-2, 105)
    axis.set_title("VSCM stiffness per knot (the discovery's plan)")
    axis.legend(fontsize=8)
    figure.tight_layout()
    written.append(out / "vscm_stiffness.png")
    figure.savefig(written[-1], dpi=110)
    plt.close(figure)

    # virtual vs actual contact force
    figure, axes = plt.subplots(3, 1, figsize=(7.5, 7.5), sharex=True)
    for axis, model in zip(axes, ("cccm", "scm", "vscm")):
        planned, executed = plans[model].planned, plans[model].trajectory
        t = planned.time_s[:-1]
        axis.plot(t, planned.gamma_N, color=COLORS[model], label="virtual force gamma (the contact model's plan)")
        axis.plot(t, np.linalg.norm(planned.contact_force_N, axis=1), color="gray", linewidth=1,
                  label="actual robot-object force in that plan")
        axis.plot(t, np.linalg.norm(executed.contact_force_N, axis=1), color="black", linewidth=1.2,
                  label="actual robot-object force, returned plan executed")
        axis.set_ylabel(f"{model.upper()} force (N)")
        axis.legend(fontsize=8, loc="upper left")
        axis.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title(f"virtual force (discovery) vs actual contact force (executed), beta = {SNAPSHOT_BETA:g}")
    figure.tight_layout()
    written.append(out / "contact_forces.png")
    figure.savefig(written[-1], dpi=110)
    plt.close(figure)
    return written
