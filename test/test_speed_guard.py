"""The executor's speed guard (cito_ros.execution.policy.within_speed_limits) with what the arm's measured motion
shows of forces from outside the motors. Real MuJoCo."""
import mujoco
import numpy as np

from cito_ros.execution.policy import bias_torques, within_speed_limits
from cito_ros.model.scene import start_configuration


def test_an_outside_push_towards_a_joints_limit_that_the_torques_do_not_explain_is_braked_against(scenes):
    """Joint j2 moves at 0.9 of the guard's limit under torques that would keep it there; its measured acceleration
    shows a push the torques do not explain (the cube's contact twisting the wrist). The guard without the
    measurement lets the torques be; with it, it brakes j2 so that the push leaves it within the limit."""
    scene = scenes["vscm"]
    data = mujoco.MjData(scene.model)
    q, qdot = start_configuration(5), np.zeros(7)
    limit = 0.95 * scene.velocity_limit
    qdot[2] = 0.9 * limit[2]
    bias = bias_torques(scene, data, q, qdot)
    u, horizon_s = np.zeros(7), 0.05
    assert np.array_equal(within_speed_limits(scene, data, u, qdot, bias, limit, horizon_s), u)
    pushed = np.zeros(7)
    pushed[2] = 0.5 * limit[2] / horizon_s  # would take j2 to 1.4 of the limit within the horizon
    guarded = within_speed_limits(scene, data, u, qdot, bias, limit, horizon_s, (pushed, u + bias))
    full = np.zeros((scene.model.nv, scene.model.nv))
    mujoco.mj_fullM(scene.model, data, full)
    acceleration = np.linalg.solve(full[np.ix_(scene.arm_dof_adr, scene.arm_dof_adr)], guarded)
    assert guarded[2] < 0.0
    assert qdot[2] + horizon_s * (acceleration[2] + pushed[2]) <= limit[2] + 1e-9
    # the same push away from the limit asks nothing
    assert np.array_equal(within_speed_limits(scene, data, u, qdot, bias, limit, horizon_s, (-pushed, u + bias)), u)
