"""`cito-bench round-trip`: how long a caller of the node waits beyond the solve, and when the bag is done.

The planner node runs in its own process (an isolated ROS domain, this host only); a client in this
process sends seeded short pushes (3-12 cm within 30 degrees of +x, from q0(beta = 7)) one after the other,
first as service calls, then as action goals. Per request: the round trip (request sent to answer
received), the solve time the answer reports (`metrics.solve_time_s`), and how long after the answer its bag
was complete (its final name and metadata in place). The figures are medians and 90th percentiles.
"""
from __future__ import annotations

import math
import os
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cito_ros.model.scene import TABLE_TOP_Z_M, start_configuration
from cito_ros.settings import load_settings

PUSH_RANGE_M = (0.03, 0.12)
DIRECTION_RANGE_RAD = math.radians(30.0)
BETA = 7.0


def goals(n: int, seed: int) -> list[tuple[float, float]]:
    """n seeded short-push targets (x, y) from the default scene's cube."""
    x0, y0 = load_settings().scene.object.position_m
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        push, direction = rng.uniform(*PUSH_RANGE_M), rng.uniform(-DIRECTION_RANGE_RAD, DIRECTION_RANGE_RAD)
        out.append((x0 + push * math.cos(direction), y0 + push * math.sin(direction)))
    return out


def _summary(values: list[float]) -> dict[str, float]:
    return {"median": float(statistics.median(values)), "p90": float(np.percentile(values, 90))}


def round_trip_benchmark(n: int = 20, seed: int = 0, progress=None) -> dict:
    """Service calls, then action goals, for n seeded short pushes; see the module docstring."""
    import rclpy
    from cito_msgs.action import PlanPush as PlanPushAction
    from cito_msgs.srv import PlanPush
    from rclpy.action import ActionClient

    domain = str(random.randint(101, 200))
    env = dict(os.environ, ROS_DOMAIN_ID=domain, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    settings = load_settings()
    start = start_configuration(BETA)
    z = TABLE_TOP_Z_M + settings.scene.object.half_size_m
    with tempfile.TemporaryDirectory(prefix="cito-round-trip-") as bags:
        node = subprocess.Popen([str(Path(sys.executable).parent / "cito-planner-node"), "--ros-args", "-p",
                                 f"node.bag_directory:={bags}", "--log-level", "warn"], env=env)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=int(domain))
        client_node = rclpy.create_node("cito_round_trip", context=context)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(client_node)
        try:
            service = client_node.create_client(PlanPush, "/cito/plan_push")
            action = ActionClient(client_node, PlanPushAction, "/cito/plan_push")
            if not (service.wait_for_service(timeout_sec=60.0) and action.wait_for_server(timeout_sec=60.0)):
                raise RuntimeError("the planner node did not come up")

            def wait(future, timeout_s: float = 300.0):
                executor.spin_until_future_complete(future, timeout_sec=timeout_s)
                if not future.done():
                    raise RuntimeError("no answer from the planner node")
                return future.result()

            def fill(message, target):
                message.target_pose.position.x, message.target_pose.position.y = target
                message.target_pose.position.z, message.target_pose.orientation.w = z, 1.0
                message.contact_model = "vscm"
                message.start_state.name = [f"j{i}" for i in range(7)]
                message.start_state.position = [float(v) for v in start]
                return message

            runs = []
            for kind in ("service", "action"):
                for index, target in enumerate(goals(n, seed)):
                    sent = time.perf_counter()
                    if kind == "service":
                        answer = wait(service.call_async(fill(PlanPush.Request(), target)))
                    else:
                        handle = wait(action.send_goal_async(fill(PlanPushAction.Goal(), target)))
                        answer = wait(handle.get_result_async()).result
                    answered = time.perf_counter()
                    bag = Path(answer.bag_path)
                    while not (bag / "metadata.yaml").is_file() and time.perf_counter() - answered < 60.0:
                        time.sleep(0.002)
                    complete = time.perf_counter() if (bag / "metadata.yaml").is_file() else math.nan
                    runs.append({"kind": kind, "goal": index, "success": bool(answer.success),
                                 "round_trip_s": answered - sent, "solve_time_s": answer.metrics.solve_time_s,
                                 "bag_after_answer_s": complete - answered})
                    if progress is not None:
                        progress(len(runs), 2 * n)
        finally:
            executor.shutdown()
            client_node.destroy_node()
            rclpy.try_shutdown(context=context)
            node.send_signal(2)
            try:
                node.wait(timeout=60)
            except subprocess.TimeoutExpired:
                node.kill()
    report = {"requests": n, "seed": seed}
    for kind in ("service", "action"):
        rows = [r for r in runs if r["kind"] == kind]
        round_trip, solve = _summary([r["round_trip_s"] for r in rows]), _summary([r["solve_time_s"] for r in rows])
        report[kind] = {
            "successes": sum(r["success"] for r in rows),
            "round_trip_s": round_trip, "solve_time_s": solve,
            "median_round_trip_minus_median_solve_s": round_trip["median"] - solve["median"],
            "round_trip_minus_solve_s": _summary([r["round_trip_s"] - r["solve_time_s"] for r in rows]),
            "bag_after_answer_s": _summary([r["bag_after_answer_s"] for r in rows]),
            "bags_incomplete": sum(math.isnan(r["bag_after_answer_s"]) for r in rows),
        }
    report["runs"] = runs
    return report


def report_text(report: dict) -> str:
    lines = [f"{report['requests']} seeded short pushes from q0(beta = {BETA:g}), one after the other (ms: median / p90):",
             "", "| through | successes | round trip | solve | round trip - solve | median round trip - median solve "
             "| bag complete after the answer |", "|---|---|---|---|---|---|---|"]
    for kind in ("service", "action"):
        r = report[kind]

        def ms(entry):
            return f"{1e3 * entry['median']:.0f} / {1e3 * entry['p90']:.0f}"

        lines.append(f"| {kind} | {r['successes']}/{report['requests']} | {ms(r['round_trip_s'])} | "
                     f"{ms(r['solve_time_s'])} | {ms(r['round_trip_minus_solve_s'])} | "
                     f"{1e3 * r['median_round_trip_minus_median_solve_s']:.0f} | {ms(r['bag_after_answer_s'])} |")
    return "\n".join(lines)
