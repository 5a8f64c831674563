"""Where a push that holds its height can leave the cube (cito_ros.planner.push_limits): the bound behind the
near-reach lottery (docs/planner.md: Reach zones)."""
import json

import numpy as np
import pytest

from cito_ros.model import reach_cache
from cito_ros.planner import push_limits
from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.settings import load_settings


def test_the_fastest_push_is_the_linear_programs_optimum():
    # v_y = q2 - q3 = 0 and v_z = q1 + q3 = 0 leave qdot = t (-1, 1, 1), v_x = t: the second joint's limit binds
    jacp = np.array([[1.0, 2.0, 0.0], [0.0, 1.0, -1.0], [1.0, 0.0, 1.0]])
    limits = np.array([1.0, 0.5, 2.0])
    speed = push_limits.fastest_push_m_s(jacp, np.zeros((3, 3)), np.array([1.0, 0.0, 0.0]), limits, False)
    assert speed == pytest.approx(0.5)
    # pushing along -x flips the sign of t: the same bound
    speed = push_limits.fastest_push_m_s(jacp, np.zeros((3, 3)), np.array([-1.0, 0.0, 0.0]), limits, False)
    assert speed == pytest.approx(0.5)


def test_a_steady_face_push_ends_centimetres_short_of_the_push_reach_and_a_release_adds_nothing_there():
    settings = load_settings()
    posed = build_problem(settings, PushRequest("vscm", settings.beta))
    limits = push_limits.push_limits(posed.scene, posed.initial_state, (0.10,), start_m=0.96, step_m=0.04)
    reach = posed.scene.push_reach_m()
    face, rim = push_limits.farthest(limits, "face"), push_limits.farthest(limits, "rim")
    assert all(row.rest_distance_m <= reach for row in limits)
    assert face.rest_distance_m < reach - 0.04 < rim.rest_distance_m
    # at full stretch the arm cannot move the plate along the push: a release there slides under a millimetre
    assert face.slide_m < 1e-3 and rim.slide_m < 1e-3
    # further in it can: the slide grows with the speed
    slides = [row.slide_m for row in limits if row.contact == "rim"]
    assert max(slides) > 10 * rim.slide_m


def test_a_scan_without_heights_or_step_is_refused():
    settings = load_settings()
    posed = build_problem(settings, PushRequest("vscm", settings.beta))
    with pytest.raises(ValueError, match="positive step"):
        push_limits.push_limits(posed.scene, posed.initial_state, (0.10,), step_m=0.0)


def test_the_steady_reach_is_the_scans_bound_and_follows_the_object(tmp_path):
    """steady_reach_m finds the face's farthest rest directly: within 2 mm of a scan's farthest at 1 mm steps near
    the boundary (the scan accepts the plate's normal up to 1e-2 off, the direct search holds it closer), short of
    the push reach; a smaller cube gives its own bound."""
    settings = load_settings()
    posed = build_problem(settings, PushRequest("vscm", settings.beta))
    steady = push_limits.steady_reach_m(posed.scene, posed.initial_state)
    heights = push_limits.face_heights_m(posed.scene)
    assert heights == pytest.approx((0.06, 0.10, 0.14))
    scan = push_limits.push_limits(posed.scene, posed.initial_state, heights[-1:], start_m=1.09, step_m=0.001)
    farthest = push_limits.farthest(scan, "face").rest_distance_m
    assert steady == pytest.approx(farthest, abs=2e-3) and steady < posed.scene.push_reach_m() - 0.04
    path = tmp_path / "small_cube.yaml"
    path.write_text("object: {half_size_m: 0.05}\n")
    small = build_problem(settings.with_overrides({"scene": str(path)}),
                          PushRequest("vscm", settings.beta, target_position_m=[1.1, 0.0]))
    assert push_limits.face_heights_m(small.scene) == pytest.approx((0.06, 0.075, 0.09))
    assert abs(push_limits.steady_reach_m(small.scene, small.initial_state) - steady) > 0.01


def test_a_reach_is_computed_once_per_machine_and_read_back_from_the_users_cache(tmp_path, monkeypatch):
    """A reach's first computation writes it to $XDG_CACHE_HOME/cito_ros/reach.json; a process that has not
    computed it (here: this one's copy cleared) reads it back without a search: the push reach, which every
    request's checks need (a one-shot cito-plan's refusal spent 0.1 s searching it), and the pull reach. A damaged
    file is computed past and written anew; a heavier cube is a scene of its own, with entries of its own."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(reach_cache, "_REACHES", {})
    searches = []
    search = push_limits.minimize.least_squares
    monkeypatch.setattr(push_limits.minimize, "least_squares", lambda *a, **k: searches.append(1) or search(*a, **k))
    settings = load_settings()
    scene = build_problem(settings, PushRequest("vscm", settings.beta)).scene  # its checks search the push reach
    path = tmp_path / "cito_ros" / "reach.json"
    push = scene.push_reach_m()
    assert searches and 1.0 < push < 1.5 and list(json.loads(path.read_text()).values()) == [push]

    def fresh(reach) -> float:
        searches.clear()
        monkeypatch.setattr(reach_cache, "_REACHES", {})
        return reach()

    computed = fresh(lambda: push_limits.pull_reach_m(scene))
    assert searches and 0.5 < computed < 1.0 and list(json.loads(path.read_text()).values()) == [push, computed]
    assert fresh(lambda: push_limits.pull_reach_m(scene)) == computed and not searches
    assert fresh(scene.push_reach_m) == push and not searches
    path.write_text("{")
    assert fresh(lambda: push_limits.pull_reach_m(scene)) == computed and searches
    assert list(json.loads(path.read_text()).values()) == [computed]
    heavy = build_problem(settings, PushRequest("vscm", settings.beta, object_scales=(1.0, 2.0))).scene
    searches.clear()
    push_limits.pull_reach_m(heavy)
    assert searches and len(json.loads(path.read_text())) == 3  # the heavy cube's push reach and pull reach
