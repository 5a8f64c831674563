"""cito-sim-robot: the arm and the cube simulated in MuJoCo in real time, in a world that may differ from the
planner's model, behind the interfaces of a ros2_control robot and a camera.

    cito-sim-robot [--ros-args -p friction_scale:=0.5 -p mass_scale:=2.0 -p offset_x_m:=0.015 ...]

It takes joint torques on /effort_controller/commands (std_msgs/Float64MultiArray: seven total torques, N m,
for j0..j6, as ros2_control's JointGroupEffortController; the robot adds no gravity compensation) and applies
the last one every step, clamped to the motor limits. When no command has come for command_timeout_s it holds
the joints where they were (a stiff PD plus the arm's bias forces: a robot's safety hold) until one comes. It
publishes /joint_states (sensor_msgs/JointState, j0..j6) every step and /object/pose (geometry_msgs/PoseStamped,
frame world) at the camera's rate, noisy and late by its latency; for judging only, at 20 Hz,
/sim/true_object_pose and /sim/joint_speed_peaks (sensor_msgs/JointState, j0..j6: in velocity each joint's largest
|speed| over the steps since the last, so a judge need not take every joint state: 200 a second cost its Python
a third of a core, which the planner beside it then lacked). The declared parameters set the world's differences
from the planner's model (the default is the nominal world: none); cito_ros.execution.world is the world itself.
"""
from __future__ import annotations

import sys
import threading
import time

import mujoco
import numpy as np
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, Header

from cito_ros.execution.policy import hold_torques
from cito_ros.execution.world import Mismatch, SimulatedWorld
from cito_ros.model.scene import ARM_JOINTS, start_configuration
from cito_ros.ros.messages import pose_msg, time_msg
from cito_ros.ros.process import LoopNode, run
from cito_ros.settings import SceneConfig, load_settings

TRUTH_EVERY = 10  # steps: the truth for judging (the true pose, the joint speed peaks) at 20 Hz
RESYNC_S = 0.05  # a simulation that falls this far behind real time drops the lag rather than racing to catch up
# name -> (default, description)
PARAMETERS = {
    "scene": ("default", "the world's scene in config/scenes, before the differences below"),
    "beta": (5.0, "the arm's start pose q0(beta)"),
    "friction_scale": (1.0, "the cube's friction: this times the scene's"),
    "mass_scale": (1.0, "the cube's mass: this times the scene's"),
    "offset_x_m": (0.0, "the cube stands this far along x from the scene's pose (m)"),
    "offset_y_m": (0.0, "and along y (m)"),
    "offset_yaw_rad": (0.0, "turned this far about z (rad)"),
    "pose_noise_m": (0.0, "the camera's position noise, standard deviation per axis (m)"),
    "yaw_noise_rad": (0.0, "the camera's yaw noise, standard deviation (rad)"),
    "latency_s": (0.0, "a cube pose arrives this long after the instant it shows (s)"),
    "camera_rate_hz": (30.0, "cube poses a second"),
    "command_timeout_s": (0.05, "commands older than this: the joints are held where they are (s)"),
    "seed": (0, "of the camera's noise"),
}


