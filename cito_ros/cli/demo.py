"""cito-demo: the main job. Starts the planner node, sends a /cito/plan_push action goal from a
client in this (separate) process for the default scene (VSCM, the configured beta, the object
pushed DEMO_PUSH_M along +x, inside the steady push reach; or --target), shows the feedback as a
progress bar, prints a summary, leaves the bag, stops the node and exits 0 when a plan came back.

    cito-demo [--contact-model {cccm,scm,vscm}] [--target X Y YAW] [--bag-directory DIR] [--timeout S]
              [--cancel-after S]
"""
from __future__ import annotations

import argparse
import math
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

from cito_ros.cli.progress import advance, progress_bar
from cito_ros.model.contact_models import CONTACT_MODELS
from cito_ros.model.scene import TABLE_TOP_Z_M
from cito_ros.planner.results import zone
from cito_ros.settings import load_settings

DEMO_PUSH_M = 0.15  # from the default scene's cube, 5 cm inside the steady push reach


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cito-demo", description=__doc__.splitlines()[0])
    parser.add_argument("--contact-model", choices=sorted(CONTACT_MODELS), default="vscm")
    parser.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "YAW"), default=None,
                        help=f"the object's goal: x, y (m, world) and yaw (rad); default {DEMO_PUSH_M} m along +x")
    parser.add_argument("--bag-directory", type=Path, default=Path("bags"))
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds to wait for the plan")
    parser.add_argument("--cancel-after", type=float, default=None, metavar="S",
                        help="cancel the goal after S seconds (the best plan so far comes back)")
    args = parser.parse_args(argv)

    # an isolated graph: a random domain on this host only, unless the caller chose one
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    node_bin = Path(sys.executable).parent / "cito-planner-node"
    node = subprocess.Popen([str(node_bin), "--ros-args", "-p", f"node.bag_directory:={args.bag_directory.resolve()}",
                             "--log-level", "warn"], env=os.environ.copy())
    try:
        return _call(args)
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()


def _call(args) -> int:
    import rclpy
    from cito_msgs.action import PlanPush
    from rclpy.action import ActionClient

    settings = load_settings()
    x, y = settings.scene.object.position_m
    target_x, target_y, yaw = (x + DEMO_PUSH_M, y, 0.0) if args.target is None else args.target
    goal = PlanPush.Goal()
    goal.target_pose.position.x, goal.target_pose.position.y = target_x, target_y
    goal.target_pose.position.z = TABLE_TOP_Z_M + settings.scene.object.half_size_m
    goal.target_pose.orientation.z, goal.target_pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    goal.contact_model = args.contact_model

    rclpy.init()
    client_node = rclpy.create_node("cito_demo_client")
    try:
        client = ActionClient(client_node, PlanPush, "/cito/plan_push")
        if not client.wait_for_server(timeout_sec=30.0):
            print("cito-demo: the planner node did not come up", file=sys.stderr)
            return 1
        bar = progress_bar(None, f"planning ({args.contact_model})", "it")

        def feedback(message) -> None:
            f = message.feedback
            best = f.best_executed_position_error_m  # NaN until a plan has been executed
            advance(bar, f.iteration, f"{f.stage}, best executed error "
                                      + (f"{100 * best:.2f} cm" if math.isfinite(best) else "-"))

        started = time.monotonic()
        sent = client.send_goal_async(goal, feedback_callback=feedback)
        rclpy.spin_until_future_complete(client_node, sent, timeout_sec=30.0)
        if not sent.done() or not sent.result().accepted:
            print("cito-demo: the goal was not accepted", file=sys.stderr)
            return 1
        future = sent.result().get_result_async()
        if args.cancel_after is not None:
            rclpy.spin_until_future_complete(client_node, future, timeout_sec=args.cancel_after)
            if not future.done():
                bar.write(f"cito-demo: cancelling the goal after {args.cancel_after:g} s", file=sys.stderr)
                sent.result().cancel_goal_async()
        rclpy.spin_until_future_complete(client_node, future, timeout_sec=args.timeout)
        bar.close()
        if not future.done():
            print(f"cito-demo: no result within {args.timeout} s", file=sys.stderr)
            return 1
        r = future.result().result
        m = r.metrics
        print(f"plan-push ({args.contact_model}, beta {settings.beta:g}): status {r.status} "
              f"({'SUCCESS' if r.success else 'no success'}) {r.message}")
        print(f"  executed error     {100 * m.position_error_m:8.2f} cm, {m.orientation_error_rad:.4f} rad "
              f"(virtual force off, as on the robot)")
        print(f"  tracked error      {100 * m.tracked_position_error_m:8.2f} cm, "
              f"{m.tracked_orientation_error_rad:.4f} rad (PD joint trajectory controller)")
        print(f"  planned error      {100 * m.planned_position_error_m:8.2f} cm (contact model, virtual force on)")
        print(f"  joint speeds       {m.max_joint_speed_ratio:8.2f} of the limits at most")
        print(f"  reach zone         {zone(m.steady_reach_margin_m):>8} "
              f"({100 * m.steady_reach_margin_m:+.1f} cm from the steady push reach)")
        print(f"  solve time         {m.solve_time_s:8.2f} s ({m.iterations} iterations; "
              f"round trip {time.monotonic() - started:.2f} s)")
        print(f"  trajectory         {len(r.trajectory.points)} points, {len(r.contact_forces)} contact samples (with the hold after it)")
        print(f"  bag                {r.bag_path}")
        return 0
    finally:
        client_node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
