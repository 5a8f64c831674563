"""The command-line tools, run as a user would (separate processes)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

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


def test_plan_json():
    result = run("cito-plan", "--contact-model", "scm", "--beta", "7", "--json")
    assert result.returncode == 0, result.stderr
    plan = json.loads(result.stdout)
    for key in ("position_error_m", "orientation_error_rad", "physical_inaccuracy_Ns", "replay_position_error_m",
                "solve_time_s", "iterations", "status", "success", "contact_model", "beta", "initial_distance_m"):
        assert key in plan, key
    assert plan["contact_model"] == "scm" and plan["success"] is True


def test_plan_human_readable_with_target():
    result = run("cito-plan", "--contact-model", "scm", "--beta", "7", "--target", "1.2", "0.05", "0.0",
                 "--max-iter", "5")
    assert result.returncode == 0, result.stderr
    assert "position error" in result.stdout and "replay error" in result.stdout
    assert "solving, iteration" in result.stderr  # the progress display


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