class SimRobot(Node):
    def __init__(self):
        super().__init__("cito_sim_robot")
        values = {}
        for name, (default, description) in PARAMETERS.items():
            kind = {str: ParameterType.PARAMETER_STRING, float: ParameterType.PARAMETER_DOUBLE,
                    int: ParameterType.PARAMETER_INTEGER}[type(default)]
            values[name] = self.declare_parameter(name, default, ParameterDescriptor(
                description=description, type=kind, read_only=True)).value
        settings = load_settings()
        self.mismatch = Mismatch(
            "parameters", values["friction_scale"], values["mass_scale"], (values["offset_x_m"], values["offset_y_m"]),
            values["offset_yaw_rad"], values["pose_noise_m"], values["yaw_noise_rad"], values["latency_s"],
            values["camera_rate_hz"])
        self.world = SimulatedWorld(settings, self.mismatch, start_configuration(values["beta"]),
                                    SceneConfig.load(values["scene"]), seed=values["seed"])
        self.command_timeout_s = values["command_timeout_s"]
        self._kp, self._kd = np.asarray(settings.tracking.kp), np.asarray(settings.tracking.kd)
        self._data = mujoco.MjData(self.world.model)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.joint_states = self.create_publisher(JointState, "/joint_states", qos)
        self.object_pose = self.create_publisher(PoseStamped, "/object/pose", qos)
        self.true_pose = self.create_publisher(PoseStamped, "/sim/true_object_pose", qos)
        self.speed_peaks = self.create_publisher(JointState, "/sim/joint_speed_peaks", qos)
        self._command: tuple[float, np.ndarray] | None = None  # (arrival, torques)
        self._held: np.ndarray | None = None
        # the commands in a loop node: every one taken as it comes, beside the parameter services
        self._commands = LoopNode("cito_sim_robot_commands")
        self._commands.node.create_subscription(Float64MultiArray, "/effort_controller/commands", self._on_command,
                                                qos)
        self._commands.start()
        self.stopping = threading.Event()
        self._thread = threading.Thread(target=self._run, name="cito_sim_robot", daemon=True)
        self._thread.start()
        self.get_logger().info(f"simulating: friction x{self.mismatch.friction_scale:g}, mass x{self.mismatch.mass_scale:g}, "
                               f"cube off by {self.mismatch.offset_m} m and {self.mismatch.offset_yaw_rad:g} rad")

    def stop(self, timeout_s: float) -> None:
        self.stopping.set()
        self._thread.join(timeout_s)

    def destroy_node(self) -> None:
        self._commands.destroy()
        super().destroy_node()

    def _on_command(self, message: Float64MultiArray) -> None:
        if len(message.data) != len(ARM_JOINTS) or not np.all(np.isfinite(message.data)):
            self.get_logger().warning(f"ignored a command of {len(message.data)} values (7 finite torques expected)",
                                      throttle_duration_sec=1.0)
            return
        self._command = (time.time(), np.array(message.data, dtype=float))

    def _torques(self, now: float) -> np.ndarray:
        """The last command, or the safety hold when it is older than command_timeout_s."""
        joints = self.world.joints()
        if self._command is not None and now - self._command[0] <= self.command_timeout_s:
            self._held = None
            return self._command[1]
        if self._held is None:
            self._held = joints.q.copy()
        return hold_torques(self.world.scene, self._data, self._kp, self._kd, self._held, joints.q, joints.qdot)

    def _run(self) -> None:
        world = self.world
        origin = time.time()
        peaks = np.zeros(len(ARM_JOINTS))  # |joint speed| since the last truth published
        while not self.stopping.is_set():
            due = origin + world.time_s
            late = time.time() - due
            if late > RESYNC_S:
                # a stall (a starved core, a suspended process): said, as the robot's measurements stopped meanwhile
                self.get_logger().warning(f"the simulation fell {late:.3f} s behind real time at {world.time_s:.3f} s "
                                          f"of its clock: it goes on from there, its stamps {late:.3f} s later")
                origin += late
            elif late < 0:
                time.sleep(-late)
            world.step(self._torques(time.time()))
            stamp = origin + world.time_s
            joints = world.joints()
            header = Header(stamp=time_msg(int(stamp * 1e9)), frame_id="world")
            self.joint_states.publish(JointState(header=header, name=list(ARM_JOINTS), position=joints.q.tolist(),
                                                 velocity=joints.qdot.tolist(), effort=joints.effort.tolist()))
            for reading in world.camera():
                self.object_pose.publish(PoseStamped(
                    header=Header(stamp=time_msg(int((origin + reading.stamp_s) * 1e9)), frame_id="world"),
                    pose=pose_msg(reading.position_m, reading.quaternion)))
            np.maximum(peaks, np.abs(joints.qdot), out=peaks)
            if round(world.time_s / world.timestep_s) % TRUTH_EVERY == 0:
                position, quaternion = world.true_object_pose()
                self.true_pose.publish(PoseStamped(header=header, pose=pose_msg(position, quaternion)))
                self.speed_peaks.publish(JointState(header=header, name=list(ARM_JOINTS), velocity=peaks.tolist()))
                peaks[:] = 0.0


def main(argv: list[str] | None = None) -> int:
    # the stepping thread must get the GIL back as soon as a step is due, not after the callbacks' 5 ms default
    sys.setswitchinterval(5e-4)
    return run(SimRobot, "cito-sim-robot", argv, params_file=False, threads=2)


if __name__ == "__main__":
    sys.exit(main())
