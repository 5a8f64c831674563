"""Requests the planner refuses, with the reason, and the reach it checks goals against. Real MuJoCo."""
import math

import mujoco
import numpy as np
import pytest

from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.plan import plan_push


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
        task.turn_per_push_rad_per_m per metre and at most task.max_push_turn_rad: a turn in place, or 1.2 rad
        over 8 cm, is refused before anything is solved (each ran to the time limit and missed); 0.6 rad over 8 cm
        and a turn within the tolerance in place are posed; the same turns the other way round or a whole turn
        apart alike. A long push is refused a turn beyond the cap."""
        k, most = settings.task.turn_per_push_rad_per_m, settings.task.max_push_turn_rad
        refused = (([0.99, 0.0], 0.6), ([0.99, 0.0], -0.6), ([1.07, 0.0], 1.2), ([1.07, 0.0], -1.2 + 2 * math.pi),
                   ([1.24, 0.0], 0.2 + most))
        for target, yaw in refused:
            turn = abs(math.remainder(yaw, 2 * math.pi))
            with pytest.raises(ValueError, match=rf"target turns the object by {turn:.2f} rad over a "
                                                 rf"{100 * (target[0] - 0.99):.1f} cm push: .* at most "
                                                 rf"{0.15 + min(k * (target[0] - 0.99), most):.2f} rad"):
                build_problem(settings, PushRequest("vscm", 7, None, target, yaw))
        posed = (([0.99, 0.0], 0.1), ([1.07, 0.0], 0.6), ([1.07, 0.0], -0.6), ([1.07, 0.0], 2 * math.pi + 0.6))
        for target, yaw in posed:
            assert build_problem(settings, PushRequest("vscm", 7, None, target, yaw)).task is not None

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
