"""The push problem: `PushProblem` (problem.py), put together from its decision layout and bounds
(layout.py), its residuals and stage costs (residuals.py) and its derivatives (derivatives.py, over the
per-step linearizations of rollout_derivatives.py)."""
from cito_ros.planner.problem.derivatives import KnotExpansion
from cito_ros.planner.problem.problem import CACHED_EVALUATIONS, Evaluation, PushProblem
from cito_ros.planner.problem.residuals import StageCost

__all__ = ["CACHED_EVALUATIONS", "Evaluation", "KnotExpansion", "PushProblem", "StageCost"]
