"""The closed-loop benchmark's report (cito_ros.studies.closed_loop): what it counts and how it says it."""
import math

import numpy as np
import pytest

from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.studies import closed_loop
from cito_ros.studies.targets import Goal


def test_the_closed_loop_report_counts_the_cubes_that_tipped_over_the_pushes_cut_short_and_the_arms_too_fast():
    def record(mode: str, tipped: bool, speed: float = 0.9) -> dict:
        return {"world": "w", "mode": mode, "steady_reach_margin_m": 0.05, "success": False, "success_tight": False,
                "position_error_m": 0.05, "max_joint_speed_ratio": speed, "pushes": 1, "replans": 0,
                "replan_rate_hz": math.nan, "replan_compute_s": math.nan, "tipped": tipped, "pushes_cut": 2 * tipped}

    summary = closed_loop.report([record("closed_loop", True), record("closed_loop", False, 1.02),
                                  record("closed_loop", False, 1.0), record("open_loop", False)])
    assert summary["zones"]["steady"]["w"]["closed_loop"]["over_speed_limit"] == 1
    assert "Episodes with a joint past its speed limit (the world's arm, above 1.0 of it at some step): 1 in w, " \
        "closed loop, inside the steady reach." in closed_loop.markdown(summary)
    assert "the first push planned sturdy" not in closed_loop.markdown(summary)  # records without the executor's cause
    assert summary["zones"]["steady"]["w"]["closed_loop"]["tipped"] == 1
    assert "Cubes tipped over (the true cube past its edge, never a success): 1 in w, closed loop, inside the " \
        "steady reach." in closed_loop.markdown(summary)
    assert "Pushes cut short with the cube off their path (executor.off_path_m): 2, in 1 closed-loop episodes." in \
        closed_loop.markdown(summary)
    assert "clock fixed" not in closed_loop.markdown(summary)  # measured compute times, the default


def test_the_closed_loop_report_says_when_the_compute_times_were_fixed_not_measured():
    record = {"world": "w", "mode": "closed_loop", "steady_reach_margin_m": 0.05, "success": True,
              "success_tight": True, "position_error_m": 0.01, "max_joint_speed_ratio": 0.9, "pushes": 1,
              "replans": 10, "replan_rate_hz": 10.0, "replan_compute_s": 0.1, "clock_s": {"plan": 2.0, "replan": 0.1}}
    summary = closed_loop.report([record, record])
    assert summary["clock_s"] == {"plan": 2.0, "replan": 0.1}
    assert "Compute on the world's clock fixed, not measured (--clock-s): 2 s a plan, 0.1 s a replan" in \
        closed_loop.markdown(summary)


def test_the_closed_loop_report_splits_the_successes_by_the_first_push_s_sturdiness_and_names_the_misses_causes():
    def record(success: bool, sturdy: bool | None, cause: str, margin_m: float = 0.05) -> dict:
        return {"world": "w", "mode": "closed_loop", "steady_reach_margin_m": margin_m, "success": success,
                "success_tight": success, "position_error_m": 0.01, "max_joint_speed_ratio": 0.9, "pushes": 1,
                "replans": 0, "replan_rate_hz": math.nan, "replan_compute_s": math.nan, "tipped": False,
                "pushes_cut": 0, "first_push_sturdy": sturdy, "cause": cause}

    summary = closed_loop.report([
        record(True, True, "succeeded"), record(False, True, "pushes_spent"), record(True, False, "succeeded"),
        record(False, False, "no_closer_push"), record(False, False, "no_closer_push"),
        record(False, None, "invalid_request"), record(False, False, "tipped", -0.01)])
    steady = summary["explained"]["steady"]
    assert steady["sturdy"] == {"sturdy": {"episodes": 2, "success": 1}, "not_sturdy": {"episodes": 3, "success": 1}}
    assert steady["miss_causes"] == {"no_closer_push": 2, "pushes_spent": 1, "invalid_request": 1}
    assert summary["explained"]["strike"]["miss_causes"] == {"tipped": 1}
    assert "Closed loop inside the steady reach: the first push planned sturdy (PlanResult.sturdy) in 2 episodes, 1 " \
        "of them successes; not sturdy in 3, 1 successes. The misses by the executor's cause: no closer push 2, " \
        "pushes spent 1, invalid request 1." in closed_loop.markdown(summary)


