"""The physical pipeline: a scripted push, or the contact model where that does not do, discovers contact;
the plan that leaves is refined without the virtual force. First the scripted start and its variants
(when `stages.scripted.enabled`), then each of `stages.starts` at each of `stages.horizon_scales`, in
that order, until one succeeds (two side by side when `stages.parallel`, see `solve_physical`):

0. scripted start (cito_ros.planner.scripted): instead of a discovery, the torques of a PD-tracked push that
   touches the object by construction, straight into the physical stages (2.) with the contact term
   from the script's first touch. Most pushes within the arm's quasi-static reach succeed from it in
   a few iterations. Where it misses, its variants (`stages.scripted.variants`: another contact
   height, an earlier end of the push, a longer horizon) follow, each a start of its own: near the
   arm's push reach a few different pushes are cheaper tickets than the discoveries. The rest go on
   to the discoveries.
1. discovery: the contact model's problem from zero torques, plus the arm's limits and a reach
   term, the plate-object gap squared from the start's fraction of the horizon on. The virtual force
   alone pushes from centimetres away and never along the face (it acts at the face centre, along
   its normal); the reach term brings the plate onto the object so that real contact pushes too.
   CCCM's slack is eliminated (stages.discovery.cccm, StageCost.complementarity): box-bounded, its
   discovery is solved like SCM's and VSCM's rather than by IPOPT with constraints.
2. physical stages (`stages.physical`): the torques alone, the contact control held at 0 (the
   dynamics the plan is executed with), from the previous stage's torques, with a contact term
   that keeps the plate on the object from the discovery's touch-down to the end: a push, not a
   strike, whose outcome depends smoothly on the torques. A stage marked only_if_beyond_limits runs
   only while the best plan still exceeds the arm's joint speed limits or ranges.
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import threading
import time
from typing import Callable

import numpy as np

from cito_ros.planner.builder import PushRequest, build_problem, scene_config
from cito_ros.planner.candidates import Executed
from cito_ros.planner.problem import PushProblem
from cito_ros.planner.results import IterationLog
from cito_ros.planner.scripted import scripted_torques
from cito_ros.planner.side_faces import face_needed, plate_tilt, side_joint_path
from cito_ros.planner.stages import Outcome, SolveClock, StartRun, physical_twin, stage_cost, touch_profile
from cito_ros.settings import Settings


def solve_physical(settings: Settings, request: PushRequest, *,
                   iteration_callback: Callable[[IterationLog], None] | None = None,
                   cancel: threading.Event | None = None) -> Outcome:
    """Every start at every horizon (stages.starts within stages.horizon_scales), in that order, until
    one succeeds: the plan is the first success in that order (the best of the scripts where a script
    succeeds short of the goal margin), or the best executed plan of all.
    Each start is a lottery ticket of a non-convex problem: about half the pushes succeed with the
    first and pay for one. With stages.parallel the next start runs beside the earliest unfinished
    one, on a thread of its own, and is abandoned when an earlier start succeeds: the threads change
    how long a solve takes (docs/planner.md: The search over starts), never which plan is returned."""
    clock = SolveClock(settings, iteration_callback)
    stages = settings.stages
    labelled = len(stages.starts) > 1
    horizon_label = (lambda horizon_s: f"horizon {horizon_s:g} s, " if len(stages.horizon_scales) > 1 else "")
    first_horizon_s = settings.round_horizons_s[0]
    # (settings overrides, discovery start fraction, None for a script or a SideStart, stage-name prefix)
    jobs = []
    side = side_start(settings, request)
    if side is not None and side.reaches:  # first the face the goal needs; the near face's starts follow
        faces = stages.scripted.side_faces
        overrides = {"horizon_s": settings.round_horizon_s(faces.horizon_scale),
                     "control_period_s": faces.control_period_s, "gradient.stride": faces.gradient_stride}
        jobs = [(overrides, dataclasses.replace(side, offset_scale=scale), f"side face{f' {i + 1}' if i else ''}: ")
                for i, scale in enumerate(faces.offset_scales)]
    if stages.scripted.enabled:
        jobs.append(({"horizon_s": first_horizon_s}, None, f"{horizon_label(first_horizon_s)}scripted: "))
        for i, (height_m, push_end, scale, gain_scale) in enumerate(stages.scripted.variants):
            horizon_s = settings.round_horizon_s(scale)
            jobs.append(({"horizon_s": horizon_s, "stages.scripted.contact_height_m": height_m,
                          "stages.scripted.push_end_fraction": push_end, "stages.scripted.gain_scale": gain_scale}, None,
                         f"{horizon_label(horizon_s)}scripted {i + 2}: "))
    jobs += [({"horizon_s": horizon_s}, fraction, horizon_label(horizon_s) + (f"start {i + 1}: " if labelled else ""))
             for horizon_s in settings.round_horizons_s for i, fraction in enumerate(stages.starts)]
    if not jobs:  # no discoveries (stages.starts), the scripts off, and a goal that needs no side face
        raise ValueError("no start to solve: the goal needs no side face, and the scripts and discoveries are off")
    width = 2 if stages.parallel and len(jobs) > 1 else 1
    scripts = sum(1 for _, start, _ in jobs if not _discovery(start))  # before the discoveries
    abandoned = [threading.Event() for _ in jobs]
    results: dict[int, tuple] = {}

    def settles(index: int) -> bool:
        """Whether a finished start ends the search: an interruption; before the last script, a success
        at the goal with the margin; from the last script on, a success of its own or of a script before
        it. A script's success short of the margin lets the next scripts run, and the best is kept: at
        the tolerance, which start's plan is returned flips with a hair of change in the request, and a
        script costs a second or two (docs/planner.md: The search over starts)."""
        executed, outcome = results[index]
        if outcome.status.interrupted:
            return True
        if index + 1 < scripts:
            return succeeds(executed) and executed.reaches(settings, outcome.executor.task)
        return any(succeeds(results[i][0]) for i in range(index + 1) if i in results)

    def succeeds(executed: Executed) -> bool:
        return Executed.succeeds(executed.rank(settings))

    def decided() -> bool:
        """Whether the finished starts settle the plan: the first unfinished start comes after a start
        that settles it, or none is left."""
        for index in range(len(jobs)):
            if index not in results:
                return False
            if settles(index):
                return True
        return True

    def solve(index: int):
        overrides, fraction, prefix = jobs[index]
        overrides = {**overrides, **({"gradient.threads": 1} if width > 1 else {})}
        return solve_start(clock, StartStop(cancel, abandoned[index]), settings, overrides, request, fraction, prefix)

    if width == 1:
        while not decided():
            results[len(results)] = solve(len(results))
    else:
        with concurrent.futures.ThreadPoolExecutor(width, thread_name_prefix="cito_start") as pool:
            running: dict[concurrent.futures.Future, int] = {}
            submitted = 0
            while not decided():
                # no start after a success is needed, whatever the earlier ones give
                while len(running) < width and submitted < len(jobs) and not any(map(settles, results)):
                    running[pool.submit(solve, submitted)] = submitted
                    submitted += 1
                finished, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
                for future in finished:
                    results[running.pop(future)] = future.result()
            for index in running.values():  # later starts, no longer needed
                abandoned[index].set()
            concurrent.futures.wait(running)
    ordered = []
    for index in sorted(results):
        ordered.append(results[index])
        if settles(index):
            break
    executed, outcome = min(ordered, key=lambda result: result[0].rank(settings))
    log = tuple(entry for _, result in ordered for entry in result.log)
    records = tuple(record for _, result in ordered for record in result.stages)
    interrupted = next((result.status for _, result in ordered if result.status.interrupted), None)
    return dataclasses.replace(outcome, log=log, stages=records, status=interrupted or outcome.status,
                               solve_time_s=clock.elapsed(), setup_s=sum(result.setup_s for _, result in ordered),
                               executed=executed, note=side.note() if side is not None and not side.reaches else "")


@dataclasses.dataclass(frozen=True)
class SideStart:
    """A start that is the scripted push on a side face (side_faces.side_joint_path's face, tilt and contact offset)."""

    face: int                # in quarter turns from the near face (side_faces.face_needed)
    tilt_rad: float          # side_faces.plate_tilt's
    offset_scale: float = 1.0  # an entry of side_faces.offset_scales
    short_m: float = 0.0     # how far the plate falls short of the face's contact at that tilt (plate_tilt's)
    reaches: bool = True     # short_m within side_faces.reach_tolerance_m: a start; else the near face's alone

    def note(self) -> str:
        """What an answer whose goal needs this face, out of the plate's reach, says of it."""
        return (f"a push towards the goal needs the object's side face {self.face} (more than 45 degrees off the "
                f"near face's normal), and the plate falls {100 * self.short_m:.1f} cm short of that face's "
                f"contact along the push: only the near face's pushes were tried, which reach such goals less often "
                f"and more slowly")


def _discovery(start: float | SideStart | None) -> bool:
    """Whether a job's start is a discovery's fraction (None: the near face's script; a SideStart: a side face's)."""
    return start is not None and not isinstance(start, SideStart)


def side_start(settings: Settings, request: PushRequest) -> SideStart | None:
    """The side face the request's goal needs (side_faces.face_needed), where it is one of side_faces.faces, with
    the tilt that reaches its contact (`reaches`), or the one that comes nearest; None where the goal needs none:
    the near face's starts alone."""
    side = settings.stages.scripted.side_faces
    if request.target_position_m is None:
        return None
    where = scene_config(settings, request).object
    face = face_needed(where.position_m, where.yaw_rad, request.target_position_m, settings)
    if face not in side.faces:
        return None
    posed = build_problem(settings, request)
    tilt_rad, short_m = plate_tilt(posed.scene, posed.initial_state, posed.task, face, side,
                                   settings.stages.scripted.joint_margin_rad)
    return SideStart(face, tilt_rad, short_m=short_m, reaches=short_m <= side.reach_tolerance_m)


class StartStop:
    """What a start's solver polls to stop: the solve's cancellation or the start's abandonment."""

    def __init__(self, *events: threading.Event | None):
        self.events = [event for event in events if event is not None]

    def is_set(self) -> bool:
        return any(event.is_set() for event in self.events)


def solve_start(clock: SolveClock, stop: StartStop, settings: Settings, overrides: dict, request: PushRequest,
                 fraction: float | SideStart | None, prefix: str):
    """One start, under `settings` with `overrides` (its horizon, its script): the discovery drawing the
    plate onto the object from `fraction` of the horizon on (None: the scripted push, cito_ros.planner.scripted,
    instead of a discovery; a SideStart: the push on its side face, cito_ros.planner.side_faces), then the physical
    stages. Returns the best plan's execution (from which the search derives its rank and goal margin) and the
    outcome."""
    began = time.perf_counter()
    settings = settings.with_overrides(overrides)  # the start's horizon and script: setup too
    posed = build_problem(settings, request)
    base, limits = posed.problem, settings.limits
    T = base.n_steps
    discovered = _discovery(fraction)
    reach = np.where(np.arange(T) >= int((fraction if discovered else 0.0) * T), 1.0 / T, 0.0)
    eliminated = base.contact_model.slack_variable is not None and settings.stages.discovery.cccm == "slack_eliminated"
    discovery = PushProblem(base.simulator, base.initial_state, base.task,
                            stage_cost(settings, base.weights, True, settings.stages.discovery.reach_weight, reach,
                                       limits.joint_speed_weight, limits.joint_position_weight,
                                       base.weights.w5 if eliminated else 0.0),
                            base.derivative_settings, base.position_scale_min_m)
    executor = physical_twin(discovery, discovery.cost)
    run = StartRun(clock, prefix, stop, settings.stages.ipopt_curvature)
    best = None  # (executed, torques, status)
    if not discovered:
        script = settings.stages.scripted
        path = None if fraction is None else side_joint_path(executor, script, fraction.face, fraction.tilt_rad,
                                                             fraction.offset_scale)
        torques = scripted_torques(executor, script, settings.tracking, path)
        touch = touch_profile(executor, executor.with_torques(torques), settings.stages.touch_force_N)
        setup_s = time.perf_counter() - began
    else:
        setup_s = time.perf_counter() - began
        stage, executed = run.stage(discovery, settings.stages.solver, discovery.initial_guess, discovery.lower,
                                    discovery.upper, "discovery", settings.stages.discovery.max_iter, executor)
        planned_z = stage.z
        best = (executed, discovery.split(stage.z)[0], stage.status)
        began = time.perf_counter()
        touch = touch_profile(discovery, planned_z, settings.stages.touch_force_N)
        setup_s += time.perf_counter() - began
        torques = best[1]
    for index, spec in enumerate(settings.stages.physical):
        if run.interrupted:
            break
        if spec.only_if_beyond_limits and not best[0].rank(settings)[0]:  # rank[0]: beyond the arm's limits
            continue
        began = time.perf_counter()  # posing a stage's problem is setup, as the discovery's is
        problem = physical_twin(discovery, stage_cost(settings, base.weights, False, spec.contact_weight, touch,
                                                      spec.joint_speed_weight, spec.joint_position_weight))
        setup_s += time.perf_counter() - began
        stage, result = run.stage(problem, settings.stages.solver, problem.with_torques(torques),
                                    problem.lower, problem.upper, f"physical {index + 1}", spec.max_iter, executor)
        torques = problem.split(stage.z)[0]
        if best is None or result.rank(settings) < best[0].rank(settings):
            best = (result, torques, stage.status)
        if result.reaches(settings, executor.task):
            break
    executed, chosen, status = best
    if not discovered:  # no discovery: the plan under the contact model is the returned torques
        planned_z = discovery.with_torques(chosen)
    return executed, Outcome(discovery, planned_z, chosen, executor, run.interrupted or status, tuple(run.log),
                             tuple(run.records), clock.elapsed(), setup_s)
