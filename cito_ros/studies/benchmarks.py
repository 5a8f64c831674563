"""Benchmarks that print figures (medians, ratios); never asserted in tests.

Each function returns a JSON-serialisable dict; `cito-bench` prints it.
"""
from __future__ import annotations

import os
import statistics
import sys
import time
from typing import Callable

import numpy as np
from tqdm import tqdm

from cito_ros.model import oracle
from cito_ros.model.scene import Scene, start_configuration
from cito_ros.model.simulator import Simulator
from cito_ros.planner.builder import PushRequest, build_problem
from cito_ros.planner.plan import plan_push
from cito_ros.planner.results import PHASE_METRICS, ZONES, zone
from cito_ros.settings import load_settings
from cito_ros.studies.paper import PAPER_CASES, PAPER_MODELS


def median_ms(function: Callable[[], object], repeats: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        function()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        samples.append(time.perf_counter() - start)
    return 1e3 * statistics.median(samples)


def paired_ms(first: Callable[[], object], second: Callable[[], object], repeats: int,
              warmup: int = 3) -> tuple[float, float, float]:
    """The median times (ms) of two functions timed in turn, back to back, the first of each pair alternating, and
    the median of their paired ratios (first / second): where the machine's speed drifts over a run (a shared
    2-core machine's does, by up to 1.5 times within a session), it moves both sides of a pair alike, and
    timing one function's repeats after the other's does not."""
    for _ in range(warmup):
        first()
        second()
    times: tuple[list[float], list[float]] = ([], [])
    for repeat in range(repeats):
        for side in ((0, 1) if repeat % 2 == 0 else (1, 0)):
            start = time.perf_counter()
            (first, second)[side]()
            times[side].append(time.perf_counter() - start)
    ratios = [a / b for a, b in zip(*times, strict=True)]
    return 1e3 * statistics.median(times[0]), 1e3 * statistics.median(times[1]), statistics.median(ratios)


def benchmark_torques(simulator: Simulator, seed: int = 0) -> np.ndarray:
    """A fixed pseudo-random torque sequence at 20 % of the motor limits: the arm moves."""
    rng = np.random.default_rng(seed)
    return 0.2 * rng.uniform(-1, 1, (simulator.n_knots, 7)) * simulator.scene.torque_limit


def rollout_benchmark(repeats: int = 200, batch: int = 64, nthread: int = 2) -> dict:
    """Native vs Python-oracle rollout of the default horizon (VSCM, beta from config, k = k_max), and native vs
    plain MuJoCo stepping the same scene through the same motion, timed in pairs (paired_ms)."""
    settings = load_settings()
    posed = build_problem(settings, PushRequest("vscm"))
    scene, state, model = posed.scene, posed.initial_state, posed.scene.contact_model
    oracle_scene = Scene(model, settings.scene, native=False)
    simulator = Simulator(scene, *settings.horizon, nthread=nthread)
    torques = benchmark_torques(simulator)
    stiffness = np.full(simulator.n_knots, model.stiffness_max)
    controls = simulator.step_controls(simulator.knot_controls(torques, stiffness))

    decoded_ms = median_ms(lambda: simulator.rollout(state, torques, stiffness), repeats)
    python_ms = median_ms(lambda: oracle.rollout(simulator, oracle_scene, state, torques, stiffness),
                          max(5, repeats // 20), warmup=1)
    # plain MuJoCo stepping the same scene through the same motion: the oracle's model (the plugins removed, its
    # motors and contact actuator plain actuators) driven by the forces the native rollout applied each step
    # (its motors' total torques, the contact force), rolled out by mujoco.rollout as the native one is
    plain = Simulator(oracle_scene, *settings.horizon, nthread=nthread)
    native_states, sensed, _ = simulator.rollout_batch(state[None], controls[None])
    plain_controls = np.zeros((simulator.n_steps, oracle_scene.model.nu))
    plain_controls[:, oracle_scene.motor_ids] = sensed[0][:, scene.sensors.torque]
    plain_controls[:, oracle_scene.contact_actuator_id] = sensed[0][:, scene.sensors.gamma][:, 0]
    native_ms, plain_ms, native_over_plain = paired_ms(
        lambda: simulator.rollout_batch(state[None], controls[None]),
        lambda: plain.rollout_batch(state[None], plain_controls[None]), repeats)
    plain_states, _, _ = plain.rollout_batch(state[None], plain_controls[None])
    arm = oracle_scene.state_qpos_adr + oracle_scene.arm_qpos_adr
    plain_drift_rad = float(np.max(np.abs(plain_states[0][:, arm] - native_states[0][:, arm])))
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
        "plain_mujoco_rollout_ms": plain_ms,
        "plain_mujoco_joint_drift_rad": plain_drift_rad,
        "native_over_plain_mujoco": native_over_plain,  # the median of paired ratios (paired_ms)
        "batched_rollouts_per_s": batch / (batch_ms / 1e3),
        "batch_threads": nthread,
        "step_us": 1e3 * native_ms / simulator.n_steps,
        "cpu_count": os.cpu_count(),
    }


def gradient_benchmark(repeats: int = 20, contact_model_name: str = "vscm") -> dict:
    """Time of the full gradient (cost over every decision variable; linearization, adjoint
    pass and terminal derivatives) against one bare native rollout of the same controls, at the
    optimizer's start (zero torques) perturbed a little per repeat (no cache hits). Beside it, the
    Gauss-Newton curvature from the gradient's linearization: iLQR's knot-wise expansion and the
    residual Jacobian of least squares and IPOPT's gauss_newton Hessian."""
    settings = load_settings()
    posed = build_problem(settings, PushRequest(contact_model_name))
    problem, simulator, state = posed.problem, posed.simulator, posed.initial_state
    rng = np.random.default_rng(0)
    points = [np.clip(problem.initial_guess + 0.01 * rng.uniform(-1, 1, problem.size) * problem.scale,
                      problem.lower, problem.upper) for _ in range(repeats + 3)]
    samples: dict[str, list[float]] = {"linearization": [], "gradient": [], "expansion": [], "jacobian": []}
    for i, z in enumerate(points):
        problem.evaluate(z)
        times = {}
        for name, compute in (("linearization", lambda: problem.linearize(z)),
                              ("gradient", lambda: problem.derivatives(z, cached=False)),
                              ("expansion", lambda: problem.knot_expansion(z)),     # the gradient's linearization
                              ("jacobian", lambda: problem.residual_jacobian(z))):  # likewise
            start_time = time.perf_counter()
            compute()
            times[name] = time.perf_counter() - start_time
        if i >= 3:  # warm-up
            for name, value in times.items():
                samples[name].append(value)
    controls = simulator.step_controls(problem.knot_controls(points[0]))[None]
    rollout_ms = median_ms(lambda: simulator.rollout_batch(state[None], controls), 10 * repeats, warmup=10)
    ms = {name: 1e3 * statistics.median(values) for name, values in samples.items()}
    return {
        "contact_model": problem.contact_model.name,
        "decision_variables": problem.size,
        "steps": simulator.n_steps,
        "threads": settings.gradient.threads,
        "gradient_ms": ms["gradient"],
        "linearization_ms": ms["linearization"],
        "knot_expansion_ms": ms["expansion"],
        "residual_jacobian_ms": ms["jacobian"],
        "rollout_ms": rollout_ms,
        "ratio": ms["gradient"] / rollout_ms,
        # an iLQR iteration's derivatives: the gradient's linearization and the knot-wise curvature from it
        "gradient_and_curvature_ratio": (ms["gradient"] + ms["expansion"]) / rollout_ms,
        "repeats": repeats,
    }


def solve_cost_benchmark(goals: int = 20, seed: int = 0, repeats: int = 20) -> dict:
    """In this process, one after the other: each of the paper's nine cases and of the first `goals`
    goals of `cito-bench targets` (seed `seed`) is solved by the physical pipeline, and one rollout of
    its problem's first horizon is timed (median of `repeats`). The solve cost in rollout-equivalents
    (solve time / rollout time, per case) does not depend on the machine's speed."""
    from cito_ros.studies.targets import draw_goals

    settings = load_settings().with_overrides({"stages.parallel": False})  # one thread per solve, as on Ray
    requests = [(f"paper {model} beta {beta}", PushRequest(model, beta=beta)) for model, beta in PAPER_CASES]
    for goal in draw_goals(goals, seed, settings)[0]:
        requests += [(f"target {goal.index} {model}",
                      PushRequest(model, start_q=start_configuration(goal.beta),
                                  target_position_m=np.array(goal.target_position_m),
                                  target_yaw_rad=goal.target_yaw_rad)) for model in PAPER_MODELS]
    cases = []
    for name, request in tqdm(requests, desc="solve-cost", unit="solve", file=sys.stderr):
        posed = build_problem(settings, request)
        controls = posed.simulator.step_controls(posed.problem.knot_controls(posed.problem.initial_guess))[None]
        rollout_ms = median_ms(lambda: posed.simulator.rollout_batch(posed.initial_state[None], controls), repeats)
        result = plan_push(request.contact_model, request.beta, start_q=request.start_q,
                           target_position_m=request.target_position_m, target_yaw_rad=request.target_yaw_rad,
                           settings=settings)
        m = result.metrics
        cases.append({"case": name, "rollout_ms": rollout_ms, "solve_time_s": m.solve_time_s,
                      "rollout_equivalents": 1e3 * m.solve_time_s / rollout_ms, "iterations": m.iterations,
                      "success": m.success, "zone": zone(m.steady_reach_margin_m),
                      **{phase: getattr(m, phase) for phase in PHASE_METRICS}})

    def median(rows: list[dict], key: str) -> float:
        return float(statistics.median(row[key] for row in rows))

    paper, targets = cases[:len(PAPER_CASES)], cases[len(PAPER_CASES):]
    return {
        "cases": len(cases),
        "rollout_ms_median": median(cases, "rollout_ms"),
        "solve_time_s_median": {"paper": median(paper, "solve_time_s"),
                                "targets": median(targets, "solve_time_s") if targets else None,
                                "all": median(cases, "solve_time_s")},
        "rollout_equivalents_median": median(cases, "rollout_equivalents"),
        "iterations_median": median(cases, "iterations"),
        "success": sum(row["success"] for row in cases),
        # per reach zone (cito_ros.planner.results.zone): the speed aims hold inside the steady push reach
        "by_zone": {name: {"cases": len(rows), "success": sum(row["success"] for row in rows),
                           "solve_time_s_median": median(rows, "solve_time_s") if rows else None,
                           "rollout_equivalents_median": median(rows, "rollout_equivalents") if rows else None}
                    for name in ZONES for rows in [[row for row in cases if row["zone"] == name]]},
        "phase_share_median": {phase: float(statistics.median(row[phase] / row["solve_time_s"] for row in cases))
                               for phase in PHASE_METRICS},
        "per_case": cases,
    }


def roughness_benchmark(scenes: tuple[str, ...] = ("default", "fine_step"), betas: tuple[int, ...] = (5, 6, 7),
                        directions: int = 2, points: int = 21, reference_amplitude_rad: float = 1e-4,
                        torque_amplitude_Nm: float = 5e-3, overrides: dict | None = None, seed: int = 0,
                        plans: bool = False) -> dict:
    """How far the executed outcome of a push jumps under tiny changes of the plan, per scene: why a
    request moved by 1e-9 can end elsewhere (docs/planner.md: Tiny changes and rough pushes). For each paper start pose (beta,
    the default target), the scripted push (cito_ros.planner.scripted) or, with `plans`, the plan the planner
    returns (SCM) is scanned along `directions` seeded random directions at `points` (odd) evenly
    spaced amplitudes: its joint reference (the executed trajectory of a plan), tracked by the PD
    controller (cito_ros.planner.tracking), within +-reference_amplitude_rad of every joint; and its knot
    torques, executed open loop without the virtual force, within +-torque_amplitude_Nm. A smooth
    outcome changes little between neighbouring points; the largest change of the position error at rest
    between neighbours is the scan's jump. Beside it, how high the cube leaves its resting height in
    the unperturbed tracked push (a cube that hops lands on an edge), the executed error of the
    unperturbed torques (the scans' centre), and the rollout time of the scene's step (the price of a
    finer one)."""
    from cito_ros.planner import tracking
    from cito_ros.planner.scripted import joint_path, scripted_torques
    from cito_ros.planner.stages import physical_twin

    if points < 3 or points % 2 == 0 or directions < 1:
        raise ValueError(f"a scan needs an odd number of points, at least 3, and 1 direction, got {points} and "
                         f"{directions}")
    # every scene parsed before the first scan: an unknown one is refused at once
    scene_settings = {scene: load_settings().with_overrides({**(overrides or {}), "scene": scene}) for scene in scenes}
    results = {}
    for scene, settings in scene_settings.items():
        rng = np.random.default_rng(seed)
        cases = []
        for beta in betas:
            plan = plan_push("scm", beta, settings=settings) if plans else None
            horizon = {"horizon_s": float(plan.knot_time_s[-1])} if plans else {}  # a later start may be longer
            problem = build_problem(settings.with_overrides(horizon), PushRequest("scm", beta=beta)).problem
            executor = physical_twin(problem, problem.cost)
            simulator = executor.simulator
            if plans:
                path, torques = tracking.JointPath(plan.trajectory.q, plan.trajectory.qdot), plan.knot_torques_Nm
            else:
                path = joint_path(executor, settings.stages.scripted)
                torques = scripted_torques(executor, settings.stages.scripted, settings.tracking)
            nominal = tracking.track(simulator, executor.initial_state, path, settings.tracking)
            hop_m = float(np.max(nominal.object_position_m[:, 2] - nominal.object_position_m[0, 2]))
            controls = simulator.step_controls(executor.knot_controls(executor.with_torques(torques)))[None]
            rollout_ms = median_ms(lambda: simulator.rollout_batch(executor.initial_state[None], controls), 10)
            for _ in range(directions):
                direction_q, direction_qdot = tracking.smooth_offset(rng, simulator.n_knots, len(path.q),
                                                                     simulator.timestep_s)
                direction_torque = rng.uniform(-1.0, 1.0, torques.shape)
                tracked, open_loop = [], []
                for fraction in np.linspace(-1.0, 1.0, points):
                    shift = fraction * reference_amplitude_rad
                    reference = tracking.JointPath(path.q + shift * direction_q, path.qdot + shift * direction_qdot)
                    tracked.append(tracking.tracked_rest_error_m(simulator, executor.initial_state, reference,
                                                                 executor.task, settings.tracking))
                    evaluation = executor.evaluate(executor.with_torques(
                        torques + fraction * torque_amplitude_Nm * direction_torque))
                    open_loop.append(tracking.rest_errors(simulator, evaluation.states[-1], executor.task,
                                                          settings.tracking)[0])
                cases.append({"beta": beta, "executed_error_m": open_loop[points // 2],
                              "success": None if plan is None else plan.metrics.success,
                              "tracked_jump_m": float(np.max(np.abs(np.diff(tracked)))),
                              "tracked_span_m": float(np.ptp(tracked)),
                              "open_loop_jump_m": float(np.max(np.abs(np.diff(open_loop)))),
                              "open_loop_span_m": float(np.ptp(open_loop)), "hop_m": hop_m,
                              "rollout_ms": rollout_ms})
        summary = {key: {"median": float(statistics.median(c[key] for c in cases)),
                         "max": float(max(c[key] for c in cases))}
                   for key in ("tracked_jump_m", "open_loop_jump_m", "hop_m", "executed_error_m", "rollout_ms")}
        results[scene] = {"timestep_s": settings.scene.timestep_s, **summary, "cases": cases}
    return {"scanned": "plans" if plans else "scripts", "reference_step_rad": 2 * reference_amplitude_rad / (points - 1),
            "torque_step_Nm": 2 * torque_amplitude_Nm / (points - 1), "scenes": results}


def push_limits_benchmark(plate_heights_m: tuple[float, ...] | None = None, step_m: float = 0.005) -> dict:
    """Where a push whose plate holds its height can leave the object, against the push reach
    (cito_ros.planner.push_limits): per kind of contact and plate height, the farthest rest distance, where the
    plate is then, its fastest speed along the push there and the slide it buys."""
    from cito_ros.planner import push_limits

    settings = load_settings()
    posed = build_problem(settings, PushRequest("vscm", settings.beta))
    if plate_heights_m is None:
        plate_heights_m = push_limits.face_heights_m(posed.scene)
    limits = push_limits.push_limits(posed.scene, posed.initial_state, plate_heights_m, step_m=step_m)
    farthest = []
    for contact in push_limits.CONTACTS:
        for height in plate_heights_m:
            rows = [row for row in limits if row.contact == contact and row.plate_height_m == height]
            if rows:
                best = max(rows, key=lambda row: row.rest_distance_m)
                farthest.append({"contact": contact, "plate_height_m": height,
                                 "plate_distance_m": best.plate_distance_m, "object_distance_m": best.object_distance_m,
                                 "release_speed_m_s": best.release_speed_m_s, "slide_m": best.slide_m,
                                 "rest_distance_m": best.rest_distance_m,
                                 "largest_slide_m": max(row.slide_m for row in rows)})
    return {"push_reach_m": posed.scene.push_reach_m(), "step_m": step_m,
            # the bound every answer's reach zone is judged against, found directly rather than on the grid
            "planner_steady_reach_m": push_limits.steady_reach_m(posed.scene, posed.initial_state),
            "steady_reach_m": {contact: push_limits.farthest(limits, contact).rest_distance_m
                               for contact in push_limits.CONTACTS},
            "farthest": farthest,
            "positions": [{**vars(row), "rest_distance_m": row.rest_distance_m} for row in limits]}
