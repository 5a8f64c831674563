"""Planning: task success, constraints and bounds at the solution, cancellation, statuses,
determinism and bad options. Real MuJoCo and real IPOPT."""
import threading

import numpy as np
import pytest

from cito_ros.planner import plan_push
from cito_ros.results import IterationLog, Status


@pytest.fixture(scope="module")
def solved(settings):
    """One plan per contact model on the paper's easiest case (beta = 7)."""
    return {name: plan_push(name, 7, settings=settings) for name in ("cccm", "scm", "vscm")}


@pytest.mark.parametrize("name", ["cccm", "scm", "vscm"])
def test_each_model_succeeds_on_beta_7(solved, name):
    result = solved[name]
    assert result.metrics.success, result.summary()
    assert result.metrics.position_error_m < 0.10
    assert result.trajectory.finite and result.replay.finite and result.trajectory.warnings == {}
    assert result.status is not Status.NUMERICAL_ERROR


def test_cccm_constraints_hold_at_the_solution(solved, settings):
    result = solved["cccm"]
    tolerance = settings.solver.ipopt_options["constr_viol_tol"]
    phi = result.trajectory.signed_distance_m.reshape(20, 10).mean(axis=1)
    gamma, slack = result.knot_variables["gamma_N"], result.knot_variables["slack_Nm"]
    assert np.all(phi >= -tolerance)
    assert np.all(gamma >= 0) and np.all(slack >= 0)
    assert np.all(phi * gamma - slack <= tolerance)
    np.testing.assert_array_equal(result.trajectory.gamma_N, np.repeat(gamma, 10))


def test_vscm_stiffness_stays_in_bounds(solved):
    k = solved["vscm"].knot_variables["stiffness_N"]
    assert np.all(k >= 0) and np.all(k <= 100.0)
    np.testing.assert_array_equal(solved["vscm"].trajectory.stiffness_N, np.repeat(k, 10))


def test_scm_keeps_its_fixed_stiffness(solved):
    np.testing.assert_array_equal(solved["scm"].knot_contact_control, np.full(20, 100.0))


@pytest.mark.parametrize("name", ["cccm", "scm", "vscm"])
def test_torques_stay_within_the_motor_limits(solved, name):
    limits = np.array([80, 80, 40, 40, 9, 9, 9])
    assert np.all(np.abs(solved[name].knot_torques_Nm) <= limits + 1e-9)


def test_result_metrics_are_consistent(solved):
    result = solved["vscm"]
    m = result.metrics
    assert m.physical_inaccuracy_Ns == pytest.approx(0.005 * result.trajectory.gamma_N.sum())
    final = result.trajectory.object_position_m[-1]
    assert m.position_error_m == pytest.approx(np.linalg.norm(final - result.target_position_m))
    replay_final = result.replay.object_position_m[-1]
    assert m.replay_position_error_m == pytest.approx(np.linalg.norm(replay_final - result.target_position_m))
    assert np.all(result.replay.gamma_N == 0)
    assert result.knot_q.shape == (21, 7) and result.knot_torques_Nm.shape == (20, 7)
    assert [entry.iteration for entry in result.iteration_log] == sorted(entry.iteration for entry in result.iteration_log)
    assert m.iterations == result.iteration_log[-1].iteration


def test_iteration_callback_and_cancellation(settings):
    cancel = threading.Event()
    seen: list[IterationLog] = []

    def callback(entry: IterationLog) -> None:
        seen.append(entry)
        if len(seen) == 4:
            threading.Thread(target=cancel.set).start()
            threading.Event().wait(0.05)  # let the other thread set it

    result = plan_push("vscm", 6, settings=settings, iteration_callback=callback, cancel=cancel)
    assert result.status is Status.CANCELLED
    assert len(seen) == 4  # stopped at the first iteration boundary after the cancel
    assert all(isinstance(e.cost, float) and e.elapsed_s >= 0 for e in seen)
    assert result.trajectory.finite  # the best iterate so far is returned, simulated


def test_iteration_limit(settings):
    result = plan_push("scm", 7, settings=settings.with_overrides({"solver.max_iter": 2}))
    assert result.status is Status.ITERATION_LIMIT and result.metrics.iterations <= 2


def test_time_limit(settings):
    result = plan_push("cccm", 7, settings=settings.with_overrides({"solver.time_limit_s": 1e-3}))
    assert result.status is Status.TIME_LIMIT and result.trajectory.finite


def test_same_case_twice_gives_identical_plans(settings):
    first, second = (plan_push("scm", 7, settings=settings) for _ in range(2))
    assert np.array_equal(first.knot_torques_Nm, second.knot_torques_Nm)
    assert first.metrics.position_error_m == second.metrics.position_error_m


class TestBadOptions:
    def test_unknown_contact_model(self, settings):
        with pytest.raises(ValueError, match="unknown contact model 'rigid'"):
            plan_push("rigid", 7, settings=settings)

    def test_nan_target(self, settings):
        with pytest.raises(ValueError, match="target position contains NaN or Inf"):
            plan_push("vscm", 7, settings=settings, target_position_m=[np.nan, 0.0])

    def test_bad_target_shape(self, settings):
        with pytest.raises(ValueError, match=r"must be \(x, y\) or \(x, y, z\)"):
            plan_push("vscm", 7, settings=settings, target_position_m=[1.0, 0.0, 0.1, 0.0])

    def test_nan_yaw(self, settings):
        with pytest.raises(ValueError, match="target yaw must be finite"):
            plan_push("vscm", 7, settings=settings, target_yaw_rad=float("nan"))


class TestUnreachableTargets:
    def test_off_the_table(self, settings):
        with pytest.raises(ValueError, match=r"target \(1.900, 0.000\) m is off the table"):
            plan_push("vscm", 7, settings=settings, target_position_m=[1.9, 0.0])

    def test_lifted(self, settings):
        with pytest.raises(ValueError, match="is not the object's resting height"):
            plan_push("vscm", 7, settings=settings, target_position_m=[1.2, 0.0, 0.5])

    def test_beyond_reach(self, settings):
        with pytest.raises(ValueError, match="beyond the 1.25 m the arm can push"):
            plan_push("vscm", 7, settings=settings, target_position_m=[1.2, 0.5])