def test_the_closed_loop_report_counts_successes_by_the_pushes_made_and_says_how_long_the_executions_took():
    def record(success: bool, pushes: int, duration_s: float) -> dict:
        return {"world": "w", "mode": "closed_loop", "steady_reach_margin_m": 0.05, "success": success,
                "success_tight": success, "position_error_m": 0.01, "max_joint_speed_ratio": 0.9, "pushes": pushes,
                "replans": 0, "replan_rate_hz": math.nan, "replan_compute_s": math.nan, "tipped": False,
                "pushes_cut": 0, "first_push_sturdy": True, "cause": "succeeded" if success else "no_closer_push",
                "duration_s": duration_s}

    summary = closed_loop.report([record(True, 1, 4.0), record(True, 2, 12.0), record(False, 2, 20.0),
                                  record(False, 3, 50.0), record(True, 1, 3.0)])
    steady = summary["explained"]["steady"]
    assert steady["by_pushes"] == {1: {"episodes": 2, "success": 2}, 2: {"episodes": 2, "success": 1},
                                   3: {"episodes": 1, "success": 0}}
    assert steady["duration_s"]["median"] == 12.0 and steady["duration_s"]["max"] == 50.0
    assert "Successes by the pushes an episode made: 1: 2 of 2, 2: 1 of 2, 3: 0 of 1. The executions took a median " \
        "12.0 s (p90 38.0 s, the longest 50.0 s)." in closed_loop.markdown(summary)


def test_a_missed_cube_is_placed_short_of_past_beside_or_turned_at_its_goal_along_the_push(settings, tmp_path):
    """The push runs from (1.0, 0.0) towards (1.1, 0.1): a cube resting 3 cm before the goal along it is short, 3 cm
    beyond it past, 3 cm across it beside, 1 cm off (within the 2 cm tolerance) turned; the report counts the misses'
    places and says them, and draws them (a record without the poses left out)."""
    along, across = (0.5 ** 0.5, 0.5 ** 0.5), (-(0.5 ** 0.5), 0.5 ** 0.5)

    def record(offset, sign: float, error_m: float, success: bool = False, tipped: bool = False) -> dict:
        final = [1.1 + sign * error_m * offset[0], 0.1 + sign * error_m * offset[1], 0.0]
        return {"world": "w", "mode": "closed_loop", "steady_reach_margin_m": 0.05, "success": success,
                "success_tight": success, "position_error_m": error_m, "max_joint_speed_ratio": 0.9, "pushes": 1,
                "replans": 0, "replan_rate_hz": math.nan, "replan_compute_s": math.nan, "tipped": tipped,
                "pushes_cut": 0, "first_push_sturdy": True, "cause": "no_closer_push",
                "start_pose": [1.0, 0.0, 0.1], "target_pose": [1.1, 0.1, 0.3], "final_pose": final}

    records = [record(along, -1, 0.03), record(along, 1, 0.03), record(across, 1, 0.03), record(across, -1, 0.03),
               record(along, 1, 0.01), record(along, 1, 0.005, success=True), record(along, 1, 0.2, tipped=True)]
    assert closed_loop.push_frame_offset_cm(records[0]) == pytest.approx((-3.0, 0.0))  # short, on the line
    assert closed_loop.push_frame_offset_cm(records[2]) == pytest.approx((0.0, 3.0))  # to the push's left
    places = [closed_loop.place(r, settings.task) for r in records]
    assert places == ["short", "past", "beside", "beside", "turned", "goal", "tipped"]
    summary = closed_loop.report([{**r, "place": p} for r, p in zip(records, places, strict=True)])
    assert summary["explained"]["steady"]["miss_places"] == {"beside": 2, "short": 1, "past": 1, "turned": 1,
                                                             "tipped": 1}
    assert "Where their cubes came to rest against the goal, along the push from where the cube started: beside it " \
        "2, short of it 1, past it (a pull back needed) 1, at the place but turned 1, tipped over 1." in \
        closed_loop.markdown(summary)
    path = closed_loop.plot([{**r, "place": p} for r, p in zip(records, places, strict=True)] +
                            [{**records[0], "final_pose": []}], tmp_path / "closed_loop.png",
                            settings.task.success_position_error_m)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_closed_loop_report_says_how_many_replans_took_the_running_plans_place():
    def record(replans: int, taken: int | None) -> dict:
        return {"world": "w", "mode": "closed_loop", "steady_reach_margin_m": 0.05, "success": True,
                "success_tight": True, "position_error_m": 0.01, "max_joint_speed_ratio": 0.9, "pushes": 1,
                "replans": replans, "replan_rate_hz": 12.0, "replan_compute_s": 0.08, "tipped": False,
                **({} if taken is None else {"replans_taken": taken})}

    summary = closed_loop.report([record(10, 4), record(6, 1)])
    assert summary["replans_taken"] == {"taken": 5, "replans": 16}
    assert "Taken: 5 of 16 replans (the others left the running plan in place)." in closed_loop.markdown(summary)
    through_the_nodes = closed_loop.report([record(10, None)])  # the action's result does not count them
    assert through_the_nodes["replans_taken"] is None and "Taken:" not in closed_loop.markdown(through_the_nodes)


