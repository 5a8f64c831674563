"""The executor node and the simulated robot as a robot stack meets them: each in its own process, an action
client and subscribers in this one, over Fast DDS on an isolated domain. One execution at a time, cancel and
stale measurements hold the arm, and every execution's bag reads back."""
from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from action_msgs.msg import GoalStatus
from cito_msgs.action import ExecutePush
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from cito_ros.cli.closed_loop_ros import closed_loop_episode
from cito_ros.execution.goal import ExecuteGoal
from cito_ros.ros.sim_robot import TRUTH_EVERY
from cito_ros.ros.sim_session import BIN, Operator, stop
from cito_ros.studies import closed_loop, targets

from node_harness import launch, read_with_mcap, read_with_rosbags, wait_for_bag

Result = ExecutePush.Result
GOAL = ExecuteGoal((1.09, 0.03), 0.0, "vscm")  # 10 cm from q0(beta = 7), inside the steady push reach


# These two run first, alone with their own robot: the module's robot below stays up until the module ends,
# and on a 2-core machine its simulation would take CPU from their plans.


def test_stale_measurements_stop_the_execution_safely(tmp_path):
    """The robot goes silent mid-execution (its driver killed): the executor ends with its status, holding."""
    domain = 191 + os.getpid() % 20
    sim = launch("cito-sim-robot", domain, "beta:=7.0")
    # 0.3 s, not the default 0.1 s: the start state must be fresh when the goal arrives, on a busy 2-core machine
    node = launch("cito-executor-node", domain, f"node.bag_directory:={tmp_path}", "executor.stale_after_s:=0.3")
    operator = Operator(domain)
    try:
        assert operator.wait_for_robot(), "the simulated robot or the executor node did not come up"
        handle = operator.start(GOAL)
        assert operator.feedback, f"the execution did not begin: {operator.wait(handle.get_result_async()).result}"
        sim.kill()
        result = operator.wait(handle.get_result_async(), 60.0).result
        assert result.status == Result.STATUS_STALE_MEASUREMENTS and not result.success
        assert "no joint states" in result.message or "no cube poses" in result.message
        assert node.poll() is None
        assert wait_for_bag(Path(result.bag_path))
    finally:
        operator.close()
        stop(node)
        stop(sim)


def test_the_executor_brings_the_cube_to_the_goal_in_a_world_that_open_loop_misses(tmp_path, settings, scenes):
    """A 10 cm straight push in the heavy, high-friction corner world, with the cube 15 mm off along both axes and
    0.1 rad turned from where the planner is told and a late, noisy camera: the plan by a joint trajectory
    controller misses it (open loop: 2.60 cm and 0.185 rad off), the executor node and the simulated robot over DDS
    reach it, judged on the simulator's true cube at rest. Not always: 25 of 25 episodes in one node at 4920391 (a
    median 0.56 cm, the worst 1.32 cm), 19 of 20 runs of this test alone at 51f2654 (the miss: the cube left 2.4 cm
    beside the goal), and it failed 1 of the 4 full test runs since 4920391 (and CI once before it), the cube left
    turned 0.19-0.21 rad: 2 misses in the 77 runs and episodes since 4920391 (docs/results.md, the README's two
    commands), the executor's own rate on this goal."""
    goal = targets.Goal(0, 7.0, (1.09, 0.0), 0.0, 0.10, 0.0)
    world = closed_loop.WORLDS[3]
    opened = closed_loop.episode(goal, world, "open_loop", "vscm", settings)
    assert not opened["success"] and opened["place"] in ("short", "past", "beside", "turned"), opened
    domain = 171 + os.getpid() % 20
    node = launch("cito-executor-node", domain, f"node.bag_directory:={tmp_path}")
    operator = Operator(domain)
    try:
        closed = closed_loop_episode(operator, domain, goal, world, "vscm", settings, 0.0, scenes["vscm"])
        # a string: pytest shortens a dict in the message to its first items
        verdict = str({k: closed[k] for k in ("success", "position_error_m", "orientation_error_rad", "at_rest",
                                              "tipped", "max_joint_speed_ratio", "ending", "message", "phases")})
        assert closed["success"], verdict
        assert closed["max_joint_speed_ratio"] <= 1.0, verdict
        assert closed["cause"] == "succeeded" and closed["pushes"] >= 1 and closed["place"] == "goal", verdict
        assert node.poll() is None
    finally:
        operator.close()
        stop(node)


