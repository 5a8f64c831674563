"""The command-line tools, run as a user would (separate processes)."""
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.plan import plan_push
from cito_ros.planner.results import METRIC_NAMES
from cito_ros.settings import SceneConfig
from cito_ros.studies import asks

BIN = Path(sys.executable).parent


def run(*args, timeout=300):
    return subprocess.run([str(BIN / args[0]), *args[1:]], capture_output=True, text=True, timeout=timeout,
                          env=os.environ.copy())


@pytest.mark.parametrize("beta, distance", [(5, 0.30), (6, 0.17), (7, 0.11)])
def test_scene_info_json(beta, distance):
    result = run("cito-scene", "info", "--beta", str(beta), "--json")
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    assert info["beta"] == beta and abs(info["initial_distance_m"] - distance) < 0.015
    assert len(info["q0"]) == 7 and len(info["object_position_m"]) == 3


def test_scene_info_rejects_a_bad_beta():
    result = run("cito-scene", "info", "--beta", "0")
    assert result.returncode == 2 and "beta must be positive" in result.stderr


def test_plan_json_is_the_library_plan(settings):
    """cito-plan and plan_push give the same plan for the same problem, to the last bit."""
    result = run("cito-plan", "--contact-model", "scm", "--beta", "7", "--target", "1.15", "0.03", "0.1", "--json")
    assert result.returncode == 0, result.stderr
    plan = json.loads(result.stdout)
    for key in (*METRIC_NAMES, "contact_model", "beta", "initial_distance_m", "final_object_position_m"):
        assert key in plan, key
    library = plan_push("scm", 7, target_position_m=[1.15, 0.03], target_yaw_rad=0.1, settings=settings).summary()
    for key in ("position_error_m", "orientation_error_rad", "planned_position_error_m", "final_object_position_m",
                "max_joint_speed_ratio", "iterations", "success"):
        assert plan[key] == library[key], key


def test_plan_json_tells_the_reach_zone_as_push_limits_does():
    """steady_reach_margin_m: the steady push reach, computed from the model as push-limits computes it, minus the
    goal's distance; positive inside it (a short push), negative beyond it (the paper's push, 1.24 m out)."""
    limits = run("cito-bench", "push-limits", "--heights", "0.14", "--step", "0.01", "--json")
    assert limits.returncode == 0, limits.stderr
    report = json.loads(limits.stdout)
    for target, inside in (("1.09", True), ("1.24", False)):
        result = run("cito-plan", "--beta", "7", "--target", target, "0", "0", "--max-iter", "1", "--json")
        assert result.returncode == 0, result.stderr
        margin = json.loads(result.stdout)["steady_reach_margin_m"]
        assert margin == pytest.approx(report["planner_steady_reach_m"] - float(target))
        assert (margin >= 0) == inside == (report["steady_reach_m"]["face"] >= float(target))
    beyond = run("cito-plan", "--beta", "7", "--target", "1.24", "0", "0", "--max-iter", "1")
    assert "reach zone         strike" in beyond.stdout and "relies on a strike" in beyond.stdout


def test_plan_json_for_a_refused_request():
    result = run("cito-plan", "--target", "1.9", "0", "0", "--json")
    assert result.returncode == 2
    refused = json.loads(result.stdout)
    assert refused["status"] == "invalid_request" and "off the table" in refused["message"]


def test_plan_human_readable_with_target():
    result = run("cito-plan", "--contact-model", "scm", "--beta", "7", "--target", "1.2", "0.05", "0.0",
                 "--max-iter", "5")
    assert result.returncode == 0, result.stderr
    assert "executed error" in result.stdout and "planned error" in result.stdout
    assert "solving: " in result.stderr and "it/s" in result.stderr  # the progress display


def test_plan_from_where_the_object_is():
    result = run("cito-plan", "--contact-model", "scm", "--beta", "7", "--object", "0.99", "0.05", "0.3",
                 "--target", "1.09", "0.05", "0.3", "--max-iter", "3", "--json")
    assert result.returncode == 0, result.stderr
    plan = json.loads(result.stdout)
    assert plan["object_start_position_m"][:2] == pytest.approx([0.99, 0.05], abs=1e-6)
    assert plan["object_start_yaw_rad"] == 0.3
    refused = run("cito-plan", "--beta", "7", "--object", "0.87", "0", "0", "--json")
    assert refused.returncode == 2
    assert "intersects the arm's" in json.loads(refused.stdout)["message"]


@pytest.mark.parametrize("args, message", [
    (["--contact-model", "soft"], "invalid choice: 'soft'"),
    (["--target", "nan", "0", "0"], "target position contains NaN or Inf"),
    (["--max-iter", "0"], "max_iter must be a positive integer"),
    (["--time-limit", "-3"], "time_limit_s must be positive"),
    (["--beta", "-2"], "beta must be positive"),
])
def test_plan_rejects_bad_options(args, message):
    result = run("cito-plan", *args)
    assert result.returncode == 2
    assert message in result.stderr