def test_the_closed_loop_report_counts_successes_and_refusals_by_the_face_a_push_towards_the_goal_needs(settings):
    def record(face: str, success: bool, cause: str, pushes: int) -> dict:
        return {"world": "w", "mode": "closed_loop", "face": face, "steady_reach_margin_m": 0.05, "success": success,
                "success_tight": success, "position_error_m": 0.01, "max_joint_speed_ratio": 0.9, "pushes": pushes,
                "replans": 0, "replan_rate_hz": math.nan, "replan_compute_s": math.nan, "tipped": False,
                "pushes_cut": 0, "first_push_sturdy": pushes > 0 or None, "cause": cause}

    records = [record("near", True, "succeeded", 1), record("near", False, "time_limit", 2),
               record("side", False, "invalid_request", 0), record("side", False, "no_push_from_here", 1),
               record("far", False, "invalid_request", 0)]
    # the refused have no resting pose to place against the push: never pushed, they are counted as refused
    refused = [{**r, "position_error_m": math.nan} for r in records if r["pushes"] == 0]
    assert [closed_loop.place(r, settings.task) for r in refused] == ["refused", "refused"]
    summary = closed_loop.report(records)
    assert summary["faces"] == {"near": {"episodes": 2, "success": 1, "refused": 0},
                                "side": {"episodes": 2, "success": 0, "refused": 1},
                                "far": {"episodes": 1, "success": 0, "refused": 1}}
    assert "Closed loop by the face a push towards the goal needs (from where the cube starts): near 1 of 2 " \
        "episodes (0 refused before any push); side 0 of 2 episodes (1 refused before any push); far 0 of 1 " \
        "episodes (1 refused before any push)." in closed_loop.markdown(summary)


def test_a_goal_the_planner_refuses_is_still_placed_in_its_reach_zone(settings):
    # the any distribution draws goals behind the pushed face: refused by the planner, judged in their zone all the same
    behind = Goal(0, 5.0, (0.80, 0.0), 0.0, 0.19, math.pi, "far")
    with pytest.raises(ValueError, match="behind the object's pushed face"):
        build_problem(settings, PushRequest("vscm", 5.0, target_position_m=np.array(behind.target_position_m)))
    assert 0.3 < closed_loop.steady_margin_m(behind, settings) < 0.5  # 0.80 m out, the steady reach 1.19 m
