"""cito-bench: benchmarks that print measured figures.

    cito-bench rollout [--json]      native vs Python-oracle rollout speed
"""
from __future__ import annotations

import argparse
import json
import sys

from cito_ros import benchmarks


def print_rollout(result: dict) -> None:
    print(f"1 s rollout ({result['steps']} steps of {result['timestep_s'] * 1e3:g} ms, {result['contact_model']}):")
    print(f"  native       {result['native_rollout_ms']:8.3f} ms   ({result['step_us']:.2f} us/step)")
    print(f"  python       {result['python_rollout_ms']:8.3f} ms   (native is {result['speedup_native_over_python']:.1f}x faster)")
    print(f"  batched      {result['batched_rollouts_per_s']:8.0f} rollouts/s on {result['batch_threads']} threads")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cito-bench", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    rollout = commands.add_parser("rollout", help="native vs Python-oracle rollout speed")
    rollout.add_argument("--repeats", type=int, default=200, help="timed native rollouts (median)")
    rollout.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)

    if args.command == "rollout":
        if args.repeats < 1:
            parser.error("--repeats must be at least 1")
        result = benchmarks.rollout_benchmark(repeats=args.repeats)
        if args.json:
            print(json.dumps(result))
        else:
            print_rollout(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
