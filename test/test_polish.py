"""Polishing the yaw: a cube at rest within the task's tolerances but turned by more than
executor.polish_orientation_rad allows is pushed again, by a push planned to that yaw tolerance and made only where
it is sturdy to it; where there is none, the execution ends a success, the arm held
(cito_ros.execution: goal.polishing, planning.compute, Executor.accept). Real MuJoCo, the real planner."""
import math

import numpy as np

from cito_ros.execution.executor import Ending, Executor, Failure
from cito_ros.execution.goal import ExecuteGoal, polishing, predict
from cito_ros.execution.planning import compute
from cito_ros.execution.policy import Policy
from cito_ros.execution.world import JointReading, PoseReading
from cito_ros.model.scene import start_configuration

# a cube at rest 1.2 cm from the goal and turned 0.129 rad from it: within 2 cm / 0.15 rad, not within 0.1 rad
TURNED = ExecuteGoal((1.1106, -0.0264), 0.1204)
TURNED_CUBE = ((1.1015, -0.019), -0.0085)
TURNED_BETA = 6.668

# 1.5 cm from the goal, which lies beside it across the near face's normal, and turned 0.103 rad: no push on the near
# face that turns it within 0.1 rad is sturdy
BESIDE = ExecuteGoal((1.1181, 0.0137), -0.053)
BESIDE_CUBE = ((1.12, 0.0287), -0.1564)
BESIDE_BETA = 6.629


def after_a_push(settings, goal, cube, beta):
    """An executor with one push made, its arm at the start pose of beta and the cube at rest at `cube`, and the job
    of its next push."""
    executor = Executor(settings, goal)
    q = start_configuration(beta)
    executor.on_joints(JointReading(0.0, q, np.zeros(7), np.zeros(7)))
    (x, y), yaw = cube
    quaternion = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    for k in range(12):
        executor.on_pose(PoseReading(0.01 * k, np.array([x, y, 0.075]), quaternion), 0.01 * k)
    executor.on_joints(JointReading(0.12, q, np.zeros(7), np.zeros(7)))
    executor.pushes = 1
    return executor, executor.job(0.12)


def test_only_a_cube_within_the_tolerances_and_turned_past_the_polish_yaw_is_polished(settings):
    polish = settings.executor.polish_orientation_rad
    assert polish == 0.1
    assert polishing(settings, 0.012, 0.129).task.success_orientation_error_rad == polish
    assert polishing(settings, 0.012, 0.094) is None       # within done_fraction of 0.1 rad: done
    assert polishing(settings, 0.012, 0.143) is None       # past done_fraction of 0.15 rad: not at the goal at all
    assert polishing(settings, 0.0191, 0.12) is None       # past done_fraction of 2 cm
    assert polishing(settings.with_overrides({"executor.polish_orientation_rad": 0.0}), 0.012, 0.129) is None


def test_a_cube_within_the_tolerances_but_turned_past_the_polish_yaw_gets_a_push_sturdy_to_it(settings):
    executor, job = after_a_push(settings, TURNED, TURNED_CUBE, TURNED_BETA)
    position, orientation = TURNED.errors(*job.object_pose)
    assert position < 0.019 and 0.1 < orientation < 0.1425, "the premise: at the goal, but not within 0.1 rad"
    policy = compute(settings, TURNED, job)
    assert isinstance(policy, Policy) and policy.sturdy
    seen = predict(settings, executor.model.scene, TURNED, job.object_pose, policy)
    assert seen.predicted[1] < settings.executor.polish_orientation_rad and seen.predicted[0] < 0.02
    assert executor.accept(job, policy, 1.0) is not None and executor.ending is None  # made


def test_where_no_push_is_sturdy_to_the_polish_yaw_the_execution_ends_a_success_with_the_arm_held(settings):
    executor, job = after_a_push(settings, BESIDE, BESIDE_CUBE, BESIDE_BETA)
    outcome = compute(settings, BESIDE, job)
    assert isinstance(outcome, Failure) and "sturdy to within 0.1 rad" in outcome.message
    assert executor.accept(job, outcome, 1.0) is None
    assert executor.ending is Ending.SUCCEEDED and "no push turning it within 0.1 rad" in executor.message


def test_the_same_failure_for_a_cube_outside_the_tolerances_ends_the_task_not_achieved(settings):
    executor, job = after_a_push(settings, TURNED, ((1.08, -0.019), -0.0085), TURNED_BETA)
    assert executor.accept(job, Failure(Ending.INVALID_REQUEST, "no push can be planned from here"), 1.0) is None
    assert executor.ending is Ending.TASK_NOT_ACHIEVED and executor.cause == "no_push_from_here"


def test_a_polishing_plan_that_is_not_finite_ends_as_a_numerical_error_not_a_success(settings):
    executor, job = after_a_push(settings, TURNED, TURNED_CUBE, TURNED_BETA)
    assert executor.accept(job, Failure(Ending.NUMERICAL_ERROR, "the plan is not finite"), 1.0) is None
    assert executor.ending is Ending.NUMERICAL_ERROR
