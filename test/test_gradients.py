"""Exact derivatives: the adjoint gradient and constraint Jacobian against central differences,
and the fallback where a contact switch makes a step's linearization unreliable."""
import dataclasses

import mujoco
import numpy as np
import pytest

from cito_ros.problem import ProblemSettings, PushProblem, PushTask


def make_problem(simulators, start_states, parameters, name, beta=7, **settings):
    simulator = simulators[name]
    state = start_states[beta]
    scene = simulator.scene
    start = state[1 + scene.object_qpos_adr:1 + scene.object_qpos_adr + 3]
    base = ProblemSettings.from_parameters(parameters, name)
    return PushProblem(simulator, state, PushTask(start + [0.25, 0.0, 0.0], 0.1), dataclasses.replace(base, **settings))


def interior_point(problem, seed=0, spread=0.05):
    """Near the optimizer's start (torques 5 % of the limits, gamma and slack a few tenths,
    k near k_max), strictly inside the bounds so central differences stay feasible."""
    rng = np.random.default_rng(seed)
    z = problem.initial_guess + spread * rng.uniform(-1, 1, problem.size) * problem.scale
    margin = 0.002 * problem.scale
    return np.clip(z, problem.lower + margin, problem.upper - margin)


def directional_difference(problem, z, direction, h):
    plus, minus = problem.evaluate(z + h * direction), problem.evaluate(z - h * direction)
    return (plus.cost - minus.cost) / (2 * h), (plus.constraints - minus.constraints) / (2 * h)


@pytest.mark.parametrize("name", ["cccm", "scm", "vscm"])
def test_gradient_matches_central_differences(simulators, start_states, parameters, name):
    problem = make_problem(simulators, start_states, parameters, name)
    z = interior_point(problem)
    evaluation = problem.derivatives(z)
    gradient, jacobian = evaluation.gradient.copy(), evaluation.jacobian.copy()
    assert evaluation.derivative_info["unresolved_columns"] == 0
    rng = np.random.default_rng(1)
    for _ in range(3):
        direction = rng.normal(size=problem.size) * problem.scale
        direction /= np.linalg.norm(direction / problem.scale)
        cost_fd, constraints_fd = directional_difference(problem, z, direction, 1e-6)
        assert gradient @ direction == pytest.approx(cost_fd, rel=2e-3, abs=1e-6 * np.abs(gradient * problem.scale).max())
        if problem.n_constraints:
            np.testing.assert_allclose(jacobian @ direction, constraints_fd, rtol=2e-3,
                                       atol=1e-3 * np.abs(constraints_fd).max())


def test_gradient_coordinates(simulators, start_states, parameters):
    problem = make_problem(simulators, start_states, parameters, "vscm")
    z = interior_point(problem, seed=3)
    gradient = problem.derivatives(z).gradient.copy()
    # every torque of the first, a middle and the last knot, and their stiffnesses
    for column in [*range(8), *range(80, 88), *range(152, 160)]:
        h = 1e-5 * problem.scale[column]
        step = np.zeros(problem.size)
        step[column] = h
        fd = (problem.evaluate(z + step).cost - problem.evaluate(z - step).cost) / (2 * h)
        assert gradient[column] == pytest.approx(fd, rel=5e-3, abs=1e-4 * np.abs(gradient).max()), column


def test_forward_difference_method_agrees_with_the_adjoint(simulators, start_states, parameters):
    adjoint = make_problem(simulators, start_states, parameters, "cccm")
    restart = make_problem(simulators, start_states, parameters, "cccm", gradient_method="forward_differences",
                           restart_step=1e-6)
    z = interior_point(adjoint, seed=5)
    a, b = adjoint.derivatives(z), restart.derivatives(z)
    scale = np.abs(a.gradient * adjoint.scale).max()
    np.testing.assert_allclose(a.gradient * adjoint.scale, b.gradient * restart.scale, atol=2e-3 * scale)
    np.testing.assert_allclose(a.jacobian * adjoint.scale, b.jacobian * restart.scale,
                               atol=2e-3 * np.abs(a.jacobian * adjoint.scale).max())


def test_contact_switch_is_detected_and_the_knot_falls_back(simulators, parameters):
    """A cube placed exactly on the table (zero penetration) sits on a contact switch: every
    small tilt makes or breaks a table contact. The linearization must flag it and the affected
    knot must be differentiated by restart differences instead."""
    simulator = simulators["vscm"]
    scene = simulator.scene
    data = scene.data_at(np.array([-np.pi / 12, -np.pi / 7, 0, 3 * np.pi / 7, -np.pi / 6, -2 * np.pi / 7, 0]))
    state = np.empty(simulator.nstate)
    mujoco.mj_getState(scene.model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    start = state[1 + scene.object_qpos_adr:1 + scene.object_qpos_adr + 3]
    settings = ProblemSettings.from_parameters(parameters, "vscm")
    problem = PushProblem(simulator, state, PushTask(start + [0.25, 0, 0]), settings)
    z = problem.initial_guess
    evaluation = problem.derivatives(z)
    info = evaluation.derivative_info
    assert info["unresolved_columns"] > 0 and info["restarted_knots"] >= 1
    assert np.all(np.isfinite(evaluation.gradient))
    fallback = PushProblem(simulator, state, PushTask(start + [0.25, 0, 0]),
                           dataclasses.replace(settings, gradient_method="forward_differences"))
    knots = info["restarted_knots"] * problem.width
    np.testing.assert_allclose(evaluation.gradient[:knots], fallback.derivatives(z).gradient[:knots], rtol=1e-12)


def test_linearization_is_independent_of_threads(simulators, start_states, parameters):
    one = make_problem(simulators, start_states, parameters, "vscm", threads=1)
    two = make_problem(simulators, start_states, parameters, "vscm", threads=2)
    z = interior_point(one, seed=7)
    first, second = one._linearize(one.evaluate(z)), two._linearize(two.evaluate(z))
    for a, b in zip(first, second):
        assert np.array_equal(a, b)


def test_bad_gradient_settings(parameters):
    with pytest.raises(ValueError, match="gradient method must be one of"):
        ProblemSettings(weights={"w1": 1, "w2": 1, "w3": 1, "w4": 1}, gradient_method="magic")
    with pytest.raises(ValueError, match=r"missing cost weights \['w4'\]"):
        ProblemSettings(weights={"w1": 1, "w2": 1, "w3": 1})
