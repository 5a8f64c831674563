"""Exact derivatives: the adjoint gradient and constraint Jacobian against central differences,
and the fallback where a contact switch makes a step's linearization unreliable."""
import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.problem import PushProblem, StageCost
from cito_ros.planner.problem.rollout_derivatives import adjoint, forward_sensitivities, linearize
from cito_ros.planner.solvers.ipopt import _Callbacks
from cito_ros.planner.stages import physical_twin, stage_cost
from cito_ros.planner.task import PushTask


def make_problem(settings, name, beta=7, **overrides):
    """The paper's push (its 1 s horizon) from q0(beta) with a 0.1 rad yaw goal, under settings with
    dotted overrides."""
    settings = settings.with_overrides({"pipeline": "paper", **overrides})
    x, y = settings.scene.object.position_m
    return build_problem(settings, PushRequest(name, beta, target_position_m=[x + 0.25, y],
                                               target_yaw_rad=0.1)).problem


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
def test_gradient_matches_central_differences(settings, name):
    problem = make_problem(settings, name)
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


def test_gradient_coordinates(settings):
    problem = make_problem(settings, "vscm")
    z = interior_point(problem, seed=3)
    gradient = problem.derivatives(z).gradient.copy()
    # every torque of the first, a middle and the last knot, and their stiffnesses
    for column in [*range(8), *range(80, 88), *range(152, 160)]:
        h = 1e-5 * problem.scale[column]
        step = np.zeros(problem.size)
        step[column] = h
        fd = (problem.evaluate(z + step).cost - problem.evaluate(z - step).cost) / (2 * h)
        assert gradient[column] == pytest.approx(fd, rel=5e-3, abs=1e-4 * np.abs(gradient).max()), column


def test_forward_difference_method_agrees_with_the_adjoint(settings):
    adjoint = make_problem(settings, "cccm")
    restart = make_problem(settings, "cccm", **{"gradient.method": "forward_differences",
                                                "gradient.restart_step": 1e-6})
    z = interior_point(adjoint, seed=5)
    a, b = adjoint.derivatives(z), restart.derivatives(z)
    scale = np.abs(a.gradient * adjoint.scale).max()
    np.testing.assert_allclose(a.gradient * adjoint.scale, b.gradient * restart.scale, atol=2e-3 * scale)
    np.testing.assert_allclose(a.jacobian * adjoint.scale, b.jacobian * restart.scale,
                               atol=2e-3 * np.abs(a.jacobian * adjoint.scale).max())


