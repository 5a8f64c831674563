"""How every node of this package runs as a process: its parameters, its signals, its spin, its shutdown.

A node is made after rclpy is initialised; a ValueError or KeyError while it is made (bad parameters) ends
the process with exit code 2 and the reason on stderr. SIGINT and SIGTERM stop the spin loop (a
`while ok: spin_once` loop: rclpy.spin could hang on a SIGTERM that arrived early), then the node's own
stop(timeout_s) finishes its work (bags, a held arm) before it is destroyed.
"""
from __future__ import annotations

import signal
import sys
import threading
from typing import Callable

import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from cito_ros.settings.paths import config_path


def with_params_file(args: list[str]) -> list[str]:
    """args with the package's config/planner.yaml as the params file, unless one is given: first among the
    ROS arguments, so that the caller's -p overrides come after it."""
    if "--params-file" in args:
        return args
    default = ["--params-file", str(config_path("planner.yaml"))]
    if "--ros-args" in args:
        at = args.index("--ros-args") + 1
        return args[:at] + default + args[at:]
    return args + ["--ros-args", *default]


def run(make_node: Callable[[], Node], program: str, argv: list[str] | None = None, *, params_file: bool = True,
        threads: int = 4, stop_timeout_s: float = 4.0) -> int:
    """Run the node make_node() makes until SIGINT or SIGTERM; the process's exit code."""
    args = list(sys.argv if argv is None else argv)
    rclpy.init(args=with_params_file(args) if params_file else args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    try:
        node = make_node()
    except (ValueError, KeyError) as error:
        print(f"{program}: bad parameters: {error}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = MultiThreadedExecutor(num_threads=threads)
    executor.add_node(node)
    try:
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    finally:
        node.get_logger().info("shutting down")
        node.stop(timeout_s=stop_timeout_s)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


class LoopNode:
    """A node of its own for a control loop's subscriptions, spun in a thread of its own by rclpy's EventsExecutor:
    its callbacks then wait behind no other entity. rclpy's Python executors rebuild the wait set of all of a
    node's entities for every callback: for a subscription at 200 Hz that took most of a core beside an action
    server, and 15 % of one alone, against 7 % with the EventsExecutor (docs/results.md: Through the nodes). Its
    spin() in a thread took a core and delivered nothing (rclpy 7.1.5): it is spun by spin_once. Start it once
    everything its callbacks use exists."""

    def __init__(self, name: str):
        self.node = Node(name, start_parameter_services=False)
        self._executor = EventsExecutor()
        self._executor.add_node(self.node)
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._spin, name=name, daemon=True)

    def _spin(self) -> None:
        while not self._stopping.is_set() and rclpy.ok():
            self._executor.spin_once(timeout_sec=0.1)

    def start(self) -> None:
        self._thread.start()

    def destroy(self) -> None:
        self._stopping.set()
        self._thread.join(2.0)
        self._executor.shutdown()
        self.node.destroy_node()
