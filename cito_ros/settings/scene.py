"""Scene descriptions (config/scenes/*.yaml): the model file and what is applied on top of it."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from cito_ros.settings.paths import config_path, read_yaml
from cito_ros.settings.typed_config import parse, setting

DEFAULT_SCENE = "default"


@dataclass(frozen=True)
class ObjectConfig:
    half_size_m: float = setting("cube half edge (m)", positive=True)
    mass_kg: float = setting("cube mass (kg)", positive=True)
    position_m: tuple[float, ...] = setting("cube centre x, y (m, world); z follows from the table top")
    yaw_rad: float = setting("cube yaw about world z (rad)")
    friction: float = setting("sliding friction of every pair involving the cube", minimum=0.0)

    def check(self, path: str) -> None:
        if len(self.position_m) != 2:
            raise ValueError(f"{path}.position_m must be [x, y], got {list(self.position_m)}")


@dataclass(frozen=True)
class SceneConfig:
    """A push scene: the model file and what is applied on top of it.

    `config/scenes/default.yaml` gives every field; any other scene file gives only what it
    changes, applied over the default scene, so every scene default lives in that one file.
    """

    description: str = setting("what the scene is")
    model: str = setting("model file in models/")
    timestep_s: float = setting("simulation timestep (s)", positive=True)
    object: ObjectConfig = setting("the object to push")
    collisions: str = setting("minimal: the model's pair list (or `pairs`); all: every geom pair",
                              choices=("minimal", "all"))
    pairs: tuple[tuple[str, ...], ...] | None = setting("the collision pairs instead of the model's, as "
                                                        "[geom, geom] names (collisions: minimal only)")
    source: str = field(default="", compare=False, metadata={"internal": True})  # the name or path loaded

    def check(self, path: str) -> None:
        if self.pairs is not None and (self.collisions != "minimal" or any(len(p) != 2 for p in self.pairs)):
            raise ValueError("pairs must be a list of [geom, geom] names, with collisions: minimal")

    @property
    def name(self) -> str:
        return Path(self.source).stem

    @property
    def object_pose_aside(self) -> "SceneConfig":
        """This scene with its object at the origin unturned: a key for what depends on the scene but not on
        where its object stands (the steady push reach, the marker template)."""
        return dataclasses.replace(self, object=dataclasses.replace(self.object, position_m=(0.0, 0.0), yaw_rad=0.0))

    def with_object_scaled(self, friction_scale: float, mass_scale: float) -> "SceneConfig":
        """This scene with its object's friction and mass scaled: a world that is not the model."""
        obj = self.object
        return dataclasses.replace(self, object=dataclasses.replace(
            obj, friction=obj.friction * friction_scale, mass_kg=obj.mass_kg * mass_scale))

    @classmethod
    def load(cls, name_or_path: str | Path = DEFAULT_SCENE) -> "SceneConfig":
        """Load `config/scenes/<name>.yaml`, or a YAML file given by path."""
        path = Path(name_or_path)
        if path.suffix not in (".yaml", ".yml"):
            path = config_path("scenes") / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ValueError(f"unknown scene {str(name_or_path)!r}: {path} does not exist")
        raw = read_yaml(path) or {}
        return cls.from_mapping(path.stem, raw, source=str(name_or_path))

    @classmethod
    def from_mapping(cls, name: str, raw: Mapping[str, Any], source: str | None = None) -> "SceneConfig":
        """A scene from its description, applied over the default scene's."""
        tree = raw
        if name != DEFAULT_SCENE:
            tree = _merged(read_yaml(config_path("scenes") / f"{DEFAULT_SCENE}.yaml"), raw)
        try:
            scene = parse(cls, tree, "")
        except ValueError as error:
            raise ValueError(f"scene {name}: {error}") from None
        return dataclasses.replace(scene, source=name if source is None else source)


def _merged(base: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    tree = dict(base)
    for key, value in changes.items():
        tree[key] = _merged(base[key], value) if isinstance(value, Mapping) and isinstance(base.get(key), Mapping) \
            else value
    return tree
