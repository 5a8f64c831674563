"""cito-plan: plan one push with a chosen contact model.

    cito-plan --contact-model {cccm,scm,vscm} --beta {5,6,7} [--target X Y YAW]
              [--max-iter N] [--time-limit S] [--json]
"""
from __future__ import annotations

import argparse
import json
import sys

from cito_ros.cli.progress import ProgressBar
from cito_ros.contact_models import CONTACT_MODELS
from cito_ros.planner import plan_push
from cito_ros.results import IterationLog, PlanResult
from cito_ros.settings import load_settings


def print_summary(result: PlanResult) -> None:
    m = result.metrics
    target = ", ".join(f"{v:.3f}" for v in result.target_position_m[:2])
    final = ", ".join(f"{v:.3f}" for v in result.trajectory.object_position_m[-1][:2])
    print(f"contact model      {result.contact_model} (beta = {result.beta}, initial distance {result.initial_distance_m:.3f} m)")
    print(f"status             {m.status.value}, {'SUCCESS' if m.success else 'task not achieved'} "
          f"({m.iterations} iterations, {m.solve_time_s:.2f} s)")
    print(f"object             ({final}) m, target ({target}) m, yaw {result.target_yaw_rad:.3f} rad")
    print(f"position error     {m.position_error_m * 100:7.2f} cm")
    print(f"orientation error  {m.orientation_error_rad:7.4f} rad")
    print(f"physical inacc.    {m.physical_inaccuracy_Ns:7.4f} N s (integral of the virtual force)")
    print(f"replay error       {m.replay_position_error_m * 100:7.2f} cm (same torques, virtual force off)")
    if result.trajectory.warnings:
        print(f"MuJoCo warnings    {result.trajectory.warnings}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cito-plan", description=__doc__.splitlines()[0])
    parser.add_argument("--contact-model", choices=sorted(CONTACT_MODELS), default=None,
                        help="contact model (default: vscm)")
    parser.add_argument("--beta", type=float, default=None, help="start pose q0(beta) (default: config beta, 5)")
    parser.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "YAW"), default=None,
                        help="object goal: x, y (m, world) and yaw (rad); default 0.25 m along +x")
    parser.add_argument("--max-iter", type=int, default=None, help="IPOPT iterations per stage")
    parser.add_argument("--time-limit", type=float, default=None, help="wall-clock limit of the solve (s)")
    parser.add_argument("--json", action="store_true", help="print one JSON object with the metrics")
    args = parser.parse_args(argv)

    try:
        overrides = {}
        if args.max_iter is not None:
            overrides["solver.max_iter"] = args.max_iter
        if args.time_limit is not None:
            overrides["solver.time_limit_s"] = args.time_limit
        settings = load_settings().with_overrides(overrides)
        bar = None if args.json else ProgressBar(None, "solving, iteration")

        def progress(entry: IterationLog) -> None:
            if bar is not None:
                bar.update(entry.iteration, f"cost {entry.cost:.4g} violation {entry.constraint_violation:.1e}")

        target = None if args.target is None else args.target[:2]
        yaw = 0.0 if args.target is None else args.target[2]
        result = plan_push(args.contact_model or "vscm", args.beta, target_position_m=target, target_yaw_rad=yaw,
                           settings=settings, iteration_callback=progress)
        if bar is not None:
            bar.close()
    except ValueError as error:
        print(f"cito-plan: error: {error}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result.summary()))
    else:
        print_summary(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
