"""cito-demo: the main job. Starts the planner node, sends a /cito/plan_push action goal from a
client in this (separate) process for the default scene (VSCM, the configured beta, the object
pushed DEMO_PUSH_M along +x, inside the steady push reach; or --target), shows the feedback as a
progress bar and prints a summary. Then the same push on a robot whose world is not the model (DEMO_WORLD):
closed loop, cito-sim-robot and cito-executor-node over DDS, the goal sent as an ExecutePush action; and open
loop, the plan from where the planner was told the cube is, executed in the same world in this process by a
joint trajectory controller. Both are judged on the simulator's true cube at rest and printed side by side.
A plan that did not succeed (a cancelled one, say) is not executed. Leaves the bags, stops the nodes and exits 0
when a plan came back (and, when it succeeded, the execution ran).

    cito-demo [--contact-model {cccm,scm,vscm}] [--target X Y YAW] [--bag-directory DIR] [--timeout S]
              [--cancel-after S] [--no-execute]
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
# the executions' world: a heavier, grippier cube than the model's, 15 mm off along x and y and turned 0.1 rad
# from where the planner is told, seen by a camera with 1 mm and 0.01 rad of noise, 30 ms late
DEMO_WORLD = dict(friction_scale=1.5, mass_scale=2.0, offset_m=(0.015, 0.015), offset_yaw_rad=0.1,
                  pose_noise_m=0.001, yaw_noise_rad=0.01, latency_s=0.03)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cito-demo", description=__doc__.splitlines()[0])
    parser.add_argument("--contact-model", choices=sorted(CONTACT_MODELS), default="vscm")
    parser.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "YAW"), default=None,
                        help=f"the object's goal: x, y (m, world) and yaw (rad); default {DEMO_PUSH_M} m along +x")
    parser.add_argument("--bag-directory", type=Path, default=Path("bags"))
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds to wait for the plan")
    parser.add_argument("--cancel-after", type=float, default=None, metavar="S",
                        help="cancel the goal after S seconds (the best plan so far comes back)")
    parser.add_argument("--no-execute", action="store_true", help="plan only: no execution in the mismatched world")
    args = parser.parse_args(argv)

    # an isolated graph: a random domain on this host only, unless the caller chose one
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    node_bin = Path(sys.executable).parent / "cito-planner-node"
    node = subprocess.Popen([str(node_bin), "--ros-args", "-p", f"node.bag_directory:={args.bag_directory.resolve()}",
                             "--log-level", "warn"], env=os.environ.copy())
    try:
        code, planned = _call(args)
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()
    if code or args.no_execute:
        return code
    if not planned:
        print("the plan did not succeed: not executed")
        return code
    return _execute(args)


def _goal(args, settings) -> tuple[float, float, float]:
    x, y = settings.scene.object.position_m
    return (x + DEMO_PUSH_M, y, 0.0) if args.target is None else tuple(args.target)


def _execute(args) -> int:
    """The push closed loop through the nodes and open loop in process, in DEMO_WORLD, side by side."""
    from cito_ros.execution.episode import at_goal, run_open_loop
    from cito_ros.execution.estimator import tipped_over
    from cito_ros.execution.goal import ExecuteGoal
    from cito_ros.execution.world import Mismatch, SimulatedWorld
    from cito_ros.model.scene import start_configuration
    from cito_ros.ros.sim_session import Operator, robot_parameters, spawn, stop

    settings = load_settings()
    x, y, yaw = _goal(args, settings)
    goal = ExecuteGoal((x, y), yaw, args.contact_model)
    world = Mismatch("demo", **DEMO_WORLD)
    told = settings.scene.object
    print(f"\nexecuting it where the cube is heavier (mass x{world.mass_scale:g}) and grippier (friction "
          f"x{world.friction_scale:g}) than the model, {1000 * world.offset_m[0]:.0f} mm / {1000 * world.offset_m[1]:.0f} "
          f"mm / {world.offset_yaw_rad:g} rad off, seen by a noisy camera {1000 * world.latency_s:.0f} ms late:")
    open_world = SimulatedWorld(settings, world, start_configuration(settings.beta))
    opened = run_open_loop(settings, goal, open_world, (tuple(told.position_m), told.yaw_rad))
    domain = int(os.environ["ROS_DOMAIN_ID"])
    logs = args.bag_directory.resolve() / "logs"  # the nodes' own words, for an execution that went wrong
    logs.mkdir(parents=True, exist_ok=True)
    sim = spawn("cito-sim-robot", domain, *robot_parameters(world, settings.beta, 0), log=logs / "cito-sim-robot.log")
    node = spawn("cito-executor-node", domain, f"node.bag_directory:={args.bag_directory.resolve()}",
                 log=logs / "cito-executor-node.log")
    operator = Operator(domain)
    try:
        if not operator.wait_for_robot():
            print("cito-demo: the simulated robot or the executor node did not come up", file=sys.stderr)
            return 1
        closed = operator.execute(goal, settings.task.rest_speed_m_s)
    finally:
        operator.close()
        stop(node)
        stop(sim)
    result = closed.result
    # both on the world's truth (the executor's own verdict, from the camera, is in its message below)
    arrived = at_goal(settings.task, closed.at_rest, closed.position_error_m, closed.orientation_error_rad,
                      upright=not tipped_over(open_world.scene, closed.max_tilt_rad))
    print(f"  {'':24}{'open loop':>22}{'closed loop':>22}")
    print(f"  {'at the goal (2 cm, 0.15 rad)':<28}{'yes' if opened.success else 'no':>18}"
          f"{'yes' if arrived else 'no':>22}")
    print(f"  {'true error at rest':<28}{100 * opened.position_error_m:>11.2f} cm {opened.orientation_error_rad:.3f} rad"
          f"{100 * closed.position_error_m:>11.2f} cm {closed.orientation_error_rad:.3f} rad")
    replans = f"{result.replans} replans ({result.replan_rate_hz:.1f} Hz)" if result.replans else "no replans"
    print(f"  closed loop: {result.message}; {replans}; {closed.round_trip_s:.1f} s from goal to result")
    print(f"  bag                {result.bag_path}")
    if result.status == result.STATUS_STALE_MEASUREMENTS:
        print(f"  the nodes' logs    {logs}")
    return 0


def _call(args) -> tuple[int, bool]:
    """The plan through the planner node: the exit code, and whether the plan succeeded."""
    import rclpy
    from cito_msgs.action import PlanPush
    from rclpy.action import ActionClient

    settings = load_settings()
    target_x, target_y, yaw = _goal(args, settings)
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
            return 1, False
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
            return 1, False
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
            return 1, False
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
        return 0, r.success
    finally:
        client_node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
