"""The contact models' parameters and the cost weights of eqs. (8)-(10), per contact model."""
from __future__ import annotations

from dataclasses import dataclass

from cito_ros.settings.typed_config import setting

CONTACT_MODEL_NAMES = ("cccm", "scm", "vscm")


@dataclass(frozen=True)
class ScmSettings:
    stiffness: float = setting("k (N), fixed", positive=True)
    curvature: float = setting("c (N/m); alpha = c / k", positive=True)


@dataclass(frozen=True)
class VscmSettings:
    stiffness_max: float = setting("upper bound of k per knot (N)", positive=True)
    stiffness_initial: float = setting("k per knot at the optimizer's start (N)", minimum=0.0)
    curvature: float = setting("c (N/m)", positive=True)

    def check(self, path: str) -> None:
        if self.stiffness_initial > self.stiffness_max:
            raise ValueError(f"{path}.stiffness_initial {self.stiffness_initial} exceeds "
                             f"{path}.stiffness_max {self.stiffness_max}")


@dataclass(frozen=True)
class CccmSettings:
    force_max: float = setting("upper bound of gamma per knot (N)", positive=True)
    slack_max: float = setting("upper bound of the complementarity slack s per knot (N m)", positive=True)


@dataclass(frozen=True)
class ContactModelsSettings:
    cccm: CccmSettings = setting("relaxed complementarity constraints, force per knot")
    scm: ScmSettings = setting("smooth contact model, gamma = k exp(-(c/k) phi), k fixed")
    vscm: VscmSettings = setting("variable smooth contact model, k per knot in [0, stiffness_max]")


@dataclass(frozen=True)
class Weights:
    """Cost weights of eqs. (8)-(10); w5 (the CCCM slack) only where the model has slack."""

    w1: float = setting("final position", minimum=0.0)
    w2: float = setting("final orientation", minimum=0.0)
    w3: float = setting("end-effector speed squared", minimum=0.0)
    w4: float = setting("virtual force squared", minimum=0.0)
    w5: float | None = setting("complementarity slack squared (CCCM)", minimum=0.0)


@dataclass(frozen=True)
class WeightsSettings:
    cccm: Weights = setting("CCCM cost weights")
    scm: Weights = setting("SCM cost weights")
    vscm: Weights = setting("VSCM cost weights")

    def check(self, path: str) -> None:
        if self.cccm.w5 is None:
            raise ValueError(f"{path}.cccm.w5: missing (CCCM's slack weight)")
