"""Rollouts: holding still, the contact laws, determinism, threads, bad input."""
import dataclasses

import numpy as np
import pytest

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene
from cito_ros.model.simulator import Simulator

from conftest import approach_torques


def end_effector(scene, q):
    return scene.data_at(q).site_xpos[scene.robot_site_id].copy()


@pytest.mark.parametrize("beta", [5, 6, 7])
def test_zero_torque_and_zero_stiffness_holds_still(scenes, simulators, start_states, beta):
    scene, simulator = scenes["vscm"], simulators["vscm"]
    trajectory = simulator.rollout(start_states[beta], np.zeros((20, 7)), np.zeros(20))
    assert trajectory.warnings == {} and trajectory.finite
    drift = np.linalg.norm(end_effector(scene, trajectory.q[-1]) - end_effector(scene, trajectory.q[0]))
    assert drift < 1e-3, f"end effector drifted {drift} m"
    assert np.all(trajectory.gamma_N == 0)
    # the cube rests: it settles into the soft table contact by a fraction of a millimetre
    assert np.abs(trajectory.object_position_m - trajectory.object_position_m[0]).max() < 5e-4
    np.testing.assert_allclose(trajectory.object_quaternion[-1], [1, 0, 0, 0], atol=1e-6)


@pytest.mark.parametrize("name", ["scm", "vscm"])
def test_gamma_follows_the_exponential_law(scenes, simulators, start_states, name):
    simulator, model = simulators[name], scenes[name].contact_model
    stiffness = np.full(20, model.default_control()) if name == "scm" else np.linspace(0, 100, 20)
    trajectory = simulator.rollout(start_states[7], approach_torques(simulator), stiffness)
    k = trajectory.stiffness_N
    expected = np.where(k > 0, k * np.exp(-(model.curvature / np.maximum(k, 1e-300)) * trajectory.signed_distance_m), 0)
    np.testing.assert_allclose(trajectory.gamma_N, expected, rtol=1e-12, atol=0)
    assert trajectory.gamma_N.max() > 0
    if name == "vscm":
        assert np.all(trajectory.gamma_N[k == 0] == 0)  # the force vanishes at k = 0


def test_gamma_is_the_cccm_control(simulators, start_states):
    forces = np.linspace(0, 5, 20)
    trajectory = simulators["cccm"].rollout(start_states[6], np.zeros((20, 7)), forces)
    np.testing.assert_array_equal(trajectory.gamma_N, np.repeat(forces, 10))
    assert trajectory.stiffness_N is None


def test_virtual_force_pushes_the_cube(simulators, start_states):
    # 3 N along the face normal for 1 s overcomes friction (0.5 * 0.155 kg * g = 0.76 N)
    trajectory = simulators["cccm"].rollout(start_states[5], np.zeros((20, 7)), np.full(20, 3.0))
    displacement = trajectory.object_position_m[-1] - trajectory.object_position_m[0]
    assert displacement[0] > 0.5 and abs(displacement[1]) < 1e-6
    # and the reaction pushes the arm back (-x)
    scene = simulators["cccm"].scene
    assert (end_effector(scene, trajectory.q[-1]) - end_effector(scene, trajectory.q[0]))[0] < -0.01


@pytest.mark.parametrize("name", ["cccm", "scm", "vscm"])
def test_same_rollout_twice_gives_identical_bits(simulators, start_states, name):
    simulator = simulators[name]
    torques = approach_torques(simulator, seed=3)
    first = simulator.rollout(start_states[7], torques)
    simulator.rollout(start_states[5], -torques)  # something else in between
    second = simulator.rollout(start_states[7], torques)
    for field in dataclasses.fields(first):
        a, b = getattr(first, field.name), getattr(second, field.name)
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b), field.name
        else:
            assert a == b, field.name


def test_one_and_two_threads_give_identical_results(scenes, start_states):
    scene = scenes["vscm"]
    one, two = Simulator(scene, nthread=1), Simulator(scene, nthread=2)
    controls = np.stack([one.step_controls(one.knot_controls(approach_torques(one, seed=s), np.full(20, 50.0)))
                         for s in range(6)])
    states = np.stack([start_states[5], start_states[6], start_states[7]] * 2)
    states_1, sensors_1, _ = one.rollout_batch(states, controls)
    states_2, sensors_2, _ = two.rollout_batch(states, controls)
    assert np.array_equal(states_1, states_2) and np.array_equal(sensors_1, sensors_2)
    # and a batch row equals the single rollout of the same inputs
    single = one.rollout(states[4], approach_torques(one, seed=4), np.full(20, 50.0))
    assert np.array_equal(single.q[1:], states_2[4][:, 1 + scene.arm_qpos_adr])


