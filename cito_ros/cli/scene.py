"""cito-scene: facts about the push scene.

    cito-scene info [--beta B] [--scene NAME] [--json]
"""
from __future__ import annotations

import argparse
import json
import sys

from cito_ros.model.contact_models import contact_model
from cito_ros.model.scene import ARM_JOINTS, Scene, start_configuration
from cito_ros.settings import SceneConfig, Settings, load_settings


def scene_info(settings: Settings, beta: float, scene_name: str | None) -> dict:
    scene = Scene(contact_model("vscm", settings.contact_models),
                  settings.scene if scene_name is None else SceneConfig.load(scene_name))
    q0 = start_configuration(beta)
    data = scene.data_at(q0)
    position, quaternion = scene.object_pose(data)
    model = scene.model
    return {
        "scene": scene.config.name,
        "beta": beta,
        "initial_distance_m": scene.signed_distance(data),
        "q0": q0.tolist(),
        "joints": list(ARM_JOINTS),
        "robot_candidate_m": data.site_xpos[scene.robot_site_id].tolist(),
        "object_candidate_m": data.site_xpos[scene.object_site_id].tolist(),
        "object_position_m": position.tolist(),
        "object_quaternion": quaternion.tolist(),
        "object_half_size_m": float(scene.object_half_size[0]),
        "object_mass_kg": float(model.body_mass[scene.object_body_id]),
        "timestep_s": model.opt.timestep,
        "collision_pairs": int(model.npair),
        "torque_limit_Nm": scene.torque_limit.tolist(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cito-scene", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    info = commands.add_parser("info", help="start pose, initial distance and object pose")
    info.add_argument("--beta", type=float, default=None, help="start-pose parameter (default: config beta)")
    info.add_argument("--scene", default=None, help="scene in config/scenes (default: config scene)")
    info.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    try:
        settings = load_settings()
        beta = args.beta if args.beta is not None else settings.beta
        result = scene_info(settings, beta, args.scene)
    except ValueError as error:
        print(f"cito-scene: error: {error}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
    else:
        print(f"scene {result['scene']}, beta = {beta:g}")
        print(f"  q0 = [{', '.join(f'{v:.4f}' for v in result['q0'])}] rad")
        print(f"  initial distance between the contact candidates: {result['initial_distance_m']:.4f} m")
        print(f"  object at ({', '.join(f'{v:.3f}' for v in result['object_position_m'])}) m, "
              f"{result['object_mass_kg']} kg, half size {result['object_half_size_m']} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
