"""The solvers' settings and the derivatives' (the linearization behind every gradient)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from cito_ros.settings.typed_config import setting


def _options(value: Any, name: str) -> tuple[tuple[str, Any], ...]:
    if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
        raise ValueError(f"{name} must be a section of option names and values, got {value!r}")
    return tuple(value.items())


SWITCHES = ("every", "ends")  # gradient.switches and executor.replan_switches


@dataclass(frozen=True)
class DerivativeSettings:
    method: str = setting("adjoint (per-step linearization) or forward_differences (knot restarts)",
                          choices=("adjoint", "forward_differences"))
    epsilon: float = setting("finite-difference step of the per-step linearization", positive=True)
    restart_step: float = setting("knot-restart difference step, relative to the variable scale", positive=True)
    threads: int = setting("linearization threads, one mjData each", minimum=1)
    stride: int = setting("every stride-th step linearized, the steps between taking the Jacobians of the one "
                          "before (1: every step)", minimum=1)
    switches: str = setting("with a stride, also linearized where the plate's contact with the object begins or "
                            "ends: at every such step (every), or only where it first begins and last ends (ends: "
                            "a plate chattering on a face switches at a third of the steps)",
                            choices=SWITCHES)


@dataclass(frozen=True)
class SolverSettings:
    max_iter: int = setting("IPOPT iterations per stage", minimum=1)
    time_limit_s: float = setting("wall clock of the whole solve, checked every iteration (s)", positive=True)
    iteration_budget: int = setting("iterations of the whole solve, over all its stages and starts (0: none): "
                                    "unlike the time limit, where it stops does not hang on the machine's load",
                                    minimum=0)
    stall_iterations: int = setting("stop when the best cost improved by less than stall_tolerance over this "
                                    "many iterations", minimum=1)
    stall_tolerance: float = setting("relative cost improvement below which the solve has stalled", minimum=0.0)
    restarts: int = setting("re-solves from the best point when the first ends short of the task", minimum=0)
    scale_variables: bool = setting("IPOPT sees z / scale (torque limits, k_max, gamma_max, slack_max)")
    ipopt: tuple[tuple[str, Any], ...] = setting("options passed to IPOPT as they are", convert=_options,
                                                 unconvert=dict)
    least_squares: tuple[tuple[str, Any], ...] = setting("options passed to mujoco.minimize.least_squares as "
                                                         "they are", convert=_options, unconvert=dict)
    ilqr: tuple[tuple[str, Any], ...] = setting("iLQR: mu_initial, mu_min, mu_max, mu_factor, step_lengths, "
                                                "accept_ratio, tolerance", convert=_options, unconvert=dict)

    @property
    def ipopt_options(self) -> dict[str, Any]:
        return dict(self.ipopt)

    @property
    def least_squares_options(self) -> dict[str, Any]:
        return dict(self.least_squares)

    @property
    def ilqr_options(self) -> dict[str, Any]:
        return dict(self.ilqr)
