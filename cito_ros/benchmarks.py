"""Benchmarks that print figures (medians, ratios); never asserted in tests.

Each function returns a JSON-serialisable dict; `cito-bench` prints it.
"""
from __future__ import annotations

import os
import statistics
import time
from typing import Callable

import numpy as np

from cito_ros import oracle
from cito_ros.config import load_parameters
from cito_ros.contact_models import contact_model
from cito_ros.scene import Scene, start_configuration
from cito_ros.simulator import Simulator


def median_ms(function: Callable[[], object], repeats: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        function()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        samples.append(time.perf_counter() - start)
    return 1e3 * statistics.median(samples)


def benchmark_torques(simulator: Simulator, seed: int = 0) -> np.ndarray:
    """A fixed pseudo-random torque sequence at 20 % of the motor limits: the arm moves."""
    rng = np.random.default_rng(seed)
    return 0.2 * rng.uniform(-1, 1, (simulator.n_knots, 7)) * simulator.scene.torque_limit


def rollout_benchmark(repeats: int = 200, batch: int = 64, nthread: int = 2) -> dict:
    """Native vs Python-oracle rollout of the default horizon (VSCM, beta from config, k = k_max)."""
    parameters = load_parameters()
    model = contact_model("vscm", parameters)
    scene = Scene(model, parameters["scene"])
    oracle_scene = Scene(model, parameters["scene"], native=False)
    simulator = Simulator(scene, parameters["horizon_s"], parameters["control_period_s"], nthread=nthread)
    state = scene.initial_state(start_configuration(parameters["beta"]))
    torques = benchmark_torques(simulator)
    stiffness = np.full(simulator.n_knots, model.stiffness_max)
    controls = simulator.step_controls(simulator.knot_controls(torques, stiffness))

    native_ms = median_ms(lambda: simulator.rollout_batch(state[None], controls[None]), repeats)
    decoded_ms = median_ms(lambda: simulator.rollout(state, torques, stiffness), repeats)
    python_ms = median_ms(lambda: oracle.rollout(simulator, oracle_scene, state, torques, stiffness),
                          max(5, repeats // 20), warmup=1)
    states = np.repeat(state[None], batch, axis=0)
    batch_controls = np.repeat(controls[None], batch, axis=0)
    batch_ms = median_ms(lambda: simulator.rollout_batch(states, batch_controls), max(5, repeats // 20))
    return {
        "contact_model": model.name,
        "horizon_s": simulator.horizon_s,
        "timestep_s": simulator.timestep_s,
        "steps": simulator.n_steps,
        "native_rollout_ms": native_ms,
        "native_rollout_with_decoding_ms": decoded_ms,
        "python_rollout_ms": python_ms,
        "speedup_native_over_python": python_ms / native_ms,
        "batched_rollouts_per_s": batch / (batch_ms / 1e3),
        "batch_threads": nthread,
        "step_us": 1e3 * native_ms / simulator.n_steps,
        "cpu_count": os.cpu_count(),
    }
