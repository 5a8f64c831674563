"""The scripted push, the physical pipeline's first start (cito_ros.planner.scripted). Real MuJoCo."""
import numpy as np
import pytest

from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.plan import plan_push
from cito_ros.planner.scripted import _cross, joint_path, plate_path, scripted_torques
from cito_ros.planner.stages import physical_twin
from cito_ros.studies.benchmarks import roughness_benchmark
from cito_ros.studies.targets import draw_goals


def executor(settings, beta, target, yaw=0.0):
    problem = build_problem(settings, PushRequest("vscm", beta, target_position_m=np.array(target),
                                                  target_yaw_rad=yaw)).problem
    return physical_twin(problem, problem.cost)


@pytest.mark.parametrize("beta, target, yaw", [(7, [1.09, 0.0], 0.0), (5, [1.10, 0.06], 0.3), (6, [1.05, -0.05], 0.0)])
def test_the_scripted_torques_push_the_object_most_of_the_way_to_the_goal(settings, beta, target, yaw):
    # executed open loop without the virtual force, as the physical stages start from them
    problem = executor(settings, beta, target, yaw)
    evaluation = problem.evaluate(problem.with_torques(scripted_torques(problem, settings.stages.scripted,
                                                                        settings.tracking)))
    scene = problem.scene
    start, end = scene.object_qpos(problem.initial_state)[:2], scene.object_qpos(evaluation.states[-1])[:2]
    assert evaluation.finite and not evaluation.warnings
    assert np.linalg.norm(end - target) < 0.5 * np.linalg.norm(np.asarray(target) - start)


def test_the_plate_path_ends_with_the_objects_face_at_the_goal(settings):
    script = settings.stages.scripted
    problem = executor(settings, 6, [1.10, 0.05])
    path, along = plate_path(problem, script)
    scene = problem.scene
    assert along == pytest.approx(np.r_[np.array([0.11, 0.05]) / np.hypot(0.11, 0.05), 0.0])
    face_to_plate = scene.object_half_size[0] + scene.plate_half_thickness_m
    lift = np.array([0.0, 0.0, script.contact_height_m])
    assert path[-1] == pytest.approx(problem.task.target_position_m - face_to_plate * along + lift)
    at_approach = int(round(script.approach_fraction * (len(path) - 1)))
    start = scene.object_qpos(problem.initial_state)[:3]
    assert path[at_approach] == pytest.approx(start - (face_to_plate + script.standoff_m) * along + lift, abs=1e-3)


def test_the_joint_path_keeps_within_the_speed_fraction_and_inside_the_ranges(settings):
    script = settings.stages.scripted
    problem = executor(settings, 5, [1.24, 0.0])  # the paper's push: its end is out of reach, the joints lag
    q = joint_path(problem, script).q
    scene, dt = problem.scene, problem.simulator.timestep_s
    assert np.all(np.abs(np.diff(q, axis=0)) <= script.speed_fraction * scene.velocity_limit * dt + 1e-12)
    low, high = scene.joint_range.T
    assert np.all(q[1:] >= low + script.joint_margin_rad - 1e-12) and np.all(q[1:] <= high - script.joint_margin_rad + 1e-12)


def test_a_target_on_the_objects_start_is_scripted_as_a_touch(settings):
    problem = executor(settings, 6, [0.99, 0.0], 0.4)  # a turn in place
    evaluation = problem.evaluate(problem.with_torques(scripted_torques(problem, settings.stages.scripted,
                                                                        settings.tracking)))
    scene = problem.scene
    moved = scene.object_qpos(evaluation.states[-1])[:2] - scene.object_qpos(problem.initial_state)[:2]
    assert evaluation.finite and np.linalg.norm(moved) < 0.02


def test_a_push_near_the_reach_the_first_script_misses_is_planned_by_a_variant_before_any_discovery(settings):
    # goal 20 of `cito-bench targets` (1.202 m from the base, within 5 cm of the push reach): SCM's first
    # script ends at the goal but a PD controller's execution of it does not; the variant with the plate
    # 6 cm above the cube's centre succeeds (README: script variants)
    goal = draw_goals(21, 0, settings)[0][20]
    result = plan_push("scm", goal.beta, target_position_m=np.array(goal.target_position_m),
                       target_yaw_rad=goal.target_yaw_rad, settings=settings)
    names = [stage.name for stage in result.stages]
    assert result.metrics.success
    assert any("scripted:" in name for name in names) and names[-1].split(": ")[0].endswith("scripted 2")
    assert not any("discovery" in name for name in names)


def test_a_scripts_success_short_of_the_goal_margin_runs_the_other_scripts_and_then_ends_the_search(settings):
    # goal 24 of `cito-bench targets` (1.228 m from the base): SCM's first script ends at the goal,
    # 1.91 cm off, short of the 1 cm margin; the two variants run and miss, and the first script's plan is
    # returned without any discovery (stages.solve_physical)
    goal = draw_goals(25, 0, settings)[0][24]
    result = plan_push("scm", goal.beta, target_position_m=np.array(goal.target_position_m),
                       target_yaw_rad=goal.target_yaw_rad, settings=settings)
    starts = [stage.name.split(": ")[0].split(", ")[-1] for stage in result.stages]  # "horizon 2 s, scripted 3"
    margin = settings.stages.goal_margin * settings.task.success_position_error_m
    first = [stage.position_error_m for start, stage in zip(starts, result.stages) if start == "scripted"]
    assert result.metrics.success and margin <= result.metrics.position_error_m == min(first)
    assert sorted(set(starts)) == ["scripted", "scripted 2", "scripted 3"]


def test_a_scripted_push_that_passes_over_the_object_leaves_its_outcome_unmoved_by_tiny_changes():
    # the roughness scan of a push that never touches the cube: the arm alone is smooth, so every jump is 0
    report = roughness_benchmark(("default",), betas=(7,), directions=1, points=5,
                                 overrides={"stages.scripted.contact_height_m": 0.3})
    case, = report["scenes"]["default"]["cases"]
    assert case["tracked_jump_m"] == case["open_loop_jump_m"] == 0.0
    assert case["hop_m"] < 1e-6
    with pytest.raises(ValueError, match="an odd number of points, at least 3"):
        roughness_benchmark(("default",), points=4)


def test_the_roughness_scan_of_plans_is_centred_on_the_plan_the_planner_returns():
    # with plans, the scan's unperturbed point is the returned torques executed: the same executed error
    # as the plan's own (plans are bit-identical request to request)
    report = roughness_benchmark(("default",), betas=(7,), directions=1, points=3, plans=True)
    case, = report["scenes"]["default"]["cases"]
    plan = plan_push("scm", 7)
    assert report["scanned"] == "plans" and case["success"] == plan.metrics.success
    assert case["executed_error_m"] == plan.metrics.position_error_m


def test_the_scripts_cross_product_is_numpys_bit_for_bit():
    # the script's inverse kinematics runs it 960 times a script; a last-digit difference moves plans near the reach
    rng = np.random.default_rng(7)
    for a, b in rng.standard_normal((200, 2, 3)) * np.array([[1.0], [1e-6]]):
        assert np.array_equal(_cross(a, b), np.cross(a, b))
