"""Where the package's models and config files live.

From a source checkout (or an editable install) they are the repository's
`models/` and `config/`; from an installed package (pip or colcon) they are in
`<prefix>/share/cito_ros/`, found through ament_index when AMENT_PREFIX_PATH is
set and through the interpreter prefix otherwise.
"""
from __future__ import annotations

import functools
import os
import sys
from pathlib import Path
from typing import Any

import yaml

PACKAGE = "cito_ros"


@functools.cache
def share_dir() -> Path:
    """Directory holding `models/` and `config/`."""
    candidates = [Path(__file__).resolve().parents[2]]  # the checkout: cito_ros/settings/paths.py
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory(PACKAGE)))
    except Exception:  # ament_index missing or package not registered: use the prefix
        pass
    candidates += [Path(sys.prefix) / "share" / PACKAGE, Path(os.environ.get("CITO_SHARE", "/nonexistent"))]
    for candidate in candidates:
        if (candidate / "models").is_dir() and (candidate / "config").is_dir():
            return candidate
    raise FileNotFoundError(f"cannot find the {PACKAGE} models/ and config/ folders (looked in {candidates})")


def model_path(name: str) -> Path:
    return share_dir() / "models" / name


def config_path(name: str) -> Path:
    return share_dir() / "config" / name


def cache_path(name: str) -> Path:
    """A file in the user's cache for this package ($XDG_CACHE_HOME, else ~/.cache): computed once per machine."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / PACKAGE / name


def read_yaml(path: str | Path) -> Any:
    """A YAML file's document, parsed by libyaml where PyYAML has it (the same document as yaml.safe_load, in a
    tenth of the time: a one-shot cito-plan's refusal spent 0.1 s parsing config/planner.yaml)."""
    with open(path, encoding="utf-8") as stream:
        return yaml.load(stream, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
