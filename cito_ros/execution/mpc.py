"""Receding-horizon replanning from the measured state (MPC), and the policy of a plan.

`PushModel` is the planner's model of a goal's pushes for the executor: the scene, the task of each push (to the
goal, or to the waypoint it was planned to: the replans of a push keep its target), and the cost the replans
minimize (the physical pipeline's stage without the virtual force that every start runs after its first: its
contact, joint-limit and object-velocity terms). `policy` turns knot torques into a `Policy`: their rollout in
the model from a state is the reference, and the feedback gains come from iLQR's backward pass there. `replan` is
one MPC step: the push from the estimated state to the end of the push, in whole knots, warm-started from the
running policy shifted in time, for a few iLQR iterations within a time budget; its gains are those of the last
backward pass whose step was kept.
"""
from __future__ import annotations

import dataclasses
import math
import time
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from cito_ros.execution.policy import SPEED_GUARD, Policy
from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene, start_configuration
from cito_ros.model.simulator import Simulator
from cito_ros.planner import tracking
from cito_ros.planner.builder import PushRequest, make_task, scene_config
from cito_ros.planner.problem import PushProblem
from cito_ros.planner.results import world_ratio
from cito_ros.planner.task import PushTask
from cito_ros.planner.solvers.base import IterationMonitor
from cito_ros.planner.solvers.ilqr import IlqrSolver, feedback_gains
from cito_ros.planner.stages import stage_cost, touch_profile
from cito_ros.settings import SceneConfig, Settings, TrackingSettings

if TYPE_CHECKING:
    from cito_ros.execution.goal import ExecuteGoal

REPLAN_STAGE = 1  # the physical stage whose weights the replans take: the one every start runs after its first


def executor_costs(settings: Settings) -> Settings:
    """The settings with the executor's stage costs (executor.orientation_balance), for its plans and replans alike."""
    return settings.with_overrides({"stages.orientation_balance": settings.executor.orientation_balance})


def servo_gains(settings: Settings) -> tuple[np.ndarray, np.ndarray]:
    """The executor's joint servo: tracking.kp and kd times executor.servo_gain_scale."""
    scale = settings.executor.servo_gain_scale
    return scale * np.asarray(settings.tracking.kp), scale * np.asarray(settings.tracking.kd)


def servo_tracking(settings: Settings, worlds: list | None = None) -> TrackingSettings:
    """The executor's servo as the tracking that checks its pushes (cito_ros.planner.tracking): servo_gains with the
    plan's torques as feed-forward, its speed guard, in the worlds of `worlds` (friction and mass scales; None:
    executor.world_*_scales)."""
    executor, (kp, kd) = settings.executor, servo_gains(settings)
    friction, mass = worlds if worlds else (executor.world_friction_scales, executor.world_mass_scales)
    return dataclasses.replace(settings.tracking, kp=tuple(kp.tolist()), kd=tuple(kd.tolist()), feed_forward=True,
                               speed_guard=SPEED_GUARD, speed_horizon_s=executor.speed_horizon_s,
                               world_friction_scales=tuple(float(v) for v in friction),
                               world_mass_scales=tuple(float(v) for v in mass))


