"""The three contact models of the paper, each a small unit behind one interface.

A contact model decides how the virtual normal force gamma (N) between the two
contact candidates is produced. In simulation it is always the force of one
MuJoCo actuator, `virtual_contact`, whose transmission (built by the scene)
applies +gamma along the object's inward face normal at the object candidate
and the reaction at the robot candidate. What differs is the actuator's
control and law:

- SCM:  control = k, fixed;                gamma = k exp(-(c/k) phi)   (native plugin)
- VSCM: control = k_l, one per knot;       gamma = k exp(-(c/k) phi)   (native plugin), 0 at k = 0
- CCCM: control = gamma_l, one per knot;   gamma = control              (plain MuJoCo force actuator)

Parameters (k, c, bounds) come from the typed settings (config/planner.yaml);
nothing here is a literal default.
"""
from __future__ import annotations

import abc
import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import mujoco
import numpy as np

from cito_ros.settings import ContactModelsSettings, Weights
from cito_ros.settings.typed_config import require_finite

CONTACT_PLUGIN = "cito.virtual_contact"


@dataclass(frozen=True)
class KnotVariable:
    """A decision variable a contact model adds at every knot (besides the 7 torques)."""

    name: str
    lower: float
    upper: float
    initial: float
    scale: float  # typical magnitude, for the optimizer's variable scaling


@dataclass(frozen=True)
class KnotConstraints:
    """Constraints g(phi_l, v_l) at each knot l, with lower <= g <= upper.

    phi_l is the knot's mean signed distance (a function of all earlier decisions
    through the dynamics), v_l the model's knot variables.
    """

    values: np.ndarray        # (N, m)
    d_phi: np.ndarray         # (N, m)       dg/dphi_l
    d_variables: np.ndarray   # (N, m, n_var) dg/dv_l
    lower: np.ndarray         # (m,)
    upper: np.ndarray         # (m,)
    names: tuple[str, ...]    # (m,)


class ContactModel(abc.ABC):
    """Interface of a contact model (see the module docstring)."""

    name: ClassVar[str]
    description: ClassVar[str]
    #: Meaning of the contact actuator's control, with its unit.
    control_name: ClassVar[str]

    @abc.abstractmethod
    def control_range(self) -> tuple[float, float]:
        """Admissible range of the contact actuator's control."""

    @abc.abstractmethod
    def default_control(self) -> float:
        """Contact control used when a caller gives none (and the optimizer's start)."""

    @abc.abstractmethod
    def gamma(self, signed_distance_m: np.ndarray, control: np.ndarray) -> np.ndarray:
        """Virtual normal force (N): the pure-Python law, the oracle of the native one."""

    @abc.abstractmethod
    def configure_actuator(self, spec: mujoco.MjSpec, actuator: mujoco.MjsActuator) -> None:
        """Make the (already placed) contact actuator compute this model's gamma natively."""

    def stiffness(self, control: np.ndarray) -> np.ndarray | None:
        """Stiffness k (N) per entry of `control`, or None for a model without one."""
        return None

    # ---------------------------------------------------------------- optimization

    #: Names of the decision variables this model adds at every knot.
    variable_names: ClassVar[tuple[str, ...]] = ()
    #: Those variables with their bounds (set per instance from its parameters).
    knot_variables: tuple[KnotVariable, ...] = ()
    #: Index in knot_variables of the variable that is the contact control, or None (fixed control).
    control_variable: ClassVar[int | None] = None
    #: Index in knot_variables of a complementarity slack, or None (no complementarity constraints).
    slack_variable: ClassVar[int | None] = None

    def contact_control(self, variables: np.ndarray) -> np.ndarray:
        """Contact control per knot from the (N, n_var) knot variables."""
        if self.control_variable is None:
            return np.full(variables.shape[0], self.default_control())
        return variables[:, self.control_variable]

    def variable_residuals(self, variables: np.ndarray, weights: Weights) -> tuple[np.ndarray, np.ndarray]:
        """Residuals of the cost terms on the knot variables alone (their squares are the cost), (k,),
        and their derivatives with respect to the (N, n_var) variables, (k, N, n_var)."""
        return np.zeros(0), np.zeros((0, *variables.shape))

    def knot_constraints(self, mean_signed_distance_m: np.ndarray, variables: np.ndarray) -> KnotConstraints:
        """Constraints per knot (none by default)."""
        n = variables.shape[0]
        return KnotConstraints(np.zeros((n, 0)), np.zeros((n, 0)), np.zeros((n, 0, variables.shape[1])),
                               np.zeros(0), np.zeros(0), ())

    def validate_control(self, control: np.ndarray) -> np.ndarray:
        """`control` as a float array, or a ValueError saying what is wrong with it."""
        control = np.asarray(control, dtype=float)
        if not np.all(np.isfinite(control)):
            raise ValueError(f"{self.name}: {self.control_name} contains NaN or Inf")
        if np.any(control < 0):
            raise ValueError(f"{self.name}: {self.control_name} must be non-negative, got {control[control < 0][0]}")
        low, high = self.control_range()
        outside = (control < low) | (control > high)
        if np.any(outside):
            raise ValueError(self._out_of_range(control[outside][0]))
        return control

    def _out_of_range(self, value: float) -> str:
        low, high = self.control_range()
        return f"{self.name}: {self.control_name} must lie in [{low}, {high}], got {value}"

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name})"