def test_an_execution_plans_from_the_cube_the_camera_sees_now_not_from_poses_before_a_gap(tmp_path):
    """The robot is replaced while no execution runs (its driver restarted, a new scene: here a simulated robot
    whose cube is 3 cm further along y): the next execution's first push is planned from the new robot's cube, not
    from a mean with the poses the node kept from before (older than executor.stale_after_s)."""
    domain = 171 + os.getpid() % 20
    # stale after 2 s, as for the module's robot below: a new simulated robot's first second can stall its poses
    node = launch("cito-executor-node", domain, f"node.bag_directory:={tmp_path}", "executor.stale_after_s:=2.0")
    operator = Operator(domain)
    sim = launch("cito-sim-robot", domain, "beta:=7.0", "offset_y_m:=0.03")
    try:
        assert operator.wait_for_robot(), "the simulated robot or the executor node did not come up"
        operator.spin(1.0)  # the node keeps the last few cube poses, 3 cm along y
        stop(sim)
        operator.spin(2.5)  # those poses older than stale_after_s now
        sim = launch("cito-sim-robot", domain, "beta:=7.0")
        assert operator.wait_for_robot()
        handle = operator.start(GOAL)
        assert operator.feedback, f"the execution did not begin: {operator.wait(handle.get_result_async()).result}"
        ending = handle.get_result_async()
        operator.spin_until(lambda: any(f.phase == "pushing" for f in operator.feedback) or ending.done(), 120.0)
        assert not ending.done(), ending.result().result.message
        operator.wait(handle.cancel_goal_async(), 30.0)
        result = operator.wait(ending).result
        bag = Path(result.bag_path)
        assert wait_for_bag(bag)
        recorded = read_with_mcap(bag)
        seen = np.array([[m.pose.position.x, m.pose.position.y] for _, m in recorded["/object/pose"][:10]])
        first = recorded["/cito/predicted_object_path"][0][1].poses[0].pose.position
        assert np.hypot(first.x - seen[:, 0].mean(), first.y - seen[:, 1].mean()) < 0.003, (first, seen.mean(axis=0))
    finally:
        operator.close()
        stop(node)
        stop(sim)


def logged(log: Path, text: str, process: subprocess.Popen, timeout_s: float = 60.0) -> bool:
    """Whether `text` appears in a node's log within timeout_s, while the node runs."""
    deadline = time.monotonic() + timeout_s
    while text not in log.read_text() and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.1)
    return text in log.read_text()


def test_the_simulated_robot_says_when_it_fell_behind_real_time(tmp_path):
    """Suspended for 0.4 s (as a starved core would hold it), the simulation says how far it fell behind: its
    measurements stopped meanwhile, which an executor sees as stale."""
    log = tmp_path / "cito-sim-robot.log"
    sim = launch("cito-sim-robot", 151 + os.getpid() % 20, log=log)
    try:
        assert logged(log, "simulating", sim), log.read_text()
        time.sleep(1.0)
        assert "behind real time" not in log.read_text()
        sim.send_signal(signal.SIGSTOP)
        time.sleep(0.4)
        sim.send_signal(signal.SIGCONT)
        time.sleep(1.0)
        lags = [float(line.split("fell ")[1].split(" s")[0]) for line in log.read_text().splitlines()
                if "behind real time" in line]
        assert lags and max(lags) >= 0.35, log.read_text()
    finally:
        stop(sim)


