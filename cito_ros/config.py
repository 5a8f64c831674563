"""Parameters from `config/`: the planner parameters (ROS params-file format)
and the scene descriptions. Values live in YAML, not in code."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import yaml

from cito_ros.paths import config_path

PLANNER_FILE = "planner.yaml"


def load_parameters(path: str | Path | None = None) -> dict[str, Any]:
    """Return the nested `ros__parameters` mapping of a params file.

    The file may address the node by name or with the `/**` wildcard; the first
    entry that has `ros__parameters` is used.
    """
    path = Path(path) if path is not None else config_path(PLANNER_FILE)
    with open(path, encoding="utf-8") as stream:
        document = yaml.safe_load(stream)
    if isinstance(document, Mapping):
        for entry in document.values():
            if isinstance(entry, Mapping) and isinstance(entry.get("ros__parameters"), Mapping):
                return dict(entry["ros__parameters"])
    raise ValueError(f"{path}: no '<node>: ros__parameters:' section found")


def require_finite(name: str, value: Any, *, positive: bool = False, nonnegative: bool = False) -> float:
    """`value` as a float, or a ValueError naming `name` and what is wrong."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ValueError(f"{name} must be finite, got {number}")
    if positive and number <= 0:
        raise ValueError(f"{name} must be positive, got {number}")
    if nonnegative and number < 0:
        raise ValueError(f"{name} must be non-negative, got {number}")
    return number


@dataclass(frozen=True)
class ObjectConfig:
    half_size_m: float
    mass_kg: float
    position_m: tuple[float, float]
    yaw_rad: float
    friction: float


@dataclass(frozen=True)
class SceneConfig:
    """A push scene: the model file and what is applied on top of it."""

    name: str
    description: str
    model: str
    timestep_s: float
    object: ObjectConfig
    collisions: str  # "minimal" (a pair list) or "all" (every geom pair)
    pairs: tuple[tuple[str, str], ...] | None = None  # the pair list instead of the model's (minimal only)

    COLLISION_MODES = ("minimal", "all")

    @classmethod
    def load(cls, name_or_path: str | Path = "default") -> "SceneConfig":
        """Load `config/scenes/<name>.yaml`, or a YAML file given by path."""
        path = Path(name_or_path)
        if path.suffix not in (".yaml", ".yml"):
            path = config_path("scenes") / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ValueError(f"unknown scene {str(name_or_path)!r}: {path} does not exist")
        with open(path, encoding="utf-8") as stream:
            raw = yaml.safe_load(stream) or {}
        return cls.from_mapping(path.stem, raw)

    @classmethod
    def from_mapping(cls, name: str, raw: Mapping[str, Any]) -> "SceneConfig":
        obj = raw.get("object", {})
        position = obj.get("position_m", [0.99, 0.0])
        if not isinstance(position, (list, tuple)) or len(position) != 2:
            raise ValueError(f"scene {name}: object.position_m must be [x, y], got {position!r}")
        collisions = raw.get("collisions", "minimal")
        if collisions not in cls.COLLISION_MODES:
            raise ValueError(f"scene {name}: collisions must be one of {cls.COLLISION_MODES}, got {collisions!r}")
        pairs = raw.get("pairs")
        if pairs is not None:
            if collisions != "minimal" or not isinstance(pairs, list) or not all(
                    isinstance(p, (list, tuple)) and len(p) == 2 and all(isinstance(g, str) for g in p) for p in pairs):
                raise ValueError(f"scene {name}: pairs must be a list of [geom, geom] names, with collisions: minimal")
            pairs = tuple((a, b) for a, b in pairs)
        return cls(
            name=name,
            description=str(raw.get("description", "")),
            model=str(raw.get("model", "push_scene.xml")),
            timestep_s=require_finite(f"scene {name}: timestep_s", raw.get("timestep_s", 0.005), positive=True),
            object=ObjectConfig(
                half_size_m=require_finite(f"scene {name}: object.half_size_m", obj.get("half_size_m", 0.075), positive=True),
                mass_kg=require_finite(f"scene {name}: object.mass_kg", obj.get("mass_kg", 0.155), positive=True),
                position_m=tuple(require_finite(f"scene {name}: object.position_m", v) for v in position),
                yaw_rad=require_finite(f"scene {name}: object.yaw_rad", obj.get("yaw_rad", 0.0)),
                friction=require_finite(f"scene {name}: object.friction", obj.get("friction", 0.5), nonnegative=True),
            ),
            collisions=collisions,
            pairs=pairs,
        )
