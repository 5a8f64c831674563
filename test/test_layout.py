"""The package's folders are its layers: a module imports only from its own layer and those below it,
only the ROS layer and the CLI talk to ROS, and no module grows past 400 lines."""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "cito_ros"
# bottom to top; ros and studies stand side by side on the execution layer and do not import each other
RANK = {"settings": 0, "model": 1, "planner": 2, "execution": 3, "ros": 4, "studies": 4, "cli": 5}
ROS_MODULES = ("rclpy", "cito_msgs", "builtin_interfaces", "geometry_msgs", "nav_msgs", "sensor_msgs", "std_msgs",
               "trajectory_msgs", "visualization_msgs", "action_msgs", "rcl_interfaces")
MODULES = sorted(p for p in PACKAGE.rglob("*.py") if p.parent != PACKAGE)


def layer(path: Path) -> str:
    return path.relative_to(PACKAGE).parts[0]


def imported(path: Path) -> list[str]:
    """Every module `path` imports, at any depth of its code, as dotted names."""
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names += [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
    return names


def test_every_module_is_in_a_layer_folder():
    assert {layer(p) for p in MODULES} <= set(RANK)
    assert [p.name for p in PACKAGE.glob("*.py")] == ["__init__.py"]


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_go_only_downward(path):
    own = layer(path)
    for name in imported(path):
        parts = name.split(".")
        if parts[0] != "cito_ros" or len(parts) < 2 or parts[1] not in RANK:
            continue
        other = parts[1]
        assert other == own or RANK[other] < RANK[own], f"{path.relative_to(ROOT)} imports {name}"


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_only_the_ros_layer_and_the_cli_talk_to_ros(path):
    if layer(path) in ("ros", "cli"):
        return
    assert not [name for name in imported(path) if name.split(".")[0] in ROS_MODULES]


def test_no_module_is_longer_than_400_lines():
    long = {str(p.relative_to(ROOT)): n for p in [*PACKAGE.rglob("*.py"), *(ROOT / "test").rglob("*.py")]
            if (n := len(p.read_text().splitlines())) > 400}
    assert not long