def test_bench_gradient_times_the_curvature_beside_the_gradient():
    result = run("cito-bench", "gradient", "--repeats", "2", "--json")
    assert result.returncode == 0, result.stderr
    timed = json.loads(result.stdout)
    for key in ("gradient_ms", "linearization_ms", "knot_expansion_ms", "residual_jacobian_ms", "rollout_ms"):
        assert math.isfinite(timed[key]) and timed[key] > 0.0, key
    assert timed["gradient_and_curvature_ratio"] == pytest.approx(
        (timed["gradient_ms"] + timed["knot_expansion_ms"]) / timed["rollout_ms"])


def test_bench_speed_vs_error_writes_table_csv_and_plot(tmp_path):
    result = run("cito-bench", "speed-vs-error", "--quick", "--out", str(tmp_path), timeout=900)
    assert result.returncode == 0, result.stderr
    for name in ("speed_vs_error.csv", "speed_vs_error_runs.csv", "speed_vs_error.md", "speed_vs_error.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert "| VSCM | default |" in (tmp_path / "speed_vs_error.md").read_text()
    assert "speed vs error" in result.stderr  # the progress display


def test_bench_hard_json(tmp_path):
    result = run("cito-bench", "hard", "--cases", "target_reached", "target_off_table", "--models", "scm",
                 "--json", "--out", str(tmp_path), timeout=900)
    assert result.returncode == 0, result.stderr
    records = json.loads(result.stdout)
    assert [(r["case"], r["contact_model"]) for r in records] == [("target_reached", "scm"), ("target_off_table", "scm")]
    for record in records:
        for key in ("case", "contact_model", "status", "success", "position_error_m", "planned_position_error_m",
                    "solve_time_s"):
            assert key in record
    assert records[1]["status"] == "invalid_request"
    assert (tmp_path / "hard_cases.md").is_file() and (tmp_path / "hard_cases.csv").is_file()


def test_bench_closed_loop_takes_a_fixed_compute_clock_only_in_process():
    result = run("cito-bench", "closed-loop", "--ros", "--clock-s", "2", "0.1")
    assert result.returncode == 2 and "only in process (not with --ros" in result.stderr
    result = run("cito-bench", "closed-loop", "--clock-s", "2", "nan")
    assert result.returncode == 2 and "two finite times of zero or more" in result.stderr


def test_bench_hard_rejects_unknown_cases():
    result = run("cito-bench", "hard", "--cases", "moon_landing")
    assert result.returncode == 2 and "unknown cases ['moon_landing']" in result.stderr


def test_bench_roughness_scans_each_scene_and_names_an_unknown_one():
    result = run("cito-bench", "roughness", "--scenes", "default", "fine_step", "--directions", "1", "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["reference_step_rad"] == pytest.approx(1e-5) and report["torque_step_Nm"] == pytest.approx(5e-4)
    assert [scene["timestep_s"] for scene in report["scenes"].values()] == [0.005, 0.002]
    for scene in report["scenes"].values():
        assert [case["beta"] for case in scene["cases"]] == [5, 6, 7]
        # the scripted pushes move the cube, and a scan's tiny changes move where it ends
        assert all(case["tracked_span_m"] > 0 and case["open_loop_span_m"] > 0 for case in scene["cases"])
    refused = run("cito-bench", "roughness", "--scenes", "default", "moon", "--plans")  # before any solve or scan
    assert refused.returncode == 2 and "unknown scene 'moon'" in refused.stderr


def test_bench_push_limits_prints_the_steady_reach_and_refuses_a_bad_step():
    result = run("cito-bench", "push-limits", "--heights", "0.10", "--step", "0.04", "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert [row["contact"] for row in report["farthest"]] == ["face", "rim"]
    assert report["steady_reach_m"]["face"] < report["steady_reach_m"]["rim"] <= report["push_reach_m"]
    # positions 4 cm apart from 0.95 m out to where the plate cannot reach, for each contact
    face = [row["plate_distance_m"] for row in report["positions"] if row["contact"] == "face"]
    assert face[0] == pytest.approx(0.95) and np.allclose(np.diff(face), 0.04)
    refused = run("cito-bench", "push-limits", "--step", "0")
    assert refused.returncode == 2 and "positive step" in refused.stderr



def test_bench_refusals_times_a_one_shot_refusal_of_each_kind_and_its_reason():
    result = run("cito-bench", "refusals", "--n", "1", "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    reasons = {row["request"]: row["message"] for row in report["requests"]}
    assert "behind the object's pushed face" in reasons["pull back"]
    assert "turns the object by 0.60 rad" in reasons["turn in place"]
    assert "beyond the 1.249 m" in reasons["beyond the reach"]
    assert "off the table" in reasons["off the table"]
    assert "unknown scene 'no_such_scene'" in reasons["unknown scene"]
    assert all(len(row["seconds"]) == 1 and row["seconds"][0] > 0 for row in report["requests"])


def test_bench_refusals_starts_cito_plan_with_the_callers_environment_not_the_gl_backend_cito_bench_sets():
    from cito_ros.cli.refusals import refusal_benchmark

    caller = {name: value for name, value in os.environ.items() if name != "MUJOCO_GL"}
    seen = subprocess.run([sys.executable, "-c", "import os, cito_ros.cli.bench as b; "
                           "print('MUJOCO_GL' in b.CALLER_ENVIRONMENT, os.environ['MUJOCO_GL'])"],
                          env=caller, capture_output=True, text=True, check=True).stdout.split()
    assert seen == ["False", "osmesa"]  # cito-bench renders with OSMesa; the one-shot processes it times do not
    with pytest.raises(ValueError, match="was not refused"):  # the processes run with the environment given
        refusal_benchmark(1, environment={**caller, "MUJOCO_GL": "no_such_backend"})


def test_bench_figures(tmp_path):
    result = run("cito-bench", "figures", "--out", str(tmp_path), timeout=900)
    assert result.returncode == 0, result.stderr
    for name in ("snapshots.png", "vscm_stiffness.png", "contact_law.png", "contact_forces.png"):
        assert (tmp_path / name).stat().st_size > 10_000, name


@pytest.mark.slow
def test_bench_collisions(tmp_path):
    result = run("cito-bench", "collisions", "--quick", "--json", "--out", str(tmp_path), timeout=1800)
    assert result.returncode == 0, result.stderr
    comparison = json.loads(result.stdout)["scenes"]
    assert comparison["minimal"]["explicit_pairs"] == 11 and comparison["all collisions"]["explicit_pairs"] == 0
    assert comparison["all collisions"]["geoms_in_broad_phase"] > comparison["minimal"]["geoms_in_broad_phase"] == 0


def test_the_main_job_cancelled_returns_the_best_plan_so_far(tmp_path):
    # a push 62 degrees off the cube's pushed face, 24 cm away: two pushes, the first across on the side face, whose
    # plan alone takes seconds; cancelled in it, the answer is that push judged against the goal
    result = run("cito-demo", "--target", "1.10", "-0.21", "-0.49", "--cancel-after", "1", "--bag-directory",
                 str(tmp_path), timeout=300)
    assert result.returncode == 0, result.stderr
    assert "cancelling the goal after 1 s" in result.stderr
    assert "status 5 (no success) the solve was cancelled" in result.stdout
    bags = [p for p in tmp_path.iterdir()]
    assert len(bags) == 1 and f"bag                {bags[0]}" in result.stdout
    assert (bags[0] / "metadata.yaml").is_file()


def test_every_speed_vs_error_case_can_be_posed_in_every_variants_scene(settings):
    # a case the planner refuses would enter the study's medians as a 0 s solve
    for variant in asks.VARIANTS:
        settings.with_overrides(variant.overrides)  # a misspelt parameter fails here, not an hour into the study
        for case in asks.SWEEP_CASES:
            scene = variant.scene or case.scene
            x, y = SceneConfig.load(scene).object.position_m
            target = np.array([x + case.push[0], y + case.push[1]])
            build_problem(settings, PushRequest("scm", case.beta, target_position_m=target,
                                                target_yaw_rad=case.push[2], scene=scene))


def test_the_main_job_plans_then_executes_open_and_closed_loop_in_a_mismatched_world(tmp_path):
    result = run("cito-demo", "--bag-directory", str(tmp_path), timeout=300)
    assert result.returncode == 0, result.stderr
    assert "status 0 (SUCCESS)" in result.stdout
    assert "open loop" in result.stdout and "closed loop" in result.stdout
    table = result.stdout.split("true error at rest", 1)[1].splitlines()[0]
    assert len(re.findall(r"\d+\.\d\d cm \d\.\d{3} rad", table)) == 2  # both outcomes, on the world's truth
    bags = sorted(p.name for p in tmp_path.iterdir() if p.name != "logs")
    assert len(bags) == 2 and bags[0].startswith("execute_") and bags[1].startswith("plan_")
    # and the nodes' own words, for an execution that went wrong
    assert "ready" in (tmp_path / "logs" / "cito-executor-node.log").read_text()
    assert "simulating" in (tmp_path / "logs" / "cito-sim-robot.log").read_text()
    assert (tmp_path / bags[0] / "metadata.yaml").is_file()
