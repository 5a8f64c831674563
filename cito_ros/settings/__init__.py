"""Every planner setting, read once into typed, frozen, validated dataclasses.

`load_settings()` reads `config/planner.yaml` (the ROS params-file the node
loads too); `Settings.from_mapping` takes the same tree from anywhere else (the
node's parameters). Every value comes from that file: the dataclasses have no
defaults of their own, a missing or unknown parameter is an error, and every
bad value is reported with its dotted name before anything is solved. Below
these entry points nothing reads a raw parameter dict.

Each field's metadata carries its description and admissible range, which the
validation here and the ROS parameter descriptors share. One module per section:
`scene`, `contact` (contact models and weights), `stages`, `execution` (limits and
tracking), `solver` (solvers and derivatives) and `planner` (the whole, and loading).
"""
from cito_ros.settings.contact import (
                                       CONTACT_MODEL_NAMES,
                                       CccmSettings,
                                       ContactModelsSettings,
                                       ScmSettings,
                                       VscmSettings,
                                       Weights,
                                       WeightsSettings,
)
from cito_ros.settings.execution import ExecutorSettings, LimitSettings, TrackingSettings
from cito_ros.settings.planner import (
                                       PLANNER_FILE,
                                       HorizonSettings,
                                       NodeSettings,
                                       Settings,
                                       TaskSettings,
                                       load_parameters,
                                       load_settings,
)
from cito_ros.settings.scene import DEFAULT_SCENE, ObjectConfig, SceneConfig
from cito_ros.settings.solver import DerivativeSettings, SolverSettings
from cito_ros.settings.stages import (
                                       IPOPT_CURVATURES,
                                       DiscoverySettings,
                                       PhysicalStage,
                                       PhysicalStages,
                                       ScriptedSettings,
                                       ScriptVariants,
                                       SideFaceSettings,
                                       StagesSettings,
)

__all__ = ["CONTACT_MODEL_NAMES", "CccmSettings", "ContactModelsSettings", "ScmSettings", "VscmSettings", "Weights",
           "WeightsSettings", "ExecutorSettings", "LimitSettings", "TrackingSettings", "PLANNER_FILE", "HorizonSettings", "NodeSettings",
           "Settings", "TaskSettings", "load_parameters", "load_settings", "DEFAULT_SCENE", "ObjectConfig",
           "SceneConfig", "DerivativeSettings", "SolverSettings", "IPOPT_CURVATURES", "DiscoverySettings",
           "PhysicalStage", "PhysicalStages", "ScriptedSettings", "ScriptVariants", "SideFaceSettings",
           "StagesSettings"]
