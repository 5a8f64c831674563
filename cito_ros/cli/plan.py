"""cito-plan: plan one push with a chosen contact model.

    cito-plan [--contact-model {cccm,scm,vscm}] [--beta B] [--target X Y YAW] [--object X Y YAW] [--scene NAME]
              [--pipeline {physical,paper}] [--max-iter N] [--time-limit S] [--json]

With --json, one JSON object on stdout: the plan's summary, or {"status": "invalid_request",
"message": ...} (exit code 2) when the request cannot be planned.
"""
from __future__ import annotations

import os

# cito-plan renders nothing: with no GL backend asked for, MuJoCo's import skips loading GLFW (70 ms of a one-shot
# refusal's answer); read by mujoco when it is first imported
os.environ.setdefault("MUJOCO_GL", "disable")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402

from cito_ros.cli.progress import advance, progress_bar  # noqa: E402
from cito_ros.model.contact_models import CONTACT_MODELS  # noqa: E402
from cito_ros.planner.plan import plan_push  # noqa: E402
from cito_ros.planner.results import IterationLog, PlanResult, zone, zone_note  # noqa: E402
from cito_ros.planner.sequence import sequence_note  # noqa: E402
from cito_ros.planner.task import aim_note, equivalent_yaw_note  # noqa: E402
from cito_ros.settings import load_settings  # noqa: E402

INVALID_REQUEST = "invalid_request"


def print_summary(result: PlanResult, requested_yaw_rad: float) -> None:
    m = result.metrics
    target = ", ".join(f"{v:.3f}" for v in result.target_position_m[:2])
    motion = result.executed_motion
    final = ", ".join(f"{v:.3f}" for v in motion.object_position_m[-1][:2])
    print(f"contact model      {result.contact_model} (beta = {result.beta}, initial distance {result.initial_distance_m:.3f} m)")
    print(f"status             {m.status.value}, {'SUCCESS' if m.success else 'task not achieved'} "
          f"({m.iterations} iterations, {m.solve_time_s:.2f} s)")
    print(f"object             ({final}) m executed, at rest, goal ({target}) m, yaw {result.target_yaw_rad:.3f} rad")
    print(f"executed error     {m.position_error_m * 100:7.2f} cm, {m.orientation_error_rad:.4f} rad "
          f"(virtual force off, as on the robot)")
    print(f"tracked error      {m.tracked_position_error_m * 100:7.2f} cm, {m.tracked_orientation_error_rad:.4f} rad "
          f"(PD joint trajectory controller)")
    print(f"planned error      {m.planned_position_error_m * 100:7.2f} cm, {m.planned_orientation_error_rad:.4f} rad "
          f"(contact model, with the virtual force)")
    print(f"joint speeds       {m.max_joint_speed_ratio:7.2f} of the limits at most")
    print(f"physical inacc.    {m.physical_inaccuracy_Ns:7.4f} N s (integral of the planned virtual force)")
    print(f"reach zone         {zone(m.steady_reach_margin_m)}: the goal {100 * abs(m.steady_reach_margin_m):.1f} cm "
          f"{'inside' if m.steady_reach_margin_m >= 0 else 'beyond'} the steady push reach"
          + (f"; {zone_note(m.steady_reach_margin_m)}" if zone(m.steady_reach_margin_m) == "strike" else ""))
    taken = equivalent_yaw_note(requested_yaw_rad, result.target_yaw_rad)
    if taken:
        print(f"goal yaw           {taken}")
    pushes = sequence_note(result)
    if pushes:
        print(f"pushes             {pushes}")
    aimed = aim_note(result.target_position_m, result.aim_position_m)
    if aimed:
        print(f"aim                {aimed}")
    if motion.warnings:
        print(f"MuJoCo warnings    {motion.warnings}")
    if result.note and not m.success:
        print(f"why                {result.note}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cito-plan", description=__doc__.splitlines()[0])
    parser.add_argument("--contact-model", choices=sorted(CONTACT_MODELS), default="vscm")
    parser.add_argument("--beta", type=float, default=None, help="start pose q0(beta) (default: the config's)")
    parser.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "YAW"), default=None,
                        help="object goal: x, y (m, world) and yaw (rad); default the config's push along +x")
    parser.add_argument("--object", type=float, nargs=3, metavar=("X", "Y", "YAW"), default=None,
                        help="where the object is now: x, y (m, world) and yaw (rad); default the scene's pose")
    parser.add_argument("--scene", default=None, help="scene in config/scenes (default: the config's)")
    parser.add_argument("--pipeline", choices=("physical", "paper"), default=None,
                        help="physical (default): executable plans; paper: exactly the paper's problem")
    parser.add_argument("--max-iter", type=int, default=None, help="solver iterations per stage")
    parser.add_argument("--time-limit", type=float, default=None, help="wall-clock limit of the solve (s)")
    parser.add_argument("--reference-offsets", type=int, default=None, metavar="N",
                        help="the plan must also reach the goal when a joint trajectory controller tracks it with "
                             "its reference off by N small seeded offsets (tracking.reference_offsets; slower)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)

    try:
        overrides = {"solver.max_iter": args.max_iter, "solver.time_limit_s": args.time_limit,
                     "pipeline": args.pipeline, "tracking.reference_offsets": args.reference_offsets}
        settings = load_settings().with_overrides({k: v for k, v in overrides.items() if v is not None})
        bar = None if args.json else progress_bar(None, "solving", "it")

        def progress(entry: IterationLog) -> None:
            if bar is not None:
                advance(bar, entry.iteration, f"{entry.stage} cost {entry.cost:.4g}")

        target = None if args.target is None else args.target[:2]
        yaw = 0.0 if args.target is None else args.target[2]
        result = plan_push(args.contact_model, args.beta, target_position_m=target, target_yaw_rad=yaw,
                           scene=args.scene, settings=settings,
                           object_pose=None if args.object is None else (args.object[:2], args.object[2]),
                           iteration_callback=progress)
        if bar is not None:
            bar.close()
    except ValueError as error:
        if args.json:
            print(json.dumps({"status": INVALID_REQUEST, "message": str(error)}))
        else:
            print(f"cito-plan: error: {error}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result.summary()))
    else:
        print_summary(result, yaw)
    return 0


if __name__ == "__main__":
    sys.exit(main())