class _ExponentialLaw(ContactModel):
    """gamma = k exp(-(c/k) phi), computed natively by the cito.virtual_contact plugin."""

    def __init__(self, curvature: float):
        self.curvature = require_finite(f"{self.name}: curvature", curvature, positive=True)

    def gamma(self, signed_distance_m, control):
        phi = np.asarray(signed_distance_m, dtype=float)
        k = np.asarray(control, dtype=float)
        positive = k > 0
        safe_k = np.where(positive, k, 1.0)
        return np.where(positive, k * np.exp(-(self.curvature / safe_k) * phi), 0.0)

    def stiffness(self, control):
        return np.asarray(control, dtype=float)

    def configure_actuator(self, spec, actuator):
        spec.activate_plugin(CONTACT_PLUGIN)
        instance = spec.add_plugin(name=f"{self.name}_contact_law", plugin_name=CONTACT_PLUGIN, active=True)
        instance.config = {"curvature": repr(self.curvature)}
        actuator.plugin = instance


class SmoothContactModel(_ExponentialLaw):
    name = "scm"
    description = "smooth contact model, fixed stiffness"
    control_name = "stiffness k (N)"

    def __init__(self, stiffness: float, curvature: float):
        super().__init__(curvature)
        self.fixed_stiffness = require_finite("scm: stiffness", stiffness, positive=True)

    def control_range(self):
        return (self.fixed_stiffness, self.fixed_stiffness)

    def default_control(self):
        return self.fixed_stiffness

    def _out_of_range(self, value):
        return (f"scm: the stiffness is fixed at k = {self.fixed_stiffness} N (config), got {value}; "
                "use vscm to vary it per knot")


class VariableSmoothContactModel(_ExponentialLaw):
    name = "vscm"
    description = "variable smooth contact model, stiffness per knot"
    control_name = "stiffness k (N)"
    control_variable = 0
    variable_names = ("stiffness_N",)

    def __init__(self, stiffness_max: float, stiffness_initial: float, curvature: float):
        super().__init__(curvature)
        self.stiffness_max = require_finite("vscm: stiffness_max", stiffness_max, positive=True)
        self.stiffness_initial = require_finite("vscm: stiffness_initial", stiffness_initial, nonnegative=True)
        if self.stiffness_initial > self.stiffness_max:
            raise ValueError(f"vscm: stiffness_initial {self.stiffness_initial} exceeds stiffness_max {self.stiffness_max}")
        self.knot_variables = (KnotVariable(self.variable_names[0], 0.0, self.stiffness_max, self.stiffness_initial,
                                            self.stiffness_max),)

    def control_range(self):
        return (0.0, self.stiffness_max)

    def default_control(self):
        return self.stiffness_initial


class ComplementarityContactModel(ContactModel):
    """gamma_l and a slack s_l per knot; constraints (11)-(12) of the paper:
    phi_l >= 0, gamma_l >= 0, s_l >= 0, phi_l gamma_l <= s_l; cost w5 sum s_l^2."""

    name = "cccm"
    description = "relaxed complementarity constraints, force per knot"
    control_name = "normal force gamma (N)"
    control_variable = 0
    slack_variable = 1
    variable_names = ("gamma_N", "slack_Nm")

    def __init__(self, force_max: float, slack_max: float):
        self.force_max = require_finite("cccm: force_max", force_max, positive=True)
        self.slack_max = require_finite("cccm: slack_max", slack_max, positive=True)
        self.knot_variables = (KnotVariable("gamma_N", 0.0, self.force_max, 0.0, self.force_max),
                               KnotVariable("slack_Nm", 0.0, self.slack_max, 0.0, self.slack_max))

    def control_range(self):
        return (0.0, self.force_max)

    def default_control(self):
        return 0.0

    def gamma(self, signed_distance_m, control):
        return np.broadcast_to(np.asarray(control, dtype=float), np.shape(signed_distance_m)).copy()

    def configure_actuator(self, spec, actuator):
        # A plain MuJoCo force actuator: force = gain * ctrl with gain 1 (the default).
        del spec, actuator

    def variable_residuals(self, variables, weights):
        root = np.sqrt(weights.w5)
        n = variables.shape[0]
        jacobian = np.zeros((n, *variables.shape))
        jacobian[np.arange(n), np.arange(n), 1] = root
        return root * variables[:, 1], jacobian

    def knot_constraints(self, mean_signed_distance_m, variables):
        phi, gamma, slack = mean_signed_distance_m, variables[:, 0], variables[:, 1]
        n = len(phi)
        d_variables = np.zeros((n, 2, 2))
        d_variables[:, 1, 0] = phi      # d(phi gamma - s)/d gamma
        d_variables[:, 1, 1] = -1.0     # d(phi gamma - s)/d s
        return KnotConstraints(
            values=np.stack([phi, phi * gamma - slack], axis=1),
            d_phi=np.stack([np.ones(n), gamma], axis=1),
            d_variables=d_variables,
            lower=np.array([0.0, -np.inf]),
            upper=np.array([np.inf, 0.0]),
            names=("signed_distance", "complementarity"),
        )


CONTACT_MODELS: dict[str, type[ContactModel]] = {
    cls.name: cls for cls in (ComplementarityContactModel, SmoothContactModel, VariableSmoothContactModel)
}


def contact_model(name: str, settings: ContactModelsSettings) -> ContactModel:
    """The contact model `name` ('cccm', 'scm' or 'vscm') with its parameters from the settings."""
    if not isinstance(name, str) or name.lower() not in CONTACT_MODELS:
        raise ValueError(f"unknown contact model {name!r}; choose one of {sorted(CONTACT_MODELS)}")
    name = name.lower()
    return CONTACT_MODELS[name](**dataclasses.asdict(getattr(settings, name)))
