"""cito-bench: benchmarks that print measured figures.

    cito-bench rollout [--json]              native vs Python-oracle rollout speed
    cito-bench gradient [--json]             full-gradient time in rollout-equivalents
    cito-bench paper [--json] [--out DIR]    the paper's nine cases, Tables I-IV
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cito_ros import benchmarks
from cito_ros.cli.progress import ProgressBar


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
    gradient = commands.add_parser("gradient", help="full-gradient time against one rollout")
    gradient.add_argument("--repeats", type=int, default=20, help="timed gradients (median)")
    gradient.add_argument("--json", action="store_true", help="print one JSON object")
    paper = commands.add_parser("paper", help="the paper's nine cases and Tables I-IV")
    paper.add_argument("--out", type=Path, default=Path("out/paper"), help="folder for the Markdown and CSV tables")
    paper.add_argument("--json", action="store_true", help="print the list of nine result objects")
    args = parser.parse_args(argv)

    if args.command == "rollout":
        if args.repeats < 1:
            parser.error("--repeats must be at least 1")
        result = benchmarks.rollout_benchmark(repeats=args.repeats)
        if args.json:
            print(json.dumps(result))
        else:
            print_rollout(result)
    elif args.command == "gradient":
        if args.repeats < 1:
            parser.error("--repeats must be at least 1")
        result = benchmarks.gradient_benchmark(repeats=args.repeats)
        if args.json:
            print(json.dumps(result))
        else:
            print(f"gradient of {result['decision_variables']} {result['contact_model']} variables: "
                  f"{result['gradient_ms']:.1f} ms (linearization {result['linearization_ms']:.1f} ms, "
                  f"{result['threads']} threads); rollout {result['rollout_ms']:.2f} ms; "
                  f"ratio {result['ratio']:.1f} rollout-equivalents")
    elif args.command == "paper":
        bar = ProgressBar(9, "paper cases")
        results = benchmarks.paper_benchmark(progress=lambda done, note: bar.update(done, note))
        bar.close()
        paths = benchmarks.write_paper_outputs(results, args.out)
        if args.json:
            print(json.dumps(results))
        else:
            print(benchmarks.paper_tables(results))
            print("written: " + ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
