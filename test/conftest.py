"""Shared fixtures: real MuJoCo scenes, compiled once per test session; the planner node in its own process with a
client in this one, and its plans, once per test module that asks for them."""
from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import Scene, start_configuration
from cito_ros.model.simulator import Simulator
from cito_ros.settings import load_settings

import node_harness
from node_harness import Client, logs_written_since, request, start_node, wait_for_bag, wait_for_states


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """A failing test's report shows the end of what every node and robot said while it ran."""
    report = (yield).get_result()
    if report.when == "call" and report.failed:
        for log in logs_written_since(call.start):
            lines = log.read_text(errors="replace").splitlines()
            report.sections.append((f"{log.name}, its last {min(len(lines), 60)} lines", "\n".join(lines[-60:])))


@pytest.fixture(scope="session", autouse=True)
def log_directory(tmp_path_factory):
    node_harness.LOG_DIRECTORY = tmp_path_factory.mktemp("logs")


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


@pytest.fixture(scope="module")
def domain():
    return 1 + os.getpid() % 100


@pytest.fixture(scope="module")
def node(domain, tmp_path_factory):
    bags = tmp_path_factory.mktemp("bags")
    process = start_node(domain, bags)
    yield process, bags
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()


@pytest.fixture(scope="module")
def client(node, domain):
    c = Client(domain)
    assert c.wait_for_service(), "the planner service did not appear"
    yield c
    c.close()


@pytest.fixture(scope="module")
def plans(client):
    """One plan per contact model from q0(beta = 7), with the messages each published."""
    out = {}
    for model in ("cccm", "scm", "vscm"):
        for received in client.received.values():
            received.clear()
        response = client.call(request(model))
        wait_for_states(client, response)
        assert wait_for_bag(Path(response.bag_path)), "the bag was not finished"
        out[model] = (response, {t: list(v) for t, v in client.received.items()})
    return out