def test_feedback_rollouts_side_by_side_are_replayed_bit_for_bit_open_loop(simulators, start_states):
    # iLQR's forward pass chooses each knot's decisions from the state it reaches; the plan it keeps is
    # those decisions, executed open loop, so both rollouts must be the same motion to the last bit,
    # whichever of the threads ran it (three trials on two threads: one thread runs two in a row)
    simulator = simulators["vscm"]
    scene, N, S = simulator.scene, simulator.n_knots, simulator.steps_per_knot
    nx = 2 * simulator.model.nv
    torques = approach_torques(simulator, seed=5)
    decisions = np.hstack([torques, np.full((N, 1), 80.0)])
    actuators = np.array([*scene.motor_ids, scene.contact_actuator_id], dtype=np.int32)
    motion, _, _ = simulator.rollout_batch(start_states[6][None], simulator.step_controls(
        simulator.knot_controls(torques, np.full(N, 80.0)))[None])
    knot_states = np.vstack([start_states[6][None], motion[0][S - 1:-1:S]])
    # a direction of change, and damping gains: the decisions depend on the velocities reached
    k = np.hstack([np.random.default_rng(5).normal(0.0, 2.0, (N, 7)), np.full((N, 1), -30.0)])
    K = np.zeros((N, 8, nx))
    K[:, np.arange(7), simulator.model.nv + np.asarray(scene.arm_dof_adr)] = -3.0
    lower = np.hstack([-np.tile(scene.torque_limit, (N, 1)), np.zeros((N, 1))])
    upper = np.hstack([np.tile(scene.torque_limit, (N, 1)), np.full((N, 1), 200.0)])
    step_lengths = np.array([1.0, 0.5, 0.0])

    assert simulator.nthread == 2
    rollouts = simulator.feedback_rollouts(start_states[6], knot_states, decisions, k, K, step_lengths, lower,
                                           upper, actuators)
    chosen = [trial for trial, _, _, _ in rollouts]
    open_states, open_sensordata, open_warnings = simulator.rollout_batch(
        np.repeat(start_states[6][None], len(step_lengths), axis=0),
        np.stack([simulator.step_controls(simulator.knot_controls(c[:, :7], c[:, 7])) for c in chosen]))
    for i, (trial, states, sensordata, warnings) in enumerate(rollouts):
        assert np.array_equal(states, open_states[i]) and np.array_equal(sensordata, open_sensordata[i])
        assert warnings == {}
        assert np.all(trial >= lower) and np.all(trial <= upper)
    assert open_warnings == {}
    # the law, knot by knot from the states reached (first knot: no deviation yet)
    qvel = slice(scene.state_qvel_adr, scene.state_qvel_adr + simulator.model.nv)
    for i, alpha in enumerate(step_lengths):
        reached = np.vstack([start_states[6][None], rollouts[i][1][S - 1:-1:S]])
        deviation = reached[:, qvel] - knot_states[:, qvel]
        expected = decisions + alpha * k + np.einsum("lij,lj->li", K[:, :, simulator.model.nv:], deviation)
        assert np.allclose(rollouts[i][0], np.clip(expected, lower, upper), rtol=0, atol=1e-9)
    # with no step the trial retraces the motion the knot states came from: no deviation ever arises
    assert np.array_equal(rollouts[2][0], decisions) and np.array_equal(rollouts[2][1], motion[0])
    assert np.abs(rollouts[0][0] - decisions).max() > 0.1  # the step and the feedback acted
    assert not np.array_equal(rollouts[0][1], rollouts[1][1])  # different step lengths, different motions


def test_feedback_rollouts_refuse_an_actuator_the_model_does_not_have(simulators, start_states):
    simulator = simulators["vscm"]
    N, nx = simulator.n_knots, 2 * simulator.model.nv
    zeros = np.zeros((N, 8))
    with pytest.raises(ValueError, match="actuators"):
        simulator.feedback_rollouts(start_states[6], np.tile(start_states[6], (N, 1)), zeros, zeros,
                                    np.zeros((N, 8, nx)), np.array([1.0]), zeros - 1, zeros + 1,
                                    np.array([0, 1, 2, 3, 4, 5, 6, simulator.model.nu], dtype=np.int32))


