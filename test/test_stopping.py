"""How a solve stops: the wall-clock limit honoured by the IterationMonitor, on a clock the test drives."""
import dataclasses

from cito_ros.planner.results import Status
from cito_ros.planner.solvers.base import IterationMonitor


def test_no_iteration_is_begun_that_the_time_left_does_not_cover(settings):
    """On a clock of whole seconds with a 10 s limit: iterations of 1 s go on while one more ends by the limit,
    and the stage stops at 10 s (checked only after each iteration, it ran on to 11 s), at 9 s where it needs 1 s
    after its last (executing its plan); a stage that starts at 8 s after an earlier stage's iterations of 3 s does
    not begin one."""
    now = [0.0]
    solver_settings = dataclasses.replace(settings.solver, time_limit_s=10.0)
    monitor = IterationMonitor(solver_settings, 0.0, 0, 0.0, None, None, clock=lambda: now[0])
    stops = []
    for iteration in range(12):
        now[0] = float(iteration)
        stops.append(monitor.record(iteration, 1.0 / (1 + iteration), 0.0, None, 0.0))
    assert stops.index(Status.TIME_LIMIT) == 10 and stops[:10] == [None] * 10
    reserved = IterationMonitor(solver_settings, 0.0, 0, 0.0, None, None, reserve_s=1.0, clock=lambda: now[0])
    for iteration in range(10):
        now[0] = float(iteration)
        if reserved.record(iteration, 1.0 / (1 + iteration), 0.0, None, 0.0) is not None:
            break
    assert now[0] == 9.0
    now[0] = 8.0
    later = IterationMonitor(solver_settings, 0.0, 0, 0.0, None, None, iteration_s=3.0, clock=lambda: now[0])
    assert later.record(0, 1.0, 0.0, None, 0.0) is Status.TIME_LIMIT
