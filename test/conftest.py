"""Shared fixtures: real MuJoCo scenes, compiled once per test session."""
from __future__ import annotations

import numpy as np
import pytest

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene, start_configuration
from cito_ros.model.simulator import Simulator
from cito_ros.settings import load_settings


@pytest.fixture(scope="session")
def settings():
    return load_settings()


@pytest.fixture(scope="session")
def scenes(settings):
    """Native scene per contact model name."""
    return {name: Scene(contact_model(name, settings.contact_models)) for name in ("cccm", "scm", "vscm")}


@pytest.fixture(scope="session")
def oracle_scenes(settings):
    return {name: Scene(contact_model(name, settings.contact_models), native=False) for name in ("cccm", "scm", "vscm")}


@pytest.fixture(scope="session")
def simulators(scenes):
    return {name: Simulator(scene) for name, scene in scenes.items()}


@pytest.fixture(scope="session")
def start_states(scenes):
    """Initial full-physics state per beta (identical for every contact model)."""
    return {beta: scenes["vscm"].initial_state(start_configuration(beta)) for beta in (5, 6, 7)}


def approach_torques(simulator: Simulator, seed: int = 1, scale: float = 0.15) -> np.ndarray:
    """A fixed torque sequence that moves the whole arm."""
    rng = np.random.default_rng(seed)
    return scale * rng.uniform(-1, 1, (simulator.n_knots, 7)) * simulator.scene.torque_limit