class PushModel:
    """The planner's model of one push (see the module docstring)."""

    def __init__(self, settings: Settings, contact_model_name: str, config: SceneConfig, target_position_m,
                 target_yaw_rad: float, object_scales: tuple[float, float] = (1.0, 1.0)):
        self.settings, self.object_scales = executor_costs(settings), object_scales
        self.scene = Scene(contact_model(contact_model_name, settings.contact_models), config)
        # the cube at rest in the model, the arm anywhere: the cube's resting height, and the goal checked there
        self.resting_state = self.scene.initial_state(start_configuration(settings.beta))
        self.task = make_task(self.scene, self.resting_state, target_position_m, target_yaw_rad, settings)
        self.control_period_s = settings.control_period_s
        self.servo_gains = servo_gains(settings)
        self.servo_tracking = servo_tracking(settings)
        self._gradient = dataclasses.replace(settings.gradient, stride=settings.executor.replan_stride,  # replans'
                                             switches=settings.executor.replan_switches)
        self._simulators: dict[int, Simulator] = {}
        self._tasks: dict[tuple, PushTask] = {}
        self._data = mujoco.MjData(self.scene.model)

    def task_to(self, target: tuple[tuple[float, float], float] | None) -> PushTask:
        """The push's task: to `target` ((x, y), yaw: a waypoint), or to the goal (None)."""
        if target is None:
            return self.task
        (x, y), yaw = target
        key = (float(x), float(y), float(yaw))
        if key not in self._tasks:  # the yaw as given (the measured cube's equivalent), not the nearest the model's
            self._tasks[key] = dataclasses.replace(
                make_task(self.scene, self.resting_state, np.array([x, y]), yaw, self.settings), target_yaw_rad=yaw)
        return self._tasks[key]

    def draw_back_q(self, state: np.ndarray) -> np.ndarray | None:
        """The scene's start pose (settings.beta) when the arm in `state` is within executor.start_clearance_m of
        the cube (an execution begun where a last one ended or was cancelled: a push planned from against the cube
        would start in it) and that pose is clear of the cube by more; None otherwise."""
        clearance_m, data, model = self.settings.executor.start_clearance_m, self._data, self.scene.model
        mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        mujoco.mj_forward(model, data)
        if self.scene.arm_clearance(data, clearance_m)[0] >= clearance_m:
            return None
        home_q = start_configuration(self.settings.beta)
        data.qpos[self.scene.arm_qpos_adr] = home_q
        mujoco.mj_forward(model, data)
        return home_q if self.scene.arm_clearance(data, clearance_m)[0] >= clearance_m else None

    def simulator(self, knots: int) -> Simulator:
        """The model's simulator of a push over `knots` knots (built once per length)."""
        if knots not in self._simulators:
            self._simulators[knots] = Simulator(self.scene, knots * self.control_period_s, self.control_period_s,
                                                nthread=self.settings.gradient.threads)
        return self._simulators[knots]

    def problem(self, state: np.ndarray, knots: int, torques: np.ndarray, task: PushTask) -> PushProblem:
        """The push to `task` from `state` over `knots` knots without the virtual force, its contact term from
        where `torques` first touch the cube."""
        simulator = self.simulator(knots)
        settings, weights = self.settings, getattr(self.settings.weights, self.scene.contact_model.name)
        stage = list(settings.stages.physical)[REPLAN_STAGE]
        bare = PushProblem(simulator, state, task, stage_cost(settings, weights, False, 0.0, None, 0.0, 0.0),
                           self._gradient, settings.task.position_error_scale_min_m)
        z = bare.with_torques(torques)
        touch = touch_profile(bare, z, settings.stages.touch_force_N)
        cost = stage_cost(settings, weights, False, stage.contact_weight, touch, stage.joint_speed_weight,
                          stage.joint_position_weight)
        problem = PushProblem(simulator, state, task, cost, self._gradient, settings.task.position_error_scale_min_m)
        rollout = bare.evaluate(z)  # the same rollout under this cost: simulated once
        problem.remember(z, rollout.states, rollout.sensordata, rollout.warnings)
        return problem

    def worst_world(self, simulator: Simulator, state: np.ndarray, reference, task: PushTask,
                    bound: float = math.inf) -> float:
        """The largest world_ratio (at rest against `task`, and the cube's tilt on the way) of `reference` (a
        Trajectory of `simulator`'s horizon) tracked by the servo from `state` (servo_tracking) in each world of
        executor.world_*_scales (below 1: sturdy there); above `bound`, the first world's above it (the rest are not
        tracked: a replan is rejected there whatever they give, and tracking them all was 40 % of a replan)."""
        def ratio(error: tracking.WorldErrors) -> float:
            return world_ratio(error, self.settings.task, self.servo_tracking.world_max_tilt_rad)

        errors = tracking.world_errors(simulator, state, reference, self.servo_tracking, task,
                                       tracking.WorldErrors(0.0, 0.0, 0.0), stop=lambda error: ratio(error) > bound)
        return max(map(ratio, errors), default=0.0)

    def policy(self, start_s: float, state: np.ndarray, torques: np.ndarray, gains: np.ndarray | None = None,
               problem: PushProblem | None = None, worst_world: float | None = None,
               target: tuple[tuple[float, float], float] | None = None, face: int = 0) -> Policy:
        """The policy of knot torques from `state` at start_s, a push to `target` (task_to): their rollout is the
        reference. Its gains on the cube's state are the backward pass's (given, or from a backward pass at the
        torques) times executor.object_gain_scale; on the arm's joints, the executor's servo PD (servo_gains): the
        backward pass's own arm gains are soft where the cost does not care where the arm is, and a heavier or
        grippier cube than the model's then pushes the arm off its path. Its worst_world is given, or computed here
        (where a push on `face` is replanned: executor.replans)."""
        task = self.task_to(target)
        problem = self.problem(state, len(torques), torques, task) if problem is None else problem
        z = problem.with_torques(torques)
        evaluation = problem.evaluate(z)
        scale, nx = self.settings.executor.object_gain_scale, 2 * self.scene.model.nv
        if gains is None:
            gains = feedback_gains(problem, z, self.settings.executor.feedback_regularization) if scale > 0 else \
                np.zeros((len(torques), 7, nx))
        gains = scale * gains[:, :7, :]
        nv, arm = self.scene.model.nv, self.scene.arm_dof_adr
        gains[:, :, arm] = 0.0
        gains[:, :, nv + arm] = 0.0
        gains[:, np.arange(7), arm] = -self.servo_gains[0]
        gains[:, np.arange(7), nv + arm] = -self.servo_gains[1]
        if worst_world is None:  # what the replans are held to; without them, not computed
            worst_world = self.worst_world(problem.simulator, state, problem.trajectory(z), task) \
                if self.settings.executor.replans(face) else math.inf
        return Policy(start_s, self.control_period_s, problem.simulator.timestep_s, np.array(torques, dtype=float),
                      gains, np.vstack([state[None], evaluation.states]), worst_world=worst_world,
                      object_scales=self.object_scales, target=target, face=face)

    def predict(self, state: np.ndarray, running: Policy, from_s: float, steps: int) -> np.ndarray:
        """The model's state `steps` simulation steps after `state` (at from_s) under the running policy's
        feed-forward torques: where the arm and the cube will be when a plan now computed takes effect."""
        simulator = next(iter(self._simulators.values()), None) or Simulator(
            self.scene, self.control_period_s, self.control_period_s, nthread=1)
        controls = np.zeros((steps, self.scene.model.nu))
        times = from_s + (np.arange(steps) + 0.5) * simulator.timestep_s
        controls[:, self.scene.motor_ids] = running.torques_at(times)
        states, _, _ = simulator.rollout_batch(state[None], controls[None])
        predicted = states[0, -1].copy()
        predicted[0] = 0.0
        return predicted

    def replan(self, measured_s: float, state: np.ndarray, running: Policy, lead_s: float) -> Policy | None:
        """One MPC step on the running policy's knots: from `state` measured at measured_s, predicted to the
        first of its knots at least lead_s ahead (a plan now computed cannot take effect sooner), over its
        remaining knots, warm-started from its torques there, one iLQR iteration or as many as the budget allows.
        None, and the running policy goes on, where fewer than min_replan_knots are left or where the replan does
        not improve on the running plan from the same state: a lower cost, no larger error, within the joint
        speed limits (a replan from a perturbed state can otherwise trade the goal for the cost's other terms), and
        where its worst_world is larger than the running policy's: a replan on the model alone pushes for the
        model's friction and mass, and without this check replans reached the goal in 12 of 24 episodes against 23
        (docs/results.md: Replans that keep the push sturdy)."""
        tc, dt = self.control_period_s, self.scene.model.opt.timestep
        knot = math.ceil((measured_s + lead_s - running.start_s) / tc - 1e-9)
        knots = len(running.torques_Nm) - knot
        if knots < self.settings.executor.min_replan_knots:
            return None
        start_s = running.start_s + knot * tc
        state = self.predict(state, running, measured_s, max(int(round((start_s - measured_s) / dt)), 0))
        guess = running.torques_Nm[knot:]
        task = self.task_to(running.target)  # a push to a waypoint is replanned to it, not on to the goal
        problem = self.problem(state, knots, guess, task)
        executor = self.settings.executor
        # from executor.replan_mu, raised at most executor.replan_regularizations times: past them the step is
        # rejected and the running plan goes on (each raise is a forward pass, and a replan late by ten of them
        # is no replan)
        options = self.settings.solver.ilqr_options
        mu_max = executor.replan_mu * options["mu_factor"] ** executor.replan_regularizations
        solver_settings = dataclasses.replace(self.settings.solver, max_iter=executor.replan_iterations,
                                              time_limit_s=executor.replan_budget_s, ilqr=tuple(
                                                  {**options, "mu_initial": executor.replan_mu, "mu_max": mu_max}.items()))
        solver = IlqrSolver(solver_settings)
        monitor = IterationMonitor(solver_settings, time.perf_counter(), 0, 0.0, None, None, "replan", False)
        start = problem.evaluate(problem.with_torques(guess))
        outcome = solver.solve(problem, start.z, problem.lower, problem.upper, monitor)
        fresh = problem.evaluate(outcome.z)
        speed = float(np.max(np.abs(self.scene.arm_qvel(fresh.states)) / self.scene.velocity_limit))
        if solver.gains is None or not (fresh.cost < start.cost and fresh.position_error_m <= start.position_error_m
                                        and speed <= 1.0):
            return None
        worst_world = self.worst_world(problem.simulator, state, problem.trajectory(outcome.z), task,
                                       running.worst_world)
        if worst_world > running.worst_world:
            return None
        # iLQR's cost only falls, so its outcome is the last kept step's, whose backward pass gave solver.gains
        return self.policy(start_s, state, problem.split(outcome.z)[0], solver.gains, problem, worst_world,
                           running.target, running.face)


# per process: the models of the goal that runs, built once (its scene's cube and the last identified one)
_MODELS: dict[tuple[ExecuteGoal, tuple[float, float]], tuple[Settings, PushModel]] = {}


def push_model(settings: Settings, goal: ExecuteGoal, object_scales: tuple[float, float] = (1.0, 1.0)) -> PushModel:
    """The planner's model of a goal's pushes, the cube's friction and mass object_scales times the scene's, built
    once per process and settings (the executor's and the identified cube's: two at a time)."""
    key, nominal = (goal, object_scales), (goal, (1.0, 1.0))
    if key not in _MODELS or _MODELS[key][0] != settings:
        kept = _MODELS.get(nominal)  # one execution at a time: its nominal model stays, any other goes
        _MODELS.clear()
        if kept is not None and kept[0] == settings:
            _MODELS[nominal] = kept
        config = scene_config(settings, PushRequest(goal.contact_model, scene=goal.scene, object_scales=object_scales))
        _MODELS[key] = (settings, PushModel(settings, goal.contact_model, config,
                                            np.asarray(goal.target_position_m, dtype=float), goal.target_yaw_rad,
                                            object_scales))
    return _MODELS[key][1]
