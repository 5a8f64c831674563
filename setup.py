"""cito_ros: contact-implicit trajectory optimization for pushing, as a ROS 2 package.

Installs as an ament_python package (colcon) and as a plain pip package. The
native MuJoCo engine plugins (cito_ros/model/native) compile against the headers and
library shipped in the `mujoco` wheel, which must be importable at build time
(`pip install --no-build-isolation`).
"""
import glob
import os

from setuptools import Extension, find_packages, setup

PACKAGE = "cito_ros"


def mujoco_extension() -> Extension:
    import mujoco  # build-time dependency: headers and libmujoco come from the wheel

    mujoco_dir = os.path.dirname(mujoco.__file__)
    libraries = sorted(glob.glob(os.path.join(mujoco_dir, "libmujoco.so*")))
    if not libraries:
        raise RuntimeError(f"libmujoco.so not found next to {mujoco.__file__}")
    return Extension(
        f"{PACKAGE}.model._native",
        sources=sorted(glob.glob("cito_ros/model/native/*.c")),
        depends=sorted(glob.glob("cito_ros/model/native/*.h")),
        include_dirs=[os.path.join(mujoco_dir, "include")],
        extra_compile_args=["-O2", "-std=c11", "-Wall", "-Wextra", "-Werror"],
        # Link the wheel's libmujoco by path; the rpaths find it for an installed
        # package ($ORIGIN/../mujoco) and for an in-place (editable) build.
        extra_link_args=[libraries[0], "-lpthread", f"-Wl,-rpath,$ORIGIN/../mujoco,-rpath,{mujoco_dir}"],
    )


def share(subdir: str, pattern: str):
    return (f"share/{PACKAGE}/{subdir}", sorted(glob.glob(os.path.join(subdir, pattern))))


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    ext_modules=[mujoco_extension()],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        share("config", "*.yaml"),
        share("models", "*.xml"),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="cito_ros developers",
    maintainer_email="cito-ros@example.invalid",
    description="Contact-implicit trajectory optimization for pushing (CCCM, SCM, VSCM) as a ROS 2 service",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "cito-scene = cito_ros.cli.scene:main",
            "cito-bench = cito_ros.cli.bench:main",
            "cito-plan = cito_ros.cli.plan:main",
            "cito-planner-node = cito_ros.ros.node:main",
            "cito-demo = cito_ros.cli.demo:main",
            "cito-executor-node = cito_ros.ros.executor_node:main",
            "cito-sim-robot = cito_ros.ros.sim_robot:main",
            "planner_node = cito_ros.ros.node:main",
        ],
    },
)
