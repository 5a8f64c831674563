"""The pictures: snapshots of the returned plans executed (the paper's Figs. 4-6), VSCM stiffness
trajectories of the paper's problem (Fig. 7), the contact law (Fig. 1), and the virtual force the paper's
problem plans with against the actual contact forces.

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

from cito_ros.model.contact_models import SmoothContactModel  # noqa: E402
from cito_ros.model.simulator import FULL_PHYSICS  # noqa: E402
from cito_ros.planner.plan import plan_push  # noqa: E402
from cito_ros.planner.results import PlanResult  # noqa: E402
from cito_ros.planner.task import yaw_rotation  # noqa: E402
from cito_ros.settings import Settings, load_settings  # noqa: E402

COLORS = {"cccm": "tab:red", "scm": "tab:orange", "vscm": "tab:blue"}
MODELS = ("cccm", "scm", "vscm")
SNAPSHOT_BETA = 7.0
# (pipeline, model, beta) of every plan the pictures show: the returned plans at SNAPSHOT_BETA, and the
# paper's problem for Fig. 7 and for the virtual force it plans with
RUNS = tuple(("physical", model, SNAPSHOT_BETA) for model in MODELS) + \
    tuple(("paper", model, SNAPSHOT_BETA) for model in MODELS) + (("paper", "vscm", 5.0), ("paper", "vscm", 6.0))
# a free camera on the push from the front left: the scene's "side" camera shows the cube at a tenth of the
# picture's width
CAMERA_LOOKAT_M, CAMERA_AZIMUTH_DEG, CAMERA_ELEVATION_DEG, CAMERA_DISTANCE_M = (0.85, 0.0, 0.15), 110.0, -30.0, 1.6
GOAL_RGBA = (0.1, 0.8, 0.2, 0.35)


def snapshot_times(result: PlanResult) -> list[float]:
    """Four instants as in Figs. 4-6: the start, first robot-object contact (or closest
    approach), halfway from there to the end, and the end (s)."""
    trajectory = result.trajectory
    times = trajectory.time_s[:-1]
    touching = np.nonzero(trajectory.contact_count > 0)[0]
    first = int(touching[0]) if touching.size else int(np.argmin(trajectory.signed_distance_m))
    return [0.005, float(times[first]), float((times[first] + trajectory.time_s[-1]) / 2), float(trajectory.time_s[-1])]


def _draw_goal(scene: mujoco.MjvScene, result: PlanResult) -> None:
    """The goal pose as a translucent box the size of the object."""
    if scene.ngeom >= scene.maxgeom:
        return
    rotation = yaw_rotation(result.target_yaw_rad)
    mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_BOX,
                        np.asarray(result.scene.object_half_size, dtype=float),
                        np.asarray(result.target_position_m, dtype=float),
                        rotation.reshape(-1), np.asarray(GOAL_RGBA, dtype=np.float32))
    scene.ngeom += 1


def render_snapshots(result: PlanResult, settings: Settings, width: int = 480,
                     height: int = 360) -> list[tuple[str, np.ndarray]]:
    """The returned plan executed without the virtual force at snapshot_times and at rest (its `rest`),
    each picture with its label, the goal drawn as a translucent box."""
    scene = result.scene
    model = scene.model
    data = mujoco.MjData(model)
    option = mujoco.MjvOption()
    option.flags[mujoco.mjtVisFlag.mjVIS_CONTACTPOINT] = True
    option.flags[mujoco.mjtVisFlag.mjVIS_CONTACTFORCE] = True
    model.vis.scale.contactwidth, model.vis.scale.contactheight, model.vis.scale.forcewidth = 0.06, 0.02, 0.03
    model.vis.map.force = 0.05
    camera = mujoco.MjvCamera()
    camera.lookat[:] = CAMERA_LOOKAT_M
    camera.azimuth, camera.elevation, camera.distance = CAMERA_AZIMUTH_DEG, CAMERA_ELEVATION_DEG, CAMERA_DISTANCE_M
    trajectory = result.trajectory
    dt = trajectory.time_s[1] - trajectory.time_s[0]
    obj = scene.object_qpos_adr
    images = []
    renderer = mujoco.Renderer(model, height, width)

    def picture(label: str) -> None:
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, camera=camera, scene_option=option)
        _draw_goal(renderer.scene, result)
        images.append((label, renderer.render().copy()))

    try:
        for t in snapshot_times(result):
            step = min(int(round(t / dt)), len(trajectory.time_s) - 1)
            data.qpos[scene.arm_qpos_adr] = trajectory.q[step]
            data.qvel[scene.arm_dof_adr] = trajectory.qdot[step]
            data.qpos[obj:obj + 3] = trajectory.object_position_m[step]
            data.qpos[obj + 3:obj + 7] = trajectory.object_quaternion[step]
            picture(f"t = {1000 * t:.0f} ms")
        if result.rest is not None and not result.rest.warnings:
            mujoco.mj_setState(model, data, result.rest.final_state, FULL_PHYSICS)
            picture(f"at rest ({1000 * settings.tracking.hold_s:.0f} ms on)")
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
    """Plan RUNS and draw the pictures into `out`; progress(done, what) before each plan and the drawing."""
    out.mkdir(parents=True, exist_ok=True)
    settings = load_settings()
    written = [contact_law_figure(out / "contact_law.png", settings)]
    plans: dict[tuple[str, str, float], PlanResult] = {}
    for index, (pipeline, model, beta) in enumerate(RUNS):
        if progress:
            progress(index, f"planning {model} beta={beta:g} ({pipeline})")
        plans[pipeline, model, beta] = plan_push(model, beta, settings=settings.with_overrides({"pipeline": pipeline}))
    if progress:
        progress(len(RUNS), "rendering")

    # snapshots, one row per contact model
    figure = None
    for row, model in enumerate(MODELS):
        result = plans["physical", model, SNAPSHOT_BETA]
        pictures = render_snapshots(result, settings)
        if figure is None:
            figure, axes = plt.subplots(len(MODELS), len(pictures), figsize=(4 * len(pictures), 9.6), squeeze=False)
        for column, (label, image) in enumerate(pictures):
            axis = axes[row, column]
            axis.imshow(image)
            axis.set_xticks([])
            axis.set_yticks([])
            axis.set_title(f"{model.upper()}  {label}", fontsize=10)
        m = result.metrics
        axes[row, 0].set_ylabel(f"{model.upper()}: {'success' if m.success else 'miss'}\n"
                                f"executed {100 * m.position_error_m:.1f} cm, {m.orientation_error_rad:.2f} rad\n"
                                f"tracked {100 * m.tracked_position_error_m:.1f} cm", fontsize=9)
    figure.suptitle(f"Returned plans executed without the virtual force, beta = {SNAPSHOT_BETA:g}; the goal in "
                    "green, MuJoCo contacts as points and force arrows")
    figure.tight_layout()
    written.append(out / "snapshots.png")
    figure.savefig(written[-1], dpi=80)
    plt.close(figure)

    # VSCM stiffness per knot (Fig. 7): the paper's problem, where k is the optimizer's
    figure, axis = plt.subplots(figsize=(6.4, 4.2))
    for beta in sorted(beta for pipeline, model, beta in RUNS if (pipeline, model) == ("paper", "vscm")):
        result = plans["paper", "vscm", beta]
        k = result.knot_variables["stiffness_N"]
        axis.step(result.knot_time_s, np.append(k, k[-1]), where="post",
                  label=f"beta = {beta:g} (phi0 = {result.initial_distance_m:.2f} m)")
    axis.set_xlabel("time (s)")
    axis.set_ylabel("stiffness k (N)")
    axis.set_ylim(-2, 105)
    axis.set_title("VSCM stiffness per knot, the paper's problem (pipeline: paper)")
    axis.legend(fontsize=8)
    figure.tight_layout()
    written.append(out / "vscm_stiffness.png")
    figure.savefig(written[-1], dpi=110)
    plt.close(figure)

    # the virtual force the paper's problem plans with, against the actual contact forces
    figure, axes = plt.subplots(len(MODELS), 2, figsize=(12, 7.5), sharey="row")
    for row, model in enumerate(MODELS):
        paper, returned = plans["paper", model, SNAPSHOT_BETA], plans["physical", model, SNAPSHOT_BETA]
        left, right = axes[row]
        t = paper.planned.time_s[:-1]
        left.plot(t, paper.planned.gamma_N, color=COLORS[model], label="virtual force gamma (planned)")
        left.plot(t, np.linalg.norm(paper.planned.contact_force_N, axis=1), color="gray", linewidth=1,
                  label="actual robot-object force in the plan")
        left.plot(t, np.linalg.norm(paper.trajectory.contact_force_N, axis=1), color="black", linewidth=1,
                  label="actual force, the plan executed without gamma")
        left.set_title(f"{model.upper()}, the paper's problem: planned "
                       f"{100 * paper.metrics.planned_position_error_m:.1f} cm, executed "
                       f"{100 * paper.metrics.position_error_m:.1f} cm", fontsize=9)
        t = returned.trajectory.time_s[:-1]
        right.plot(t, np.linalg.norm(returned.trajectory.contact_force_N, axis=1), color="black", linewidth=1,
                   label="actual robot-object force, executed")
        right.set_title(f"{model.upper()}, the returned plan (physical pipeline): executed "
                        f"{100 * returned.metrics.position_error_m:.1f} cm", fontsize=9)
        left.set_ylabel(f"{model.upper()} force (N)")
        for axis in (left, right):
            axis.legend(fontsize=7, loc="upper left")
            axis.grid(alpha=0.3)
    for axis in axes[-1]:
        axis.set_xlabel("time (s)")
    figure.suptitle(f"Virtual and actual contact forces, beta = {SNAPSHOT_BETA:g} "
                    "(errors where the cube comes to rest)")
    figure.tight_layout()
    written.append(out / "contact_forces.png")
    figure.savefig(written[-1], dpi=100)
    plt.close(figure)
    return written