def test_contact_switch_is_detected_and_the_knot_falls_back(simulators, settings):
    """A cube placed exactly on the table (zero penetration) sits on a contact switch: every
    small tilt makes or breaks a table contact. The linearization must flag it and the affected
    knot must be differentiated by restart differences instead."""
    simulator = simulators["vscm"]
    scene = simulator.scene
    data = scene.data_at(np.array([-np.pi / 12, -np.pi / 7, 0, 3 * np.pi / 7, -np.pi / 6, -2 * np.pi / 7, 0]))
    state = np.empty(simulator.nstate)
    mujoco.mj_getState(scene.model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    task = PushTask(scene.object_qpos(state)[:3] + [0.25, 0, 0])

    def problem_with(derivative_settings):
        return PushProblem(simulator, state, task, StageCost.paper(settings.weights.vscm), derivative_settings,
                           settings.task.position_error_scale_min_m)

    problem = problem_with(settings.gradient)
    z = problem.initial_guess
    evaluation = problem.derivatives(z)
    info = evaluation.derivative_info
    assert info["unresolved_columns"] > 0 and info["restarted_knots"] >= 1
    assert np.all(np.isfinite(evaluation.gradient))
    fallback = problem_with(settings.with_overrides({"gradient.method": "forward_differences"}).gradient)
    knots = info["restarted_knots"] * problem.width
    np.testing.assert_allclose(evaluation.gradient[:knots], fallback.derivatives(z).gradient[:knots], rtol=1e-12)


def test_a_collider_outlier_at_the_nominal_state_is_differenced_around(simulators, settings):
    """A recorded state of a physical plan (goal 19 of `cito-bench targets`) where the wrist's cylinder
    presses on the cube's top face: the convex collider's depth there jumps by 0.1 mm under any 1e-6
    perturbation, so forward differences from the nominal state made one step's transition 1e3 times too
    steep (spectral radius 15), and a knot of 16 such steps 1e12. Both perturbed sides agree with each
    other; their central difference is the smooth one."""
    scene = simulators["vscm"].scene
    recorded = json.loads((Path(__file__).parent / "data" / "wrist_on_cube_state.json").read_text())
    state, control = np.array([recorded["state"]]), np.array([recorded["ctrl"]])
    datas = (mujoco.MjData(scene.model),)
    fine = linearize(scene.model, datas, state, control, settings.gradient.epsilon)
    coarse = linearize(scene.model, datas, state, control, 1e-4)  # steps over the collider's jumps
    assert fine.info()["one_sided_columns"] > 0
    assert np.abs(fine.A).max() <= 2 * np.abs(coarse.A).max()
    assert np.abs(np.linalg.eigvals(fine.A[0])).max() < 1.1


def every_term(settings, name, virtual_force, complementarity=0.0):
    """The beta = 7 push with every stage-cost term active: limits with tight margins, the object's final
    velocity, and the contact term over the second half of the horizon (and CCCM's slack eliminated
    with a positive complementarity weight)."""
    base = make_problem(settings, name)
    profile = np.where(np.arange(base.n_steps) >= base.n_steps // 2, 1.0 / base.n_steps, 0.0)
    cost = StageCost(base.weights, virtual_force, joint_speed=100.0, joint_speed_margin=0.05, joint_position=100.0,
                     joint_position_margin_rad=2.0, object_velocity=10.0, contact=50.0, contact_profile=profile,
                     complementarity=complementarity, orientation_equivalent_m_per_rad=0.5)
    return PushProblem(base.simulator, base.initial_state, base.task, cost, settings.gradient,
                       settings.task.position_error_scale_min_m)


@pytest.mark.parametrize("balance, turn_per_position", [(0.0, 0.14), (1.0, 1.0)])
def test_the_executors_pushes_weigh_a_turn_off_by_its_tolerance_as_a_position_off_by_its_own(settings, balance,
                                                                                            turn_per_position):
    """A push near the goal (1 cm: the position scale at its 5 cm floor): with the paper's w2 alone a cube turned
    by the orientation tolerance costs 1/7 of one off by the position tolerance; with the executor's
    stages.orientation_balance 1, as much. Both measured on the terminal residuals of states with the cube so."""
    tuned = settings.with_overrides({"stages.orientation_balance": balance})
    base = make_problem(settings, "vscm")
    scene, state = base.scene, base.initial_state
    task = PushTask(scene.object_qpos(state)[:3] + [0.01, 0.0, 0.0])
    problem = PushProblem(base.simulator, state, task, stage_cost(tuned, base.weights, False, 0.0, None, 0.0, 0.0),
                          tuned.gradient, tuned.task.position_error_scale_min_m)
    assert problem.position_scale == tuned.task.position_error_scale_min_m

    def pose_cost(offset_m: float, yaw_rad: float) -> float:
        final = state.copy()
        pose = scene.object_qpos(final)
        pose[:3] = task.target_position_m + [offset_m, 0.0, 0.0]
        pose[3:7] = [np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)]
        residuals, _ = problem._terminal_residuals(final, derivatives=False)
        return float(residuals[:6] @ residuals[:6])

    turned, moved = pose_cost(0.0, tuned.task.success_orientation_error_rad), \
        pose_cost(tuned.task.success_position_error_m, 0.0)
    assert turned / moved == pytest.approx(turn_per_position, rel=0.02)


@pytest.mark.parametrize("name, virtual_force, complementarity",
                         [("cccm", True, 0.0), ("cccm", True, 1.0e3), ("vscm", True, 0.0), ("vscm", False, 0.0)])
def test_residual_jacobian_matches_differences_and_the_gradient(settings, name, virtual_force, complementarity):
    problem = every_term(settings, name, virtual_force, complementarity)
    z = interior_point(problem, seed=11, spread=0.3)
    evaluation = problem.evaluate(z)
    assert evaluation.cost == pytest.approx(evaluation.residuals @ evaluation.residuals, rel=1e-12)
    running, _ = problem._running_residuals(evaluation.sensordata)
    # an evaluation builds its residuals without their Jacobians: the same values, bit for bit
    with_derivatives = np.concatenate([problem._terminal_residuals(evaluation.states[-1])[0], running.ravel()])
    np.testing.assert_array_equal(evaluation.residuals[:len(with_derivatives)], with_derivatives)
    # columns: ee velocity (3), [gamma], 7 speeds, 7 positions, contact, [phi gamma]
    first = 4 if virtual_force else 3
    active = np.abs(running).max(axis=0) > 0
    assert active[first:first + 7].any() and active[first + 7:first + 14].any() and active[first + 14], active
    assert running.shape[1] == first + 15 + (complementarity > 0) and active[-1], active
    jacobian = problem.residual_jacobian(z).copy()
    gradient = problem.gradient(z)
    np.testing.assert_allclose(2 * jacobian.T @ evaluation.residuals, gradient,
                               atol=1e-9 * np.abs(gradient).max())
    rng = np.random.default_rng(2)
    for _ in range(3):
        direction = rng.normal(size=problem.size) * problem.scale
        direction /= np.linalg.norm(direction / problem.scale)
        h = 1e-6
        fd = (problem.residuals(z + h * direction) - problem.residuals(z - h * direction)) / (2 * h)
        np.testing.assert_allclose(jacobian @ direction, fd, rtol=2e-3, atol=2e-3 * np.abs(fd).max())


def test_cccm_with_its_slack_eliminated_is_box_bounded_with_gamma_alone(settings):
    # the paper's w5 s^2 with s >= phi gamma: at the optimum s = phi gamma, so the slack and the
    # complementarity constraint give way to the running residual sqrt(w5 / S) phi_t gamma_t
    paper, eliminated = every_term(settings, "cccm", True), every_term(settings, "cccm", True, 1.0e3)
    assert [v.name for v in paper.variables] == ["gamma_N", "slack_Nm"] and paper.n_constraints == 40
    assert [v.name for v in eliminated.variables] == ["gamma_N"] and eliminated.n_constraints == 0
    z = interior_point(eliminated, seed=3, spread=0.3)
    evaluation = eliminated.evaluate(z)
    phi, gamma = eliminated.signed_distance(evaluation.sensordata), evaluation.sensordata[:, eliminated.gamma_row]
    assert np.all(gamma > 0) and np.all(phi > 0)
    running, _ = eliminated._running_residuals(evaluation.sensordata)
    S = eliminated.steps_per_knot
    np.testing.assert_allclose(running[:, -1] ** 2 * S / 1.0e3, (phi * gamma) ** 2, rtol=1e-12)
    with pytest.raises(ValueError, match="vscm has no complementarity constraints to eliminate a slack of"):
        every_term(settings, "vscm", True, 1.0e3)


def test_ipopts_gauss_newton_hessian_is_the_residuals_curvature_by_differences(settings):
    # what IPOPT gets with curvature gauss_newton, in its scaled variables x = z / scale: the lower
    # triangle of obj_factor 2 (J S)'(J S), held here to differences of the residuals along directions
    problem = every_term(settings, "cccm", True)
    z = interior_point(problem, seed=11, spread=0.3)
    callbacks = _Callbacks(problem, problem.scale, monitor=None)
    rows, columns = callbacks.hessianstructure()
    assert np.all(rows >= columns) and len(rows) == problem.size * (problem.size + 1) // 2
    hessian = np.zeros((problem.size, problem.size))
    hessian[rows, columns] = callbacks.hessian(z / problem.scale, np.ones(problem.n_constraints), 0.5)
    hessian += np.tril(hessian, -1).T
    rng = np.random.default_rng(4)
    for _ in range(3):
        direction = rng.normal(size=problem.size)  # in x
        h = 1e-6
        fd = (problem.residuals(z + h * direction * problem.scale)
              - problem.residuals(z - h * direction * problem.scale)) / (2 * h)
        assert direction @ hessian @ direction == pytest.approx(0.5 * 2 * fd @ fd, rel=5e-3)


@pytest.mark.parametrize("virtual_force", [True, False])
def test_knot_expansion_is_the_gauss_newton_of_the_residual_jacobian(settings, virtual_force):
    # iLQR's backward pass sees the cost only through the knot-wise expansion; composed back over the
    # horizon (controls held, the cost-to-go's state derivatives carried knot to knot) it must give
    # the gradient 2 J'r and the diagonal knot blocks of the Gauss-Newton 2 J'J of the residual
    # Jacobian (checked against differences above)
    problem = every_term(settings, "vscm", virtual_force)
    z = interior_point(problem, seed=11, spread=0.3)
    expansion = problem.knot_expansion(z)
    jacobian, residuals = problem.residual_jacobian(z), problem.residuals(z)
    gradient, hessian = 2 * jacobian.T @ residuals, 2 * jacobian.T @ jacobian
    w = problem.width
    vx, vxx = expansion.vx, expansion.vxx
    for l in range(problem.n_knots - 1, -1, -1):
        fx, fc, knot = expansion.fx[l], expansion.fc[l], slice(l * w, (l + 1) * w)
        np.testing.assert_allclose(expansion.lc[l] + fc.T @ vx, gradient[knot], rtol=1e-8,
                                   atol=1e-10 * np.abs(gradient).max())
        np.testing.assert_allclose(expansion.lcc[l] + fc.T @ vxx @ fc, hessian[knot, knot], rtol=1e-8,
                                   atol=1e-10 * np.abs(hessian).max())
        vx, vxx = expansion.lx[l] + fx.T @ vx, expansion.lxx[l] + fx.T @ vxx @ fx


def test_the_adjoint_pass_is_the_derivative_of_a_linear_system():
    """On x_{t+1} = A_t x_t + B_t u_t, s_t = C_t x_t + D_t u_t and y = sum_t w_t . s_t + g . x_T, with
    u held per knot, the pure adjoint pass gives dy/du_knot exactly (checked against the explicit sum)."""
    rng = np.random.default_rng(0)
    T, S, nx, nu, ns, n_out = 12, 3, 4, 2, 3, 2
    A, B = rng.normal(size=(T, nx, nx)) * 0.5, rng.normal(size=(T, nx, nu))
    C, D = rng.normal(size=(T, ns, nx)), rng.normal(size=(T, ns, nu))
    w, g = rng.normal(size=(T, ns, n_out)), rng.normal(size=(nx, n_out))

    def outputs(knot_u):
        x, y = np.zeros(nx), np.zeros(n_out)
        for t in range(T):
            u = knot_u[t // S]
            y += (C[t] @ x + D[t] @ u) @ w[t]
            x = A[t] @ x + B[t] @ u
        return y + x @ g

    expected = np.zeros((T // S, nu, n_out))
    for knot in range(T // S):
        for j in range(nu):
            u = np.zeros((T // S, nu))
            u[knot, j] = 1.0
            expected[knot, j] = outputs(u)  # the map is linear: its value at a unit input is the derivative
    np.testing.assert_allclose(adjoint(A, B, C, D, w, g, S), expected, rtol=1e-12, atol=1e-12)


def test_linearization_is_independent_of_threads(settings):
    one = make_problem(settings, "vscm", **{"gradient.threads": 1})
    two = make_problem(settings, "vscm", **{"gradient.threads": 2})
    z = interior_point(one, seed=7)
    first, second = one.linearize(z), two.linearize(z)
    for name in ("A", "B", "C", "D", "flags"):
        assert np.array_equal(getattr(first, name), getattr(second, name)), name


def test_bad_gradient_settings(settings):
    with pytest.raises(ValueError, match=r"gradient.method must be one of \['adjoint', 'forward_differences'\]"):
        settings.with_overrides({"gradient.method": "magic"})
    with pytest.raises(ValueError, match=r"weights.scm.w4: missing"):
        settings.with_overrides({"weights.scm.w4": None})


def strike(problem):
    """Constant torques, shoulder down and elbow in: from q0(7) the plate strikes the cube mid-horizon."""
    torques = np.zeros((problem.n_knots, 7))
    torques[:, 1], torques[:, 3] = 0.2 * problem.scene.torque_limit[1], -0.2 * problem.scene.torque_limit[3]
    return problem.with_torques(torques)


def test_linearization_is_mujocos_transition_fd_from_the_nominal_warmstart(settings):
    """Steps of the strike without a contact switch: the native linearization is mjd_transitionFD's
    forward differences, with the constraint solver warmstarted at the nominal step's accelerations."""
    problem = make_problem(settings, "vscm")
    model = problem.scene.model
    evaluation = problem.evaluate(strike(problem))
    states_before = problem.states_before(evaluation)
    controls = problem.simulator.step_controls(evaluation.knot_controls)
    nx, ns, eps = 2 * model.nv, model.nsensordata, settings.gradient.epsilon
    data = mujoco.MjData(model)
    for step in (0, 40, 100):  # the cube on the table; the plate on it, too
        ours = linearize(model, (data,), states_before[step:step + 1], controls[step:step + 1], eps)
        assert ours.info()["one_sided_columns"] == 0 and ours.info()["unresolved_columns"] == 0
        mujoco.mj_setState(model, data, states_before[step], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        data.ctrl[:], data.qacc_warmstart[:] = controls[step], 0.0
        mujoco.mj_forward(model, data)
        assert data.ncon > 0
        data.qacc_warmstart[:] = data.qacc
        A, B = np.zeros((nx, nx)), np.zeros((nx, model.nu))
        C, D = np.zeros((ns, nx)), np.zeros((ns, model.nu))
        mujoco.mjd_transitionFD(model, data, eps, 0, A, B, C, D)
        for native, reference in zip((ours.A[0], ours.B[0], ours.C[0], ours.D[0]), (A, B, C, D)):
            np.testing.assert_allclose(native, reference, rtol=0, atol=1e-12 * np.abs(reference).max())


def test_object_columns_left_out_before_the_arm_touches_the_object_change_no_sensitivity(settings):
    """Without the virtual force the object's columns of the steps before the first touch are not
    computed: nothing the torques do reaches the object there, so the sensitivities of the sensors
    and the final state to every knot are those of the full linearization."""
    posed = make_problem(settings, "vscm")
    problem = physical_twin(posed, posed.cost)
    z = strike(problem)
    evaluation = problem.evaluate(z)
    touching = np.flatnonzero(evaluation.sensordata[:, problem.scene.sensors.contact_found.start] > 0)
    touch = int(touching[0])
    assert 0 < touch < problem.n_steps // 2
    assert np.linalg.norm(problem.scene.object_qpos(evaluation.states[-1])[:2] - problem.scene.object_qpos(
        problem.initial_state)[:2]) > 0.05  # struck: the object's motion after the touch matters

    skipped = problem.linearize(z)
    full = linearize(problem.scene.model, problem._linearization_data,
                     problem.states_before(evaluation),
                     problem.simulator.step_controls(evaluation.knot_controls), problem.derivative_settings.epsilon)
    nv = problem.scene.model.nv
    columns = np.r_[problem.scene.object_dofs, nv + problem.scene.object_dofs]
    assert not skipped.A[:touch][:, :, columns].any() and full.A[:touch][:, :, columns].any()
    np.testing.assert_array_equal(skipped.A[touch:], full.A[touch:])
    S = problem.steps_per_knot
    for left_out, computed in zip(forward_sensitivities(skipped.A, skipped.B, skipped.C, skipped.D, S),
                                  forward_sensitivities(full.A, full.B, full.C, full.D, S)):
        np.testing.assert_allclose(left_out, computed, rtol=1e-12, atol=1e-12 * np.abs(computed).max())


def test_a_physical_stage_expansion_stays_finite_with_the_plate_inside_the_object(settings):
    # Without the virtual force the contact actuator's control is 0, where SCM's law k exp(-(c/k) phi)
    # has an infinite derivative in k once the plate's centre is inside the object (phi < 0). No
    # decision drives that actuator, so iLQR's expansion must not see it (0 * inf made it NaN, and
    # iLQR stalled there).
    base = make_problem(settings, "scm")
    scene = base.scene
    state = base.initial_state.copy()
    data = scene.data_at(scene.arm_qpos(state))
    inside = data.site_xpos[scene.robot_site_id] + [scene.object_half_size[0] - 0.01, 0.0, 0.0]
    scene.object_qpos(state)[:3] = inside
    problem = physical_twin(PushProblem(base.simulator, state, base.task, base.cost, settings.gradient,
                                        settings.task.position_error_scale_min_m), base.cost)
    z = problem.initial_guess
    evaluation = problem.evaluate(z)
    assert problem.signed_distance(evaluation.sensordata)[0] < 0
    assert not np.isfinite(problem.linearize(z).B[0][:, scene.contact_actuator_id]).all()
    expansion = problem.knot_expansion(z)
    for name in ("fx", "fc", "lx", "lc", "lxx", "lcc", "lcx", "vx", "vxx"):
        assert np.isfinite(getattr(expansion, name)).all(), name


def test_a_linearization_of_every_other_step_keeps_the_gradients_direction_and_the_contact_switches(settings):
    """gradient.stride 2 (the executor's replans): the even steps and the steps where the plate's contact begins
    or ends are linearized as in full, each other step takes the Jacobians of the one before, and the strike's
    gradient still points the way of the exact one."""
    posed, strided_posed = make_problem(settings, "vscm"), make_problem(settings, "vscm", **{"gradient.stride": 2})
    exact_problem = physical_twin(posed, posed.cost)
    strided_problem = physical_twin(strided_posed, strided_posed.cost)
    z = strike(exact_problem)
    exact, strided = exact_problem.linearize(z), strided_problem.linearize(z)
    found = exact_problem.evaluate(z).sensordata[:, exact_problem.scene.sensors.contact_found.start] > 0
    switches = np.flatnonzero(found[1:] != found[:-1]) + 1
    assert switches.size and np.any(switches % 2 == 1)  # an odd step that a plain stride would have copied
    computed = np.union1d(np.arange(0, len(found), 2), np.union1d(switches - 1, switches))
    copied = np.setdiff1d(np.arange(len(found)), computed)
    assert copied.size > len(found) // 3
    np.testing.assert_array_equal(strided.A[computed], exact.A[computed])
    np.testing.assert_array_equal(strided.B[copied], strided.B[copied - 1])
    assert not np.array_equal(exact.A[copied], strided.A[copied])
    g_exact, g_strided = exact_problem.gradient(z), strided_problem.gradient(z)
    assert np.dot(g_exact, g_strided) > 0.98 * np.linalg.norm(g_exact) * np.linalg.norm(g_strided)
