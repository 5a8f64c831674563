"""The state estimate from a late, noisy camera: the cube carried forward at the velocity its poses show, and at rest
where the mean of its poses puts it. Real MuJoCo."""
import math

import numpy as np
import pytest

from cito_ros.execution.estimator import StateEstimator
from cito_ros.execution.world import PoseReading
from cito_ros.model.scene import start_configuration


def test_the_estimate_carries_the_cube_forward_at_the_velocity_its_poses_show(settings, scenes):
    scene = scenes["vscm"]
    estimator = StateEstimator(scene, scene.initial_state(start_configuration(7)))
    for k in range(5):  # moving at 0.2 m/s along x, turning at 0.5 rad/s
        t = 0.1 + k / 30
        yaw = 0.5 * t
        estimator.add_pose(PoseReading(t, np.array([1.0 + 0.2 * t, 0.0, 0.3]),
                                       np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])))
    (x, y), yaw = estimator.object_pose(0.3)
    assert (x, y, yaw) == pytest.approx((1.06, 0.0, 0.15), abs=1e-9)
    assert estimator.object_speed_m_s() == pytest.approx(0.2 + 0.5 * np.linalg.norm(scene.object_half_size))


def seen_at_rest(scene) -> StateEstimator:
    """An estimate of a cube at rest at (1.0, 0.02), yaw 0.1, from ten camera poses at 30 Hz with 1 mm of noise per
    axis and 0.01 rad in yaw."""
    estimator = StateEstimator(scene, scene.initial_state(start_configuration(7)))
    rng = np.random.default_rng(0)
    for k in range(10):
        yaw = 0.1 + rng.normal(0, 0.01)
        estimator.add_pose(PoseReading(k / 30, np.array([1.0, 0.02, 0.3]) + rng.normal(0, 0.001, 3),
                                       np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])))
    return estimator


def test_a_cube_at_rest_is_seen_where_the_mean_of_its_noisy_poses_puts_it(settings, scenes):
    estimator = seen_at_rest(scenes["vscm"])
    (x, y), yaw = estimator.resting_pose()
    (last_x, last_y), _ = estimator.object_pose(9 / 30)
    assert math.hypot(x - 1.0, y - 0.02) < 0.5 * math.hypot(last_x - 1.0, last_y - 0.02)
    assert yaw == pytest.approx(0.1, abs=0.006)
