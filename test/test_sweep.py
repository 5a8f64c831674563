"""Sweeps on Ray: the same records as in process, a killed worker is one case's failure, resumption.
Real Ray (embedded, local), real solves."""
from __future__ import annotations

import dataclasses
import math
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from cito_ros.planner.results import PHASE_METRICS
from cito_ros.settings import load_settings
from cito_ros.studies import sweep, targets, targets_report

TIMINGS = ("solve_time_s", *PHASE_METRICS)


def small_sweep(settings, goals: int = 4, models=("scm", "vscm")):
    """A few seeded goals with each model, each solve capped at a few iterations per stage."""
    drawn, _ = targets.draw_goals(goals, seed=3, settings=settings)
    return targets.jobs(drawn, models, settings)


def without_timings(record: dict) -> dict:
    return {k: v for k, v in record.items() if k not in TIMINGS}


def test_solves_one_at_a_time_plan_with_the_configured_threads_and_several_at_once_with_one_each():
    settings = load_settings()
    assert settings.gradient.threads > 1
    assert sweep.settings_for(settings, 0) == settings and sweep.settings_for(settings, 1) == settings
    for workers in (None, 2):
        shared = sweep.settings_for(settings, workers)
        assert shared.gradient.threads == 1 and not shared.stages.parallel


def test_a_sweep_gives_the_same_records_on_ray_and_in_process():
    settings = load_settings().with_overrides({"solver.max_iter": 4})
    in_process = sweep.run_sweep(small_sweep(sweep.settings_for(settings, 0)), workers=0)
    on_ray = sweep.run_sweep(small_sweep(sweep.settings_for(settings, 2)), workers=2)
    assert [r["key"] for r in on_ray] == [r["key"] for r in in_process]
    assert not any(r.get("failed") for r in on_ray + in_process)
    # the threaded in-process solve and the single-threaded Ray task plan the same bits
    assert [without_timings(r) for r in on_ray] == [without_timings(r) for r in in_process]
    report = targets_report.report(on_ray, [], targets.region(settings))
    assert set(report["models"]) == {"scm", "vscm"} and report["models"]["scm"]["goals"] == 4
    for model, split in report["by_zone"]["models"].items():
        assert split["steady"]["goals"] + split["strike"]["goals"] == 4
        assert split["steady"]["successes"] + split["strike"]["successes"] == \
            sum(r["success"] for r in on_ray if r["contact_model"] == model)
    assert "Goals inside the steady push reach" in targets_report.markdown(report)
    # every plan also tracked with its reference off; the report counts the successes' executions
    assert all(len(r["offset_tracked_position_errors_m"]) == targets.OFFSETS for r in on_ray)
    for model, summary in report["models"].items():
        successes = [r for r in on_ray if r["contact_model"] == model and r["success"]]
        assert summary["offset_executions_within_2cm"] == [
            sum(e < 0.02 for r in successes for e in r["offset_tracked_position_errors_m"]),
            targets.OFFSETS * len(successes)]


def test_the_report_sets_apart_the_goals_beyond_the_steady_push_reach():
    def record(goal: int, perturbation: str, success: bool, error_m: float, margin_m: float):
        return {"goal": goal, "contact_model": "scm", "perturbation": perturbation, "success": success,
                "position_error_m": error_m, "solve_time_s": 1.0, "target_position_m": [1.1 - margin_m, 0.0, 0.1],
                "steady_reach_margin_m": margin_m}

    # a goal beyond the steady reach whose perturbed twin flips, one inside whose twin moves 5 mm
    records = [record(0, "none", True, 0.015, -0.01), record(0, "target x +1e-9 m", False, 0.03, -0.01),
               record(1, "none", True, 0.002, 0.05), record(1, "target x +1e-9 m", True, 0.007, 0.05)]
    split = targets_report.by_zone(records)
    assert split["steady_reach_m"] == [1.1]
    scm = split["models"]["scm"]
    assert (scm["strike"]["goals"], scm["strike"]["successes"], scm["strike"]["pairs_stable"]) == (1, 1, 0)
    assert (scm["steady"]["goals"], scm["steady"]["pairs_stable"], scm["steady"]["perturbed_pairs"]) == (1, 1, 1)
    assert scm["steady"]["executed_position_error_m"]["median"] == 0.002