def test_models_with_different_parameters_coexist(settings, start_states):
    soft = settings.with_overrides({"contact_models.vscm.curvature": 1000.0})
    stiff_scene = Scene(contact_model("vscm", settings.contact_models))
    soft_scene = Scene(contact_model("vscm", soft.contact_models))
    stiff, soft_sim = Simulator(stiff_scene), Simulator(soft_scene)
    for _ in range(2):  # interleaved: neither scene's parameters leak into the other
        for simulator in (stiff, soft_sim):
            law = simulator.scene.contact_model
            trajectory = simulator.rollout(start_states[6], approach_torques(simulator), np.full(20, 80.0))
            expected = 80.0 * np.exp(-(law.curvature / 80.0) * trajectory.signed_distance_m)
            np.testing.assert_allclose(trajectory.gamma_N, expected, rtol=1e-12)


class TestBadInput:
    def test_wrong_torque_shape(self, simulators, start_states):
        with pytest.raises(ValueError, match=r"torques must have shape \(20, 7\)"):
            simulators["vscm"].rollout(start_states[5], np.zeros((20, 6)))

    @pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
    def test_non_finite_torques(self, simulators, start_states, bad):
        torques = np.zeros((20, 7))
        torques[3, 2] = bad
        with pytest.raises(ValueError, match="torques contain NaN or Inf"):
            simulators["vscm"].rollout(start_states[5], torques)

    def test_torque_over_the_motor_limit(self, simulators, start_states):
        torques = np.zeros((20, 7))
        torques[0, 4] = 10.0
        with pytest.raises(ValueError, match="exceeds the j4 motor limit 9.0"):
            simulators["vscm"].rollout(start_states[5], torques)

    def test_negative_stiffness(self, simulators, start_states):
        with pytest.raises(ValueError, match=r"vscm: stiffness k \(N\) must be non-negative, got -1.0"):
            simulators["vscm"].rollout(start_states[5], np.zeros((20, 7)), np.full(20, -1.0))

    def test_stiffness_over_the_maximum(self, simulators, start_states):
        with pytest.raises(ValueError, match=r"must lie in \[0.0, 100.0\], got 150.0"):
            simulators["vscm"].rollout(start_states[5], np.zeros((20, 7)), np.full(20, 150.0))

    def test_nan_stiffness(self, simulators, start_states):
        with pytest.raises(ValueError, match="contains NaN or Inf"):
            simulators["vscm"].rollout(start_states[5], np.zeros((20, 7)), np.full(20, np.nan))

    def test_scm_stiffness_is_fixed(self, simulators, start_states):
        with pytest.raises(ValueError, match="scm: the stiffness is fixed at k = 100.0 N"):
            simulators["scm"].rollout(start_states[5], np.zeros((20, 7)), np.full(20, 50.0))

    def test_negative_cccm_force(self, simulators, start_states):
        with pytest.raises(ValueError, match="cccm: normal force gamma .* must be non-negative"):
            simulators["cccm"].rollout(start_states[5], np.zeros((20, 7)), np.full(20, -0.5))

    def test_wrong_contact_control_shape(self, simulators, start_states):
        with pytest.raises(ValueError, match=r"contact_control must have shape \(20,\)"):
            simulators["vscm"].rollout(start_states[5], np.zeros((20, 7)), np.zeros(19))

    def test_bad_initial_state(self, simulators, start_states):
        state = start_states[5].copy()
        with pytest.raises(ValueError, match="initial state must have shape"):
            simulators["vscm"].rollout(state[:-1], np.zeros((20, 7)))
        state[3] = np.nan
        with pytest.raises(ValueError, match="initial state contains NaN or Inf"):
            simulators["vscm"].rollout(state, np.zeros((20, 7)))

    def test_unknown_contact_model(self):
        with pytest.raises(ValueError, match=r"unknown contact model 'soft'; choose one of \['cccm', 'scm', 'vscm'\]"):
            contact_model("soft", None)

    @pytest.mark.parametrize("horizon, period, message", [
        (-1.0, 0.05, "horizon_s must be positive"),
        (1.0, 0.0, "control_period_s must be positive"),
        (1.0, 0.3, "whole number of control periods"),
        (1.0, 0.0125, "whole number of timesteps"),
        (float("nan"), 0.05, "horizon_s must be finite"),
    ])
    def test_bad_horizon(self, scenes, horizon, period, message):
        with pytest.raises(ValueError, match=message):
            Simulator(scenes["vscm"], horizon, period)

    def test_bad_contact_model_parameters(self, settings):
        with pytest.raises(ValueError, match="contact_models.scm.curvature must be positive, got -5.0"):
            settings.with_overrides({"contact_models.scm.curvature": -5.0})
        with pytest.raises(ValueError, match="contact_models.scm.curvature: missing"):
            settings.with_overrides({"contact_models.scm.curvature": None})
