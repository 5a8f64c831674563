"""Settings are read once, typed and validated, with every default in config/planner.yaml and every
bad value named by its dotted parameter name; the metric fields are declared once."""
import dataclasses
import re
import typing
from pathlib import Path

import pytest

from cito_ros.planner.results import METRIC_NAMES
from cito_ros.settings import Settings, load_parameters, load_settings
from cito_ros.settings.paths import share_dir


def settings_classes(cls=Settings, seen=None):
    seen = set() if seen is None else seen
    if cls in seen or not dataclasses.is_dataclass(cls):
        return seen
    seen.add(cls)
    for annotation in typing.get_type_hints(cls).values():
        for candidate in (annotation, *typing.get_args(annotation)):
            settings_classes(candidate, seen)
    return seen


def settings_module_classes():
    return {cls.__name__ for cls in settings_classes()}


def test_the_config_file_reads_into_frozen_typed_settings(settings):
    assert isinstance(settings.solver.max_iter, int) and settings.solver.stall_iterations == 5
    assert settings.scene.name == "default" and settings.stages.discovery.max_iter == 50
    assert settings.weights.scm.w5 is None and settings.weights.cccm.w5 is not None
    assert settings.horizon == (settings.horizon_s, settings.control_period_s)
    assert settings.with_overrides({"pipeline": "paper"}).horizon == (1.0, 0.05)
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.solver.max_iter = 3


def test_every_default_lives_in_the_config_files_only():
    assert settings_module_classes() >= {"Settings", "SolverSettings", "SceneConfig", "ObjectConfig", "Weights"}
    for cls in settings_classes():
        for field in dataclasses.fields(cls):
            if field.metadata.get("internal"):
                continue
            assert field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING, \
                f"{cls.__name__}.{field.name} has a default in code"
            assert field.metadata.get("description"), f"{cls.__name__}.{field.name} has no description"


def test_settings_round_trip_through_the_parameter_tree(settings):
    assert Settings.from_mapping(settings.to_mapping()) == settings
    assert settings.to_mapping() == load_parameters()


@pytest.mark.parametrize("overrides, message", [
    ({"solver.max_iter": 0}, "solver.max_iter must be a positive integer, got 0"),
    ({"solver.max_iter": 2.5}, "solver.max_iter must be an integer, got 2.5"),
    ({"solver.time_limit_s": -1.0}, "solver.time_limit_s must be positive, got -1.0"),
    ({"solver.iteration_budget": -1}, "solver.iteration_budget must be"),
    ({"executor.plan_iterations": 0}, "executor.plan_iterations must be a positive integer"),
    ({"solver.stall_iterations": 0}, "solver.stall_iterations must be a positive integer"),
    ({"solver.scale_variables": "yes"}, "solver.scale_variables must be true or false"),
    ({"horizon_s": -1.0}, "horizon_s must be positive"),
    ({"control_period_s": 2.0}, "whole number of control periods"),
    ({"control_period_s": 0.0125}, "whole number of timesteps"),
    ({"executor.horizon_s": 2.5}, "executor.horizon_s 2.5 must be a positive whole number of control periods"),
    ({"beta": float("nan")}, "beta must be finite"),
    ({"weights.vscm.w3": -0.2}, "weights.vscm.w3 must be non-negative"),
    ({"weights.cccm.w5": None}, "weights.cccm.w5: missing"),
    ({"contact_models.vscm.stiffness_initial": 150.0}, "contact_models.vscm.stiffness_initial 150.0 exceeds"),
    ({"stages.starts": [0.3, 1.2]}, r"stages.starts must be fractions of the horizon in \[0, 1\)"),
    ({"stages.starts": [], "stages.scripted.enabled": False, "stages.scripted.side_faces.enabled": False},
     r"stages.starts must be fractions of the horizon in \[0, 1\), at least one where the scripts and the side"),
    ({"stages.starts": [0.3, -1.0]}, r"stages.starts\[1\] must be non-negative"),
    ({"stages.solver": "newton"}, "stages.solver must be one of"),
    ({"stages.scripted.push_end_fraction": 0.3}, r"stages.scripted: approach_fraction < push_end_fraction <= 1"),
    ({"stages.scripted.joint_weights": [1.0, 5.0]}, r"stages.scripted.joint_weights must have one entry per arm joint"),
    ({"stages.scripted.variants.horizon_scale": [1.0]}, r"stages.scripted.variants must give every variant one entry"),
    ({"stages.scripted.variants.push_end_fraction": [0.9, 0.2]},
     r"stages.scripted: approach_fraction < push_end_fraction <= 1 is needed, got 0.35 and 0.2"),
    ({"stages.scripted.variants.horizon_scale": [1.0, 0.0]}, r"stages.scripted.variants.horizon_scale\[1\] must be positive"),
    ({"stages.physical.max_iter": []}, "stages.physical must list at least one stage"),
    ({"stages.physical.max_iter": [30]}, "stages.physical must list at least one stage, with one entry per stage"),
    ({"stages.physical.only_if_beyond_limits": [True, False, True, True]},
     r"stages.physical.only_if_beyond_limits\[0\] must be false"),
    ({"tracking.kp": [1.0, 2.0]}, "tracking.kp and tracking.kd must have one gain per arm joint"),
    ({"paper.control_period_s": 0.3}, "paper.horizon_s 1.0 must be a positive whole number of control periods"),
    ({"pipeline": "fast"}, "pipeline must be one of"),
    ({"node.default_contact_model": "rigid"}, "node.default_contact_model must be one of"),
    ({"scene": "moon"}, "unknown scene 'moon'"),
    ({"solver.maxiter": 10}, r"solver.maxiter: unknown parameter \(solver has"),
    ({"solver.ipopt": 3}, "solver.ipopt must be a section of option names and values"),
    ({"task.push_distance_m.x": 1.0}, "task.push_distance_m is a value, not a section"),
])
def test_a_bad_value_is_named_before_anything_is_solved(settings, overrides, message):
    with pytest.raises(ValueError, match=message):
        settings.with_overrides(overrides)


def test_a_params_file_with_a_bad_value_fails_to_load(tmp_path):
    text = (share_dir() / "config" / "planner.yaml").read_text().replace("max_iter: 100", "max_iter: -4")
    path = tmp_path / "planner.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match="solver.max_iter must be a positive integer, got -4"):
        load_settings(path)


def test_overrides_give_a_new_validated_copy(settings):
    changed = settings.with_overrides({"solver.max_iter": 7, "stages.starts": [0.4]})
    assert changed.solver.max_iter == 7 and changed.stages.starts == (0.4,)
    assert settings.solver.max_iter == 100 and settings.stages.starts == (0.5, 0.3, 0.15, 0.7)


def test_the_metric_fields_are_the_plan_metrics_message():
    text = (Path(__file__).resolve().parent.parent / "msg_defs" / "msg" / "PlanMetrics.msg").read_text()
    names = [match.group(1) for match in re.finditer(r"^\s*[\w/]+(?:\[\])?\s+(\w+)", text, re.MULTILINE)]
    assert names == [name.lower() for name in METRIC_NAMES]