def _descendants(pid: int) -> set[int]:
    """The process ids below `pid` in the process tree (from /proc)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parent = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(parent, []).append(int(entry.name))
    found, stack = set(), [pid]
    while stack:
        for child in children.get(stack.pop(), []):
            if child not in found:
                found.add(child)
                stack.append(child)
    return found


def _kill_one_ray_task(killed: list[int], deadline_s: float = 120.0) -> None:
    """SIGKILL the first process of the Ray cluster this test started (a descendant of this process) that runs
    a task (its title is ray::_call); nothing else on the machine is signalled."""
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline and not killed:
        for pid in sorted(_descendants(os.getpid())):
            try:
                title = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0]
            except OSError:
                continue
            if title.startswith(b"ray::_call"):
                time.sleep(1.0)  # well into its solve
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
        time.sleep(0.1)


def test_a_killed_worker_is_reported_as_that_case_s_failure(tmp_path):
    # without the scripted start the first solve outlasts the killer's second (with it, about half a second)
    settings = sweep.settings_for(load_settings().with_overrides({"stages.scripted.enabled": False}), 1)
    jobs = small_sweep(settings, goals=2, models=("vscm",))
    killed: list[int] = []
    killer = threading.Thread(target=_kill_one_ray_task, args=(killed,))
    killer.start()
    records = sweep.run_sweep(jobs, workers=1, out=tmp_path)
    killer.join()
    assert killed, "no Ray task process was found"
    finished, failed = sweep.split_failures(records)
    assert len(failed) == 1 and len(finished) == 1
    assert failed[0]["key"] == jobs[0][0] and "WorkerCrashedError" in failed[0]["error"]
    assert finished[0]["key"] == jobs[1][0] and "position_error_m" in finished[0]
    assert [p.name for p in (tmp_path / "cases").iterdir()] == [f"{jobs[1][0]}.json"]  # a rerun retries the other
    summary = targets_report.report(records, [])
    assert summary["failures"] == [(failed[0]["key"], failed[0]["error"])]
    assert summary["models"]["vscm"]["goals"] == 2 and summary["models"]["vscm"]["failed_solves"] == 1


def test_a_rerun_with_the_same_out_skips_the_finished_cases_and_retries_the_failed(tmp_path):
    calls = []

    def job(value: int) -> dict:
        calls.append(value)
        if value == 2:
            raise RuntimeError("no plan")
        return {"value": value}

    jobs = [(f"case{i}", job, (i,)) for i in range(3)]
    first = sweep.run_sweep(jobs, workers=0, out=tmp_path)
    assert calls == [0, 1, 2] and first[2]["failed"] and "no plan" in first[2]["error"]
    second = sweep.run_sweep(jobs, workers=0, out=tmp_path)
    assert calls == [0, 1, 2, 2] and second == first


def test_the_any_distribution_draws_goals_all_over_the_region_each_labelled_with_the_face_it_needs():
    settings = load_settings()
    where = targets.region(settings)
    goals, refused = targets.draw_goals(60, 0, settings, "any")
    assert refused and all("beyond the" in reason for reason in refused)  # only the region's edge is redrawn
    x0, y0 = where["object_start_m"]
    for goal in goals:
        x, y = goal.target_position_m
        assert where["table_low_m"][0] <= x <= where["table_high_m"][0]
        assert where["table_low_m"][1] <= y <= where["table_high_m"][1]
        assert np.hypot(x, y) <= where["push_reach_m"]
        assert goal.direction_rad == pytest.approx(np.arctan2(y - y0, x - x0))
        assert goal.face == targets.face_needed(goal.direction_rad, (x0, y0), 0.0)
    assert {goal.face for goal in goals} == set(targets.FACES)
    yaws = [goal.target_yaw_rad for goal in goals]
    assert min(yaws) < -2.5 and max(yaws) > 2.5
    assert {goal.face for goal in targets.draw_goals(60, 0, settings)[0]} == {"near"}  # forward: within 35 degrees
    beside = targets.draw_goals(60, 0, settings, "beside")[0]
    assert {goal.face for goal in beside} == {"side"}  # 50-130 degrees either side of +x: a side face's
    assert {np.sign(goal.direction_rad) for goal in beside} == {-1.0, 1.0}
    assert all(0.03 <= goal.push_m <= 0.25 and abs(goal.target_yaw_rad) <= 0.3 for goal in beside)
    turns = targets.draw_goals(60, 0, settings, "turn")[0]  # at the cube's place, turned beyond the tolerance
    assert all(goal.push_m <= 0.015 and 0.16 <= abs(goal.target_yaw_rad) <= 0.30 for goal in turns)
    assert {np.sign(goal.target_yaw_rad) for goal in turns} == {-1.0, 1.0} and len({g.face for g in turns}) == 3
    with pytest.raises(ValueError, match="unknown goal distribution 'everywhere'"):
        targets.draw_goals(1, 0, settings, "everywhere")


def test_a_refused_goal_is_reported_with_its_reason_and_time_apart_from_the_plans():
    settings = load_settings().with_overrides({"solver.max_iter": 4})
    goals, _ = targets.draw_goals(30, 0, settings, "any")
    pull = next(goal for goal in goals if goal.face == "far")
    refusal = targets.solve_goal(pull, "vscm", settings)
    assert "behind the object's pushed face" in refusal["refused"] and not refusal["success"]
    assert refusal["refusal_time_s"] > 0.0 and refusal["face"] == "far"
    solved = targets.solve_goal(targets.draw_goals(1, 0, settings)[0][0], "vscm", settings)
    assert "refused" not in solved and solved["face"] == "near"
    summary = targets_report.report([refusal, solved], [], targets.region(settings))
    vscm = summary["models"]["vscm"]
    assert (vscm["goals"], vscm["refusals"]) == (2, 1) and vscm["refusal_time_s_max"] == refusal["refusal_time_s"]
    assert vscm["success_rate"] == solved["success"] / 2
    faces = summary["by_face"]["vscm"]
    assert (faces["far"]["goals"], faces["far"]["refusals"], faces["far"]["successes"]) == (1, 1, 0)
    assert faces["far"]["solve_time_s"]["median"] is None and faces["near"]["goals"] == 1
    text = targets_report.markdown(summary)
    assert "| VSCM | far | 0/1 | 1 (" in text and "1 goal(s) refused" in text


def test_goals_aimed_at_an_equivalent_yaw_are_counted_with_their_successes():
    """A goal drawn a quarter turn round is planned as the same goal (its yaw taken back by the quarter turn), and
    the report counts it apart: a marked cube would have none of its successes."""
    settings = load_settings().with_overrides({"solver.max_iter": 4})
    goal = targets.draw_goals(1, 0, settings)[0][0]
    records = [targets.solve_goal(g, "vscm", settings)
               for g in (goal, dataclasses.replace(goal, target_yaw_rad=goal.target_yaw_rad + math.pi / 2))]
    assert records[1]["target_yaw_rad"] == pytest.approx(records[0]["target_yaw_rad"])
    assert records[1]["requested_yaw_rad"] == pytest.approx(records[0]["target_yaw_rad"] + math.pi / 2)
    summary = targets_report.report(records, [])
    assert summary["models"]["vscm"]["equivalent_yaw_goals_successes"] == [1, int(records[1]["success"])]
    assert "VSCM: 1 posed goal(s) aimed at a yaw a quarter turn or more from the one drawn" in \
        targets_report.markdown(summary)


def test_the_face_a_goal_needs_is_judged_from_the_face_towards_the_arm_however_the_cube_is_turned():
    for yaw in (0.0, math.pi / 2, math.pi, -2.0):
        assert targets.face_needed(0.0, (0.99, 0.0), yaw) == "near"     # straight away from the arm
        assert targets.face_needed(math.pi / 2, (0.99, 0.0), yaw) == "side"
        assert targets.face_needed(math.pi, (0.99, 0.0), yaw) == "far"  # back towards it
    assert targets.face_needed(math.pi / 2, (0.0, 0.99), 0.0) == "near"  # a cube straight beside the arm base
