"""Reaches computed once per machine: the arm's push, steady push and pull reaches (Scene.push_reach_m,
cito_ros.planner.push_limits) are searches of a second or so each, and a planning process's start, or a one-shot
cito-plan's refusal, need not pay them (builder.warm_up). ROS-free.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import mujoco

from cito_ros.settings import SceneConfig
from cito_ros.settings.paths import cache_path, model_path

if TYPE_CHECKING:
    from cito_ros.model.scene import Scene

# (kind, scene without the object's pose) -> reach: a reach depends on the arm, the object's size and the scene's
# contact parameters, not on where the object stands (its slide there is under a millimetre)
_REACHES: dict[tuple[str, SceneConfig], float] = {}


def cached(kind: str, scene: Scene, compute: Callable[[], float], *sources: Path) -> float:
    """compute()'s reach of `kind` for the scene, its object's pose aside: kept in this process and in the user's
    cache ($XDG_CACHE_HOME or ~/.cache, cito_ros/reach.json), whose entry is named by a hash of the scene's
    description, MuJoCo's version, the model files and `sources` (the code that builds the scene and computes the
    reach), so that a change in any of them computes it again. An unreadable or unwritable file is computed past:
    the cache only saves time."""
    config = scene.config.object_pose_aside
    if (kind, config) in _REACHES:
        return _REACHES[(kind, config)]
    digest = hashlib.sha256(f"{kind} {mujoco.__version__} {dataclasses.replace(config, source='')!r}".encode())
    for path in [*sorted(model_path(config.model).parent.glob("*.xml")), *sources]:
        digest.update(path.read_bytes())
    entry, path = digest.hexdigest(), cache_path("reach.json")
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        stored = {}
    stored = stored if isinstance(stored, dict) else {}
    reach = stored.get(entry)
    if not isinstance(reach, float):
        reach = compute()
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            partial = path.with_suffix(f".{os.getpid()}.tmp")
            partial.write_text(json.dumps({**stored, entry: reach}))
            os.replace(partial, path)  # whole or not at all for a process that reads it meanwhile
        except OSError:
            pass
    _REACHES[(kind, config)] = reach
    return reach
