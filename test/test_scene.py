"""The push scene: start poses, initial distances, model contents, config errors."""
import dataclasses
import math

import mujoco
import numpy as np
import pytest

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene, pushed_face, start_configuration
from cito_ros.settings import SceneConfig, load_settings

PAPER_DISTANCES = {5: 0.30, 6: 0.17, 7: 0.11}


@pytest.mark.parametrize("beta", [5, 6, 7])
def test_initial_distance_matches_paper(scenes, beta):
    distance = scenes["vscm"].initial_distance(beta)
    assert abs(distance - PAPER_DISTANCES[beta]) < 0.015, distance


def test_start_configuration_formula():
    q0 = start_configuration(6)
    np.testing.assert_allclose(q0, [-math.pi / 12, -math.pi / 6, 0, math.pi / 2, -math.pi / 6, -math.pi / 3, 0])


@pytest.mark.parametrize("beta", [0, -3, float("nan"), float("inf")])
def test_bad_beta_is_rejected(beta):
    with pytest.raises(ValueError, match="beta"):
        start_configuration(beta)


def test_start_pose_outside_joint_limits_is_rejected(scenes):
    with pytest.raises(ValueError, match="j3 .* outside its range"):
        scenes["vscm"].data_at(start_configuration(1.0))


def test_only_pushing_pairs_collide(scenes):
    model = scenes["vscm"].model
    # no geom takes part in broad-phase collision; only the listed pairs are tested
    assert not np.any(model.geom_contype) and not np.any(model.geom_conaffinity)
    pairs = {frozenset((model.geom(int(a)).name, model.geom(int(b)).name))
             for a, b in zip(model.pair_geom1, model.pair_geom2)}
    assert {"object_geom", "table"} in pairs and {"plate", "object_geom"} in pairs
    # every pair is arm-object, object-table or arm-table(top)
    assert all("object_geom" in pair or "table_top" in pair for pair in pairs)
    assert len(pairs) == model.npair == 11


def test_simulator_settings_live_in_the_model(scenes):
    opt = scenes["vscm"].model.opt
    assert opt.timestep == 0.005 and opt.tolerance == 1e-12
    assert opt.solver == mujoco.mjtSolver.mjSOL_NEWTON and opt.integrator == mujoco.mjtIntegrator.mjINT_EULER


def test_scene_config_is_applied(tmp_path):
    path = tmp_path / "heavy.yaml"
    path.write_text("object: {half_size_m: 0.05, mass_kg: 2.0, position_m: [1.0, 0.1], friction: 1.2}\n")
    scene = Scene(contact_model("vscm", load_settings().contact_models), SceneConfig.load(path))
    data = scene.data_at(start_configuration(5))
    position, _ = scene.object_pose(data)
    np.testing.assert_allclose(position, [1.0, 0.1, 0.075])
    assert scene.model.body_mass[scene.object_body_id] == pytest.approx(2.0)
    np.testing.assert_allclose(data.site_xpos[scene.object_site_id], [0.95, 0.1, 0.075])
    object_pairs = [p for p in range(scene.model.npair) if scene.object_geom_id in
                    (scene.model.pair_geom1[p], scene.model.pair_geom2[p])]
    assert all(scene.model.pair_friction[p][0] == 1.2 for p in object_pairs)


def test_unknown_scene_is_rejected():
    with pytest.raises(ValueError, match="unknown scene 'nope'"):
        SceneConfig.load("nope")


def test_bad_scene_values_are_rejected():
    with pytest.raises(ValueError, match="mass_kg must be positive"):
        SceneConfig.from_mapping("x", {"object": {"mass_kg": -1}})
    with pytest.raises(ValueError, match="position_m must be"):
        SceneConfig.from_mapping("x", {"object": {"position_m": [1, 2, 3]}})


def test_a_scene_can_name_its_collision_pairs(tmp_path):
    path = tmp_path / "plate_only.yaml"
    path.write_text("object: {friction: 0.7}\npairs: [[plate, object_geom], [object_geom, table]]\n")
    scene = Scene(contact_model("vscm", load_settings().contact_models), SceneConfig.load(path))
    model = scene.model
    assert model.npair == 2
    assert {frozenset((model.geom(int(a)).name, model.geom(int(b)).name))
            for a, b in zip(model.pair_geom1, model.pair_geom2)} == {frozenset(("plate", "object_geom")),
                                                                     frozenset(("object_geom", "table"))}
    assert all(f == 0.7 for f in model.pair_friction[:, 0])


def test_bad_collision_pairs_are_rejected(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("pairs: [[plate, nothing]]\n")
    with pytest.raises(ValueError, match="no geom named 'nothing'"):
        Scene(contact_model("vscm", load_settings().contact_models), SceneConfig.load(path))
    with pytest.raises(ValueError, match="pairs must be a list of"):
        SceneConfig.from_mapping("x", {"pairs": [["plate"]]})


def test_all_collisions_scene_puts_every_geom_in_the_broad_phase():
    scene = Scene(contact_model("vscm", load_settings().contact_models), "all_collisions")
    model = scene.model
    assert model.npair == 0 and np.all(model.geom_contype == 1) and np.all(model.geom_conaffinity == 1)
    assert model.geom_priority[scene.object_geom_id] == 1


@pytest.mark.parametrize("yaw", [0.0, 0.6, 1.0, math.pi / 2, math.pi, -2.0])
def test_the_contact_candidate_is_on_the_face_towards_the_arm_however_the_cube_is_turned(yaw):
    """A cube turned by a quarter turn is the same cube: the candidate sits on the face the arm reaches, its
    inward normal the one of the cube's four within 45 degrees of straight away from the arm base."""
    settings = load_settings()
    config = settings.scene
    config = dataclasses.replace(config, object=dataclasses.replace(config.object, position_m=(0.9, 0.3), yaw_rad=yaw))
    scene = Scene(contact_model("vscm", settings.contact_models), config)
    data = scene.data_at(start_configuration(7))
    away = np.array([0.9, 0.3]) / np.hypot(0.9, 0.3)
    normal = scene.inward_normal(data)
    assert normal[:2] @ away >= math.cos(math.pi / 4) - 1e-9 and abs(normal[2]) < 1e-9
    centre = data.xpos[scene.object_body_id]
    np.testing.assert_allclose(data.site_xpos[scene.object_site_id], centre - 0.075 * normal, atol=1e-9)
    quarter_turns = round(math.remainder(math.atan2(normal[1], normal[0]) - yaw, 2 * math.pi) / (math.pi / 2)) % 4
    assert pushed_face((0.9, 0.3), yaw) == quarter_turns