def test_the_simulated_robots_joint_speed_peaks_are_the_largest_speeds_of_its_joint_states(tmp_path):
    """A judge that takes /sim/joint_speed_peaks at 20 Hz sees the largest speed every joint had in the joint states
    of those steps, to the bit: the arm falling under zero torques (the robot adds no gravity compensation)."""
    domain = 171 + os.getpid() % 20
    sim = launch("cito-sim-robot", domain, "beta:=7.0")
    operator = Operator(domain)  # the judge: it takes the peaks; here it takes every joint state too
    states, peaks = [], operator.speed_peaks
    qos = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)
    operator.node.create_subscription(JointState, "/joint_states", states.append, qos)
    commands = operator.node.create_publisher(Float64MultiArray, "/effort_controller/commands", qos)
    try:
        assert operator.spin_until(lambda: len(peaks) >= 2, 60.0), "no joint speed peaks from the simulated robot"
        states.clear()
        peaks.clear()
        began = time.monotonic()
        while time.monotonic() - began < 1.5:
            commands.publish(Float64MultiArray(data=[0.0] * 7))
            operator.executor.spin_once(timeout_sec=0.005)
    finally:
        operator.close()
        stop(sim)

    def stamp(message) -> int:
        return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec

    # a peak goes out with the joint state of its last step, under the same header
    stamps = [stamp(m) for m in states]
    index = {s: i for i, s in enumerate(stamps)}
    step_ns = float(np.median(np.diff(stamps)))
    windows = 0
    for peak in peaks[1:]:
        last = index.get(stamp(peak))
        if last is None or last < TRUTH_EVERY - 1:
            continue
        window = range(last - TRUTH_EVERY + 1, last + 1)
        gaps = np.diff([stamps[i] for i in window])
        if np.all(np.abs(gaps - step_ns) < 0.5 * step_ns):  # every joint state of its steps came
            windows += 1
            assert np.array_equal(np.max([np.abs(states[i].velocity) for i in window], axis=0),
                                  np.asarray(peak.velocity)), stamp(peak)
    assert windows >= 10, f"{windows} windows with all their joint states of {len(peaks)} peaks"
    assert max(max(p.velocity) for p in peaks) > 0.05  # the arm moved


