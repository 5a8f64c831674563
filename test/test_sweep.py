"""Sweeps on Ray: the same records as in process, a killed worker is one case's failure, resumption.
Real Ray (embedded, local), real solves."""
from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np

from cito_ros.planner.results import PHASE_METRICS
from cito_ros.settings import load_settings
from cito_ros.studies import sweep, targets

TIMINGS = ("solve_time_s", *PHASE_METRICS)


def small_sweep(settings, goals: int = 4, models=("scm", "vscm")):
    """A few seeded goals with each model, each solve capped at a few iterations per stage."""
    drawn, _ = targets.draw_goals(goals, seed=3, settings=settings)
    return targets.jobs(drawn, models, settings)


def without_timings(record: dict) -> dict:
    return {k: v for k, v in record.items() if k not in TIMINGS}


def test_a_sweep_gives_the_same_records_on_ray_and_in_process():
    settings = load_settings().with_overrides({"solver.max_iter": 4})
    in_process = sweep.run_sweep(small_sweep(sweep.settings_for(settings, 0)), workers=0)
    on_ray = sweep.run_sweep(small_sweep(sweep.settings_for(settings, 2)), workers=2)
    assert [r["key"] for r in on_ray] == [r["key"] for r in in_process]
    assert not any(r.get("failed") for r in on_ray + in_process)
    # the threaded in-process solve and the single-threaded Ray task plan the same bits
    assert [without_timings(r) for r in on_ray] == [without_timings(r) for r in in_process]
    report = targets.report(on_ray, [], targets.push_reach_m(settings))
    assert set(report["models"]) == {"scm", "vscm"} and report["models"]["scm"]["goals"] == 4
    for model, split in report["by_reach"]["models"].items():
        assert split["inside"]["goals"] + split["near"]["goals"] == 4
        assert split["inside"]["successes"] + split["near"]["successes"] == \
            sum(r["success"] for r in on_ray if r["contact_model"] == model)
    assert "against the push reach of" in targets.markdown(report)
    # every plan also tracked with its reference off; the report counts the successes' executions
    assert all(len(r["offset_tracked_position_errors_m"]) == targets.OFFSETS for r in on_ray)
    for model, summary in report["models"].items():
        successes = [r for r in on_ray if r["contact_model"] == model and r["success"]]
        assert summary["offset_executions_within_2cm"] == [
            sum(e < 0.02 for r in successes for e in r["offset_tracked_position_errors_m"]),
            targets.OFFSETS * len(successes)]


def test_the_report_sets_apart_the_goals_within_the_band_at_the_push_reach():
    settings = load_settings()
    reach = targets.push_reach_m(settings)
    goals, _ = targets.draw_goals(50, seed=0, settings=settings)
    distance = {g.index: float(np.hypot(*g.target_position_m)) for g in goals}
    assert max(distance.values()) <= reach  # the draws the planner refuses are drawn again

    def record(goal, perturbation, success, error_m):
        return {"goal": goal.index, "contact_model": "scm", "perturbation": perturbation, "success": success,
                "position_error_m": error_m, "solve_time_s": 1.0, "target_position_m": [*goal.target_position_m, 0.1]}

    # a near goal whose perturbed twin flips, an inside goal whose twin moves 5 mm
    near = next(g for g in goals if distance[g.index] > reach - targets.NEAR_REACH_BAND_M)
    inside = next(g for g in goals if distance[g.index] <= reach - targets.NEAR_REACH_BAND_M)
    records = [record(near, "none", True, 0.015), record(near, "target x +1e-9 m", False, 0.03),
               record(inside, "none", True, 0.002), record(inside, "target x +1e-9 m", True, 0.007)]
    split = targets.by_reach(records, reach)["models"]["scm"]
    assert (split["near"]["goals"], split["near"]["successes"], split["near"]["pairs_stable"]) == (1, 1, 0)
    assert (split["inside"]["goals"], split["inside"]["pairs_stable"], split["inside"]["perturbed_pairs"]) == (1, 1, 1)


def _kill_one_ray_task(killed: list[int], deadline_s: float = 120.0) -> None:
    """SIGKILL the first process Ray runs a task in (its title is ray::_call)."""
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline and not killed:
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit():
                continue
            try:
                title = (entry / "cmdline").read_bytes().split(b"\0")[0]
            except OSError:
                continue
            if title.startswith(b"ray::_call"):
                time.sleep(1.0)  # well into its solve
                os.kill(int(entry.name), signal.SIGKILL)
                killed.append(int(entry.name))
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
    summary = targets.report(records, [])
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
