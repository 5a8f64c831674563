"""Requests the planner refuses, with the reason, and the reach it checks goals against. Real MuJoCo."""
import math

import mujoco
import numpy as np
import pytest

from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.plan import plan_push
from cito_ros.planner.task import aim_note, equivalent_yaw_note


class TestBadRequests:
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


class TestReach:
    def test_off_the_table(self, settings):
        with pytest.raises(ValueError, match=r"target \(1.900, 0.000\) m is off the table"):
            plan_push("vscm", 7, settings=settings, target_position_m=[1.9, 0.0])

    def test_a_target_z_within_the_tolerance_is_the_resting_height(self, settings):
        """z = table top + half edge (the demo's, 0.1 mm above the settled cube) poses the same problem
        as (x, y) alone."""
        spelled = [build_problem(settings, PushRequest("vscm", 7, None, target, 0.0, None, None)).problem.task
                   for target in ([1.09, 0.0], [1.09, 0.0, 0.1])]
        assert np.array_equal(spelled[0].target_position_m, spelled[1].target_position_m)

    def test_lifted(self, settings):
        with pytest.raises(ValueError, match="is not the object's resting height"):
            plan_push("vscm", 7, settings=settings, target_position_m=[1.2, 0.0, 0.5])

    def test_the_reach_comes_from_the_model(self, scenes):
        """The plate centre's farthest point at the top of the cube's faces, found by optimization, plus
        the plate's radius and the cube's half edge: checked against a dense sample of the arm's
        configurations, none of which reaches farther."""
        scene = scenes["vscm"]
        reach = scene.push_reach_m()
        data = mujoco.MjData(scene.model)
        rng = np.random.default_rng(0)
        low, high = scene.joint_range.T
        farthest = 0.0
        for q in rng.uniform(low, high, (20000, 7)):
            data.qpos[scene.arm_qpos_adr] = q
            mujoco.mj_kinematics(scene.model, data)
            plate = data.site_xpos[scene.robot_site_id]
            if plate[2] <= 0.175:
                farthest = max(farthest, float(np.hypot(plate[0], plate[1])))
        assert farthest + 0.035 + 0.075 <= reach + 1e-6
        assert reach > 1.24  # the paper's push (0.25 m along +x from 0.99 m) is within reach

    def test_beyond_reach_is_refused_with_the_numbers(self, settings, scenes):
        reach = scenes["vscm"].push_reach_m()
        with pytest.raises(ValueError, match=rf"beyond the {reach:.3f} m the arm can push the object's centre to"):
            plan_push("vscm", 7, settings=settings, target_position_m=[reach + 0.01, 0.0])

    def test_a_goal_behind_the_pushed_face_is_refused_with_how_far(self, settings):
        """Pushing on the cube's near face moves it away from that face: a goal 10 cm back towards the arm is
        refused before anything is solved."""
        with pytest.raises(ValueError, match=r"target is 10.0 cm behind the object's pushed face"):
            plan_push("vscm", 7, settings=settings, target_position_m=[0.89, 0.0])

    def test_a_turn_one_push_cannot_make_is_refused_with_how_much(self, settings):
        """A push turns the cube as it moves it, by at most the orientation tolerance plus
        task.turn_per_push_rad_per_m per metre, over the push to the goal or to the aim past it (at most
        task.aim_past_max_m): a turn of 0.6 rad in place, or over 2 cm, is refused before anything is solved (each
        ran to the time limit and missed); 0.6 rad over 8 cm and a turn within the tolerance in place are posed; the
        same turns the other way round or a whole turn apart alike."""
        k, past_m = settings.task.turn_per_push_rad_per_m, settings.task.aim_past_max_m
        refused = (([0.99, 0.0], 0.6), ([0.99, 0.0], -0.6), ([1.01, 0.0], 0.6), ([1.01, 0.0], -0.6 + 2 * math.pi))
        for target, yaw in refused:
            push_m = target[0] - 0.99 + past_m
            with pytest.raises(ValueError, match=rf"target turns the object by 0.60 rad over a {100 * push_m:.1f} cm "
                                                 rf"push \(aimed {100 * past_m:.1f} cm past the goal\): .* at most "
                                                 rf"{0.15 + k * push_m:.2f} rad"):
                build_problem(settings, PushRequest("vscm", 7, None, target, yaw))
        posed = (([0.99, 0.0], 0.1), ([1.07, 0.0], 0.6), ([1.07, 0.0], -0.6), ([1.07, 0.0], 2 * math.pi + 0.6))
        for target, yaw in posed:
            assert build_problem(settings, PushRequest("vscm", 7, None, target, yaw)).task is not None

    def test_a_turn_at_the_cubes_place_is_aimed_past_the_goal_and_judged_at_the_goal(self, settings):
        """A push turns the cube only as it moves it: a goal on the cube's place turned 0.2 rad (beyond the 0.15 rad
        tolerance; refused as a turn in place before) is aimed (0.2 - 0.15) / task.aim_turn_rad_per_m past the goal
        along the near face's push, the plan judged at the goal: executed, it ends within the tolerances of the goal,
        and the answer says so. A turn more than one push makes even aimed task.aim_past_max_m past is refused, and a
        goal far enough away for its turn is aimed at itself."""
        limits = settings.task
        task = build_problem(settings, PushRequest("vscm", 7, None, [0.99, 0.0], 0.2)).task
        past_m = (0.2 - limits.success_orientation_error_rad) / limits.aim_turn_rad_per_m
        assert task.target_position_m[:2].tolist() == [0.99, 0.0]
        assert task.aim_m[:2] == pytest.approx([0.99 + past_m, 0.0])
        assert build_problem(settings, PushRequest("vscm", 7, None, [1.07, 0.0], 0.6)).task.aim_position_m is None
        with pytest.raises(ValueError, match=r"turns the object by 0.35 rad over a 1.2 cm push \(aimed 1.2 cm past the "
                                             r"goal\): .* at most 0.30 rad there .* aimed at most 1.2 cm past the goal"):
            build_problem(settings, PushRequest("vscm", 7, None, [0.99, 0.0], 0.35))
        result = plan_push("vscm", 7, target_position_m=[0.99, 0.0], target_yaw_rad=0.2,
                           settings=settings.with_overrides({"solver.time_limit_s": 30.0}))
        end = result.executed_motion.object_position_m[-1, :2]
        assert result.metrics.success
        assert result.metrics.position_error_m == pytest.approx(float(np.linalg.norm(end - [0.99, 0.0])), abs=1e-4)
        assert np.linalg.norm(end - [0.99, 0.0]) > 1e-3  # it moved: pushed, not held
        assert "aimed 0.6 cm past the goal" in aim_note(result.target_position_m, result.aim_position_m)

    def test_a_goal_yaw_counts_modulo_a_quarter_turn_and_the_answer_says_which_it_aimed_at(self, settings):
        """The cube turned by a quarter turn is the same cube: a turn of 1.2 rad over 8 cm (refused when the goal's
        frame counted, for 0.15 + 12.5 x 0.08 = 1.15 rad) is the turn of 1.2 - pi/2 = -0.371 rad, posed and aimed at
        that yaw; from a cube at 0.6 rad the goal yaw -0.8 is aimed at -0.8 + pi/2. The note names the quarter
        turns; a goal already nearest, or as near as its equivalent, says nothing."""
        task = build_problem(settings, PushRequest("vscm", 7, None, [1.07, 0.0], 1.2)).task
        assert task.target_yaw_rad == pytest.approx(1.2 - math.pi / 2)
        assert equivalent_yaw_note(1.2, task.target_yaw_rad) == (
            "the goal yaw 1.200 rad was taken as -0.371 rad, 1 quarter turn(s) clockwise from it: the same pose of "
            "the cube, nearer its start")
        turned = build_problem(settings, PushRequest("vscm", 7, None, [1.07, 0.0], -0.8, None, ((0.99, 0.0), 0.6)))
        assert turned.task.target_yaw_rad == pytest.approx(-0.8 + math.pi / 2)
        assert "counter-clockwise" in equivalent_yaw_note(-0.8, turned.task.target_yaw_rad)
        assert equivalent_yaw_note(0.3, build_problem(settings, PushRequest("vscm", 7, None, [1.07, 0.0], 0.3)
                                                      ).task.target_yaw_rad) == ""
        # 45 degrees as written to four digits (the hard case yaw_45deg), 4e-6 rad past an eighth of a turn, is as
        # near either way round: taken as asked, not as -45 degrees
        for yaw in (0.7854, -0.7854):
            assert build_problem(settings, PushRequest("vscm", 6, None, [1.19, 0.0], yaw)).task.target_yaw_rad == yaw

    def test_the_pushed_face_is_the_face_towards_the_arm_wherever_the_cube_is_turned(self, settings):
        """Without side faces: a goal straight beside the cube is a side push for a cube square to the arm, and a
        goal 5.6 cm behind the pushed face of one turned by 0.6 rad; a goal within the position tolerance behind it
        (a turn in place) is posed. A cube turned by half a turn is the same cube: pushed away from the arm, not
        refused."""
        settings = settings.with_overrides({"stages.scripted.side_faces.enabled": False})
        sideways = PushRequest("vscm", 7, None, [0.99, -0.10], 0.0, None, ((0.99, 0.0), 0.0))
        assert build_problem(settings, sideways).task is not None
        turned = PushRequest("vscm", 7, None, [0.99, -0.10], 0.0, None, ((0.99, 0.0), 0.6))
        with pytest.raises(ValueError, match=r"target is 5.6 cm behind the object's pushed face"):
            build_problem(settings, turned)
        in_place = PushRequest("vscm", 7, None, [0.975, 0.0], 0.25, None, ((0.99, 0.0), 0.0))
        assert build_problem(settings, in_place).task is not None
        for target, refused in (([1.09, 0.0], False), ([0.89, 0.0], True)):
            half_turned = PushRequest("vscm", 7, None, target, math.pi, None, ((0.99, 0.0), math.pi))
            if refused:
                with pytest.raises(ValueError, match=r"target is 10.0 cm behind the object's pushed face"):
                    build_problem(settings, half_turned)
            else:
                assert build_problem(settings, half_turned).task is not None