def test_ctrl_c_stops_the_node_and_its_planner_process_quietly(tmp_path):
    """A terminal's Ctrl-C reaches the node's whole process group, its planner's process too: the node shuts down
    with exit code 0, and no process prints a traceback."""
    log = tmp_path / "cito-executor-node.log"
    env = dict(os.environ, ROS_DOMAIN_ID=str(131 + os.getpid() % 20), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    with open(log, "wb") as output:
        node = subprocess.Popen([str(BIN / "cito-executor-node"), "--ros-args", "-p", f"node.bag_directory:={tmp_path}"],
                                env=env, stdout=output, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        assert logged(log, "ready", node), log.read_text()
        os.killpg(node.pid, signal.SIGINT)
        assert node.wait(timeout=20.0) == 0, log.read_text()
        time.sleep(0.5)  # the planner's process, if it outlived the node, has had its say
        assert "shutting down" in log.read_text() and "Traceback" not in log.read_text(), log.read_text()
    finally:
        if node.poll() is None:
            os.killpg(node.pid, signal.SIGKILL)


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    """The simulated robot (the cube 3 cm off sideways from where the planner is told, a late, noisy camera) and
    the executor node, and an operator."""
    domain = 211 + os.getpid() % 20  # Fast DDS takes domains up to 232
    bags = tmp_path_factory.mktemp("execution_bags")
    sim = launch("cito-sim-robot", domain, "beta:=7.0", "offset_y_m:=0.03", "pose_noise_m:=0.001", "latency_s:=0.03")
    # measurements count as stale only after 2 s here: on this 2-core machine, with the planner, the robot and
    # this test all busy, the node has gone 0.5 s without a cube pose (2 of 3 runs at 437c323); these tests are
    # about rejection, cancel and the bag, the stale test above is about staleness
    node = launch("cito-executor-node", domain, f"node.bag_directory:={bags}", "executor.stale_after_s:=2.0")
    operator = Operator(domain)
    try:
        assert operator.wait_for_robot(), "the simulated robot or the executor node did not come up"
        yield operator, sim, node
    finally:
        operator.close()
        stop(node)
        stop(sim)


def test_a_bad_goal_is_refused_with_its_reason_and_the_node_serves_the_next(robot):
    operator, sim, node = robot
    for goal, reason in ((dataclasses.replace(GOAL, contact_model="rigid"), "unknown contact model 'rigid'"),
                         (dataclasses.replace(GOAL, time_limit_s=-1.0), "time_limit_s must be a non-negative"),
                         (dataclasses.replace(GOAL, scene="no_such_scene"), "unknown scene 'no_such_scene'")):
        handle = operator.send(goal)
        assert handle.accepted
        result = operator.wait(handle.get_result_async()).result
        assert result.status == Result.STATUS_INVALID_REQUEST and not result.success
        assert reason in result.message, result.message
    assert sim.poll() is None and node.poll() is None
    handle = operator.start(GOAL)  # and the next goal runs (sent again while the node's measurements are not fresh)
    assert handle.accepted
    operator.wait(handle.cancel_goal_async(), 30.0)
    assert operator.wait(handle.get_result_async()).result.status == Result.STATUS_CANCELLED


def test_a_second_goal_is_rejected_while_one_runs_and_a_cancel_holds_the_arm(robot):
    operator, sim, node = robot
    running = operator.send(GOAL)
    assert running.accepted
    assert not operator.send(GOAL).accepted  # one execution at a time
    operator.spin(1.0)
    answer = operator.wait(running.cancel_goal_async(), 30.0)
    assert len(answer.goals_canceling) == 1
    result = operator.wait(running.get_result_async())
    assert result.status == GoalStatus.STATUS_CANCELED, result.result.message
    assert result.result.status == Result.STATUS_CANCELLED and not result.result.success
    assert "held" in result.result.message
    operator.speed_peaks.clear()
    operator.spin(1.5)  # after the cancel the arm is held: it comes to rest and stays
    speeds = np.array([max(m.velocity) for m in operator.speed_peaks[-4:]])  # its last 40 steps
    assert len(speeds) == 4 and speeds.max() < 0.05
    assert sim.poll() is None and node.poll() is None


def test_an_execution_is_recorded_and_its_bag_reads_back(robot):
    operator, _, _ = robot
    operator.feedback.clear()
    handle = operator.send(GOAL)
    assert handle.accepted
    result = operator.wait(handle.get_result_async()).result
    assert result.status in (Result.STATUS_SUCCEEDED, Result.STATUS_TASK_NOT_ACHIEVED, Result.STATUS_TIME_LIMIT,
                             Result.STATUS_INVALID_REQUEST), result.message
    assert operator.feedback and {f.phase for f in operator.feedback} <= {"planning", "pushing", "settling", "retreating", "done"}
    bag = Path(result.bag_path)
    assert wait_for_bag(bag)
    for reader in (read_with_mcap, read_with_rosbags):
        recorded = reader(bag)
        assert set(recorded) >= {"/joint_states", "/object/pose", "/effort_controller/commands"}
        assert len(recorded["/joint_states"]) > 100 and len(recorded["/effort_controller/commands"]) > 100, \
            (result.status, result.message, {topic: len(messages) for topic, messages in recorded.items()})
        assert all(len(m.data) == 7 for _, m in recorded["/effort_controller/commands"][:10])
    if result.replans:
        assert read_with_rosbags(bag)["/cito/predicted_object_path"]
