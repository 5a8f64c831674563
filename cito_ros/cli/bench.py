"""cito-bench: benchmarks that print measured figures.

    cito-bench rollout [--json]                   native vs Python-oracle rollout speed
    cito-bench gradient [--json]                  full-gradient time in rollout-equivalents
    cito-bench solve-cost [--goals N] [--json]             solve time in rollout-equivalents (one process)
    cito-bench paper [--pipeline P] [--perturb] [--json] [--out DIR]   the paper's nine cases, Tables I-IV
    cito-bench targets [--n 50] [--seed S] [--models M ...] [--perturb K] [--json] [--out DIR]   random pushes
    cito-bench speed-vs-error [--out DIR]         solver effort against error, with a plot
    cito-bench hard [--json] [--out DIR]          cases that stress the numerics
    cito-bench collisions [--json] [--out DIR]    the minimal scene against all collisions
    cito-bench figures [--out DIR]                snapshots and plots of planned motions
    cito-bench roughness [--scenes S ...] [--plans] [--json]   how far a push's outcome jumps under tiny changes
    cito-bench push-limits [--heights H ...] [--step M] [--json]   where a push that holds its height can leave the cube
    cito-bench round-trip [--n 20] [--seed S] [--json]   the node's answer time beyond the solve, and its bags
    cito-bench refusals [--n 10] [--json]         how soon a one-shot cito-plan refuses a goal, its start included
    cito-bench closed-loop [--n 30] [--seed S] [--distribution D] [--ros | --clock-s PLAN_S REPLAN_S] [--out DIR]
                                                  open and closed loop in mismatched worlds (in process, each
                                                  compute on the world's clock as measured, one episode at a
                                                  time unless --workers says, or as --clock-s fixes it; --ros:
                                                  through the nodes)

The sweeps (paper, targets, speed-vs-error, hard, collisions) run every solve as a Ray task on an
embedded local Ray (--workers W at once, default this machine's cores), on a cluster with
--address ADDR, or one by one in this process with --workers 0; each finished case is written to
<out>/cases/ as it arrives, and a rerun with the same --out skips those (cito_ros.studies.sweep).
"""
from __future__ import annotations

import os

# the environment the caller gave: what `refusals` starts its one-shot cito-plan processes with (the GL backend
# set below loads OSMesa in each of them, 0.1-0.2 s of a refusal no user's cito-plan pays)
CALLER_ENVIRONMENT = dict(os.environ)
# offscreen rendering for `figures`; read by mujoco when it is first imported
os.environ.setdefault("MUJOCO_GL", "osmesa")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from cito_ros.cli.progress import advance, progress_bar  # noqa: E402
from cito_ros.studies import asks, benchmarks, paper, sweep  # noqa: E402
from cito_ros.studies.cases import load_cases  # noqa: E402
from cito_ros.studies.targets import DISTRIBUTIONS  # noqa: E402


def print_rollout(result: dict) -> None:
    print(f"{result['horizon_s']:g} s rollout ({result['steps']} steps of {result['timestep_s'] * 1e3:g} ms, {result['contact_model']}):")
    print(f"  native       {result['native_rollout_ms']:8.3f} ms   ({result['step_us']:.2f} us/step)")
    print(f"  python       {result['python_rollout_ms']:8.3f} ms   (native is {result['speedup_native_over_python']:.1f}x faster)")
    print(f"  plain MuJoCo {result['plain_mujoco_rollout_ms']:8.3f} ms   (the same scene and motion without the plugins, "
          f"joints within {result['plain_mujoco_joint_drift_rad']:.1e} rad; native is {result['native_over_plain_mujoco']:.2f}x "
          f"its time, the median of paired runs)")
    print(f"  batched      {result['batched_rollouts_per_s']:8.0f} rollouts/s on {result['batch_threads']} threads")


def push_limits_table(result: dict) -> str:
    lines = ["Farthest rest of the cube's centre from the arm base for a push whose plate holds its height, "
             f"plate positions every {100 * result['step_m']:g} cm along +x (face: the plate's face along the push; "
             "rim: any orientation, its rim leading); the fastest plate speed there within the joint velocity "
             "limits, and the slide it buys when released", "",
             "| contact | plate height (m) | plate at (m) | cube centre at (m) | release speed (m/s) | slide (mm) "
             "| rest (m) | largest slide anywhere (mm) |",
             "|---|---|---|---|---|---|---|---|"]
    for row in result["farthest"]:
        lines.append(f"| {row['contact']} | {row['plate_height_m']:.2f} | {row['plate_distance_m']:.3f} | "
                     f"{row['object_distance_m']:.3f} | {row['release_speed_m_s']:.3f} | {1e3 * row['slide_m']:.1f} | "
                     f"{row['rest_distance_m']:.3f} | {1e3 * row['largest_slide_m']:.1f} |")
    steady = result["steady_reach_m"]
    lines += ["", f"steady push reach on this grid: face {steady['face']:.3f} m, rim {steady['rim']:.3f} m; "
                  f"push reach (the plate's rim at full stretch) {result['push_reach_m']:.3f} m",
              f"steady push reach the planner's answers use (the face, found directly): "
              f"{result['planner_steady_reach_m']:.4f} m"]
    return "\n".join(lines)


def roughness_table(result: dict) -> str:
    what = "The plans the planner returns (SCM)" if result["scanned"] == "plans" else "The scripted push"
    lines = [f"{what} of the paper's three start poses, scanned: its tracked joint reference in steps of "
             f"{result['reference_step_rad']:g} rad, its torques open loop in steps of {result['torque_step_Nm']:g} "
             f"N m (largest change of the final position error between neighbouring points, median / max over "
             f"the scans)", "",
             "| scene | step (ms) | rollout (ms) | tracked jump (cm) | open-loop jump (cm) | cube hop (mm) "
             "| executed error (cm) |",
             "|---|---|---|---|---|---|---|"]
    for name, scene in result["scenes"].items():
        lines.append(f"| {name} | {1e3 * scene['timestep_s']:g} | {scene['rollout_ms']['median']:.2f} | "
                     f"{100 * scene['tracked_jump_m']['median']:.2f} / {100 * scene['tracked_jump_m']['max']:.2f} | "
                     f"{100 * scene['open_loop_jump_m']['median']:.2f} / "
                     f"{100 * scene['open_loop_jump_m']['max']:.2f} | {1e3 * scene['hop_m']['max']:.1f} | "
                     f"{100 * scene['executed_error_m']['median']:.2f} / {100 * scene['executed_error_m']['max']:.2f} |")
    return "\n".join(lines)


def add_sweep_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--workers", type=int, default=None,
                        help="solves at once on Ray (default: this machine's cores); 0: one by one in this process")
    parser.add_argument("--address", default=None,
                        help="join a running Ray cluster (host:port or auto) instead of starting a local one")


def positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cito-bench", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    rollout = commands.add_parser("rollout", help="native vs Python-oracle rollout speed")
    rollout.add_argument("--repeats", type=positive_int, default=200, help="timed native rollouts (median)")
    rollout.add_argument("--json", action="store_true", help="print one JSON object")
    gradient = commands.add_parser("gradient", help="full-gradient time against one rollout")
    gradient.add_argument("--repeats", type=positive_int, default=20, help="timed gradients (median)")
    gradient.add_argument("--json", action="store_true", help="print one JSON object")
    cost = commands.add_parser("solve-cost", help="solve time in rollout-equivalents, in one process")
    cost.add_argument("--goals", type=int, default=20, metavar="N",
                      help="the first N goals of `targets` (seed 0) with each model, besides the nine paper cases")
    cost.add_argument("--repeats", type=positive_int, default=20, help="timed rollouts per case (median)")
    cost.add_argument("--json", action="store_true", help="print one JSON object")
    paper_parser = commands.add_parser("paper", help="the paper's nine cases and Tables I-IV")
    paper_parser.add_argument("--pipeline", choices=("paper", "physical"), default="paper",
                              help="paper: exactly the paper's problem (Tables I-IV); physical: the planner's own")
    paper_parser.add_argument("--out", type=Path, default=Path("out/paper"),
                              help="the Markdown and CSV tables, and each finished case as it arrives (a rerun skips those)")
    paper_parser.add_argument("--json", action="store_true", help="print the list of result objects")
    paper_parser.add_argument("--perturb", action="store_true",
                              help="each case again with the target moved 1e-9 m along x and with every start "
                                   "joint moved 1e-9 rad: same verdict, executed error within 1 cm?")
    add_sweep_options(paper_parser)
    targets = commands.add_parser("targets", help="seeded random pushes, judged by their execution")
    targets.add_argument("--n", type=positive_int, default=50, help="goals")
    targets.add_argument("--distribution", choices=DISTRIBUTIONS, default="forward",
                         help="forward: pushes within 35 degrees of +x (the default); beside: 3-25 cm at 50-130 "
                              "degrees either side of +x; any: anywhere on the table the arm can push the cube to, "
                              "any yaw; turn: within 1.5 cm of the cube, turned 0.16-0.30 rad")
    targets.add_argument("--time-limit", type=float, default=None, metavar="S",
                         help="each solve's wall-clock limit (solver.time_limit_s; default: the settings')")
    targets.add_argument("--seed", type=int, default=0)
    targets.add_argument("--models", nargs="+", default=list(asks.MODELS), choices=asks.MODELS)
    targets.add_argument("--perturb", type=int, default=0, metavar="K",
                         help="also solve the first K goals with the target moved 1e-9 m and the start 1e-9 rad")
    targets.add_argument("--out", type=Path, default=Path("out/targets"),
                         help="reports, and each finished case as it arrives (a rerun skips those)")
    targets.add_argument("--json", action="store_true", help="print the summary and every run")
    targets.add_argument("--reference-offsets", type=int, default=None, metavar="N",
                         help="tracking.reference_offsets: plans must also reach the goal when tracked with N offsets "
                              "of their reference (slower; give another --out, finished cases are reused)")
    add_sweep_options(targets)
    speed = commands.add_parser("speed-vs-error", help="solver effort against error (CSV, Markdown, PNG)")
    speed.add_argument("--out", type=Path, default=Path("out/speed_vs_error"))
    speed.add_argument("--quick", action="store_true", help="two settings, one case (a smoke run)")
    speed.add_argument("--json", action="store_true", help="print the per-setting summary")
    add_sweep_options(speed)
    hard = commands.add_parser("hard", help="cases that stress the numerics")
    hard.add_argument("--out", type=Path, default=Path("out/hard"))
    hard.add_argument("--cases", nargs="+", default=None, help="case names (default: all of config/hard_cases.yaml)")
    hard.add_argument("--models", nargs="+", default=list(asks.MODELS), choices=asks.MODELS)
    hard.add_argument("--repeat", type=positive_int, default=1, help="run each case this many times (2: check identity)")
    hard.add_argument("--json", action="store_true", help="print one object per case and contact model")
    add_sweep_options(hard)
    collisions = commands.add_parser("collisions", help="minimal collision pairs against all collisions")
    collisions.add_argument("--out", type=Path, default=Path("out/collisions"))
    collisions.add_argument("--json", action="store_true", help="print the comparison")
    collisions.add_argument("--quick", action="store_true", help="beta 7 only, 10 timed repeats (a smoke run)")
    add_sweep_options(collisions)
    figures = commands.add_parser("figures", help="snapshots and plots of planned motions")
    figures.add_argument("--out", type=Path, default=Path("docs/figures"))
    roughness = commands.add_parser("roughness", help="how far a push's outcome jumps under tiny changes, per scene")
    roughness.add_argument("--scenes", nargs="+", default=["default", "fine_step"], help="config/scenes names")
    roughness.add_argument("--directions", type=positive_int, default=2, help="seeded scan directions per case")
    roughness.add_argument("--plans", action="store_true",
                           help="scan the plans the planner returns for those pushes instead of the scripted pushes")
    roughness.add_argument("--json", action="store_true", help="print one JSON object")
    limits = commands.add_parser("push-limits", help="where a push that holds its height can leave the cube")
    limits.add_argument("--heights", nargs="+", type=float, default=None,
                        help="plate-centre heights above the floor (m); default: where the plate lies wholly on "
                             "the object's face, its bottom, middle and top (0.06, 0.10, 0.14 m for the cube)")
    limits.add_argument("--step", type=float, default=0.005, help="spacing of the plate positions along the push (m)")
    limits.add_argument("--json", action="store_true", help="print one JSON object")
    trip = commands.add_parser("round-trip", help="the node's answer time beyond the solve, and when its bags are done")
    trip.add_argument("--n", type=positive_int, default=20, help="seeded short pushes, each as a call and as a goal")
    trip.add_argument("--seed", type=int, default=0)
    trip.add_argument("--json", action="store_true", help="print one JSON object")
    refusals = commands.add_parser("refusals", help="how soon a one-shot cito-plan refuses a goal, its start included")
    refusals.add_argument("--n", type=positive_int, default=10, help="fresh processes per refused request")
    refusals.add_argument("--json", action="store_true", help="print one JSON object")
    closed = commands.add_parser("closed-loop", help="pushes open and closed loop in worlds that are not the model")
    closed.add_argument("--n", type=positive_int, default=30, help="targets goals (each in every world, both ways)")
    closed.add_argument("--seed", type=int, default=0)
    closed.add_argument("--distribution", choices=DISTRIBUTIONS, default="forward",
                        help="the targets distribution the goals are drawn from (forward: the default; any: anywhere "
                             "on the table the arm can push the cube to, any yaw)")
    closed.add_argument("--contact-model", default="vscm", choices=asks.MODELS)
    closed.add_argument("--ros", action="store_true", help="closed loop through cito-executor-node and "
                        "cito-sim-robot over DDS, one episode after another in real time (else: in process, on Ray)")
    closed.add_argument("--out", type=Path, default=Path("out/closed_loop"),
                        help="reports, and each finished episode as it arrives (a rerun skips those)")
    closed.add_argument("--json", action="store_true", help="print the summary and every episode")
    closed.add_argument("--clock-s", type=float, nargs=2, metavar=("PLAN_S", "REPLAN_S"), default=None,
                        help="in process: each plan and replan takes this long on the world's clock instead of its "
                             "measured compute time, so that the outcomes do not hang on the machine's speed "
                             "(changes compared episode by episode)")
    add_sweep_options(closed)
    hashes = commands.add_parser("plan-hashes", help="the paper's cases and the first targets goals, by plan hash")
    hashes.add_argument("--goals", type=int, default=10, help="targets goals (seed 0), each with every model")
    hashes.add_argument("--out", type=Path, default=None, help="write the hashes to this JSON file")
    add_sweep_options(hashes)
    args = parser.parse_args(argv)

    if args.command == "rollout":
        result = benchmarks.rollout_benchmark(repeats=args.repeats)
        if args.json:
            print(json.dumps(result))
        else:
            print_rollout(result)
    elif args.command == "gradient":
        result = benchmarks.gradient_benchmark(repeats=args.repeats)
        if args.json:
            print(json.dumps(result))
        else:
            print(f"gradient of {result['decision_variables']} {result['contact_model']} variables: "
                  f"{result['gradient_ms']:.1f} ms (linearization {result['linearization_ms']:.1f} ms, "
                  f"{result['threads']} threads); rollout {result['rollout_ms']:.2f} ms; "
                  f"ratio {result['ratio']:.1f} rollout-equivalents; Gauss-Newton curvature from its "
                  f"linearization: knot-wise {result['knot_expansion_ms']:.1f} ms, residual Jacobian "
                  f"{result['residual_jacobian_ms']:.1f} ms; gradient plus knot-wise curvature "
                  f"{result['gradient_and_curvature_ratio']:.1f} rollout-equivalents")
    elif args.command == "solve-cost":
        if args.goals < 0:
            parser.error(f"--goals must be zero or more, got {args.goals}")
        result = benchmarks.solve_cost_benchmark(goals=args.goals, repeats=args.repeats)
        if args.json:
            print(json.dumps(result))
        else:
            solve = result["solve_time_s_median"]
            print(f"{result['cases']} solves in one process: median rollout {result['rollout_ms_median']:.2f} ms; "
                  f"median solve {solve['all']:.2f} s (paper cases {solve['paper']:.2f} s"
                  + (f", targets {solve['targets']:.2f} s" if solve["targets"] is not None else "")
                  + f"); median solve cost {result['rollout_equivalents_median']:.0f} rollout-equivalents, "
                  f"{result['iterations_median']:.0f} iterations; {result['success']} successes")
            print("median share of the solve: " + ", ".join(
                f"{name.removesuffix('_time_s')} {share:.0%}" for name, share in result["phase_share_median"].items()))
            for name, entry in result["by_zone"].items():
                where = "inside the steady push reach" if name == "steady" else "beyond it (strikes)"
                print(f"{where}: {entry['cases']} solves, {entry['success']} successes" + (
                    f", median solve {entry['solve_time_s_median']:.2f} s, "
                    f"{entry['rollout_equivalents_median']:.0f} rollout-equivalents" if entry["cases"] else ""))
    elif args.command == "paper":
        results = paper.paper_benchmark(args.pipeline, perturb=args.perturb, workers=args.workers,
                                             address=args.address, out=args.out)
        paths = paper.write_paper_outputs(results, args.out)
        if args.json:
            print(json.dumps(results))
        else:
            print(paper.paper_tables(results))
            print("written: " + ", ".join(str(p) for p in paths))
    elif args.command == "targets":
        from cito_ros.settings import load_settings
        from cito_ros.studies import targets as targets_module, targets_report

        settings = load_settings()
        if args.reference_offsets is not None:
            settings = settings.with_overrides({"tracking.reference_offsets": args.reference_offsets})
        if args.time_limit is not None:
            settings = settings.with_overrides({"solver.time_limit_s": args.time_limit})
        goals, refused = targets_module.draw_goals(args.n, args.seed, settings, args.distribution)
        jobs = targets_module.jobs(goals, args.models, sweep.settings_for(settings, args.workers), args.perturb)
        records = sweep.run_sweep(jobs, workers=args.workers, address=args.address,
                                  out=args.out / f"{args.distribution}-seed{args.seed}", label="targets")
        summary = targets_report.report(records, refused, targets_module.region(settings))
        paths = targets_report.write_outputs(records, summary, args.out)
        if args.json:
            print(json.dumps({"summary": summary, "runs": records}))
        else:
            print(targets_report.markdown(summary))
            print("written: " + ", ".join(str(p) for p in paths))
    elif args.command == "speed-vs-error":
        variants = [v for v in asks.VARIANTS if v.name in ("default", "max_iter 10")] if args.quick \
            else list(asks.VARIANTS)
        cases = asks.SWEEP_CASES[2:3] if args.quick else asks.SWEEP_CASES
        records = asks.speed_vs_error(variants, cases, workers=args.workers, address=args.address, out=args.out)
        summary = asks.speed_vs_error_summary(records)
        args.out.mkdir(parents=True, exist_ok=True)
        table = asks.speed_vs_error_table(summary, sweep.split_failures(records)[1])
        (args.out / "speed_vs_error.md").write_text(table)
        paths = [asks.write_csv(args.out / "speed_vs_error_runs.csv", records),
                 asks.write_csv(args.out / "speed_vs_error.csv", summary),
                 args.out / "speed_vs_error.md",
                 asks.speed_vs_error_plot(summary, args.out / "speed_vs_error.png")]
        print(json.dumps(summary) if args.json else table)
        print("written: " + ", ".join(str(p) for p in paths), file=sys.stderr if args.json else sys.stdout)
    elif args.command == "hard":
        known = load_cases()
        unknown = [c for c in args.cases or [] if c not in known]
        if unknown:
            parser.error(f"unknown cases {unknown}; choose from {sorted(known)}")
        names = args.cases or list(known)
        records = asks.hard_cases(args.models, names, args.repeat, workers=args.workers, address=args.address,
                                     out=args.out)
        args.out.mkdir(parents=True, exist_ok=True)
        report = asks.hard_report(records)
        (args.out / "hard_cases.md").write_text(report)
        (args.out / "hard_cases.json").write_text(json.dumps(records, indent=1))
        asks.write_csv(args.out / "hard_cases.csv", records)
        print(json.dumps(records) if args.json else report)
    elif args.command == "collisions":
        result = asks.collision_cost(10 if args.quick else 50, betas=(7,) if args.quick else (5, 6, 7),
                                        workers=args.workers, address=args.address, out=args.out)
        args.out.mkdir(parents=True, exist_ok=True)
        report = asks.collision_report(result)
        (args.out / "collisions.md").write_text(report)
        (args.out / "collisions.json").write_text(json.dumps(result, indent=1))
        print(json.dumps(result) if args.json else report)
    elif args.command == "roughness":
        try:
            result = benchmarks.roughness_benchmark(tuple(args.scenes), directions=args.directions, plans=args.plans)
        except ValueError as error:  # an unknown scene
            parser.error(str(error))
        print(json.dumps(result) if args.json else roughness_table(result))
    elif args.command == "push-limits":
        try:
            result = benchmarks.push_limits_benchmark(None if args.heights is None else tuple(args.heights), args.step)
        except ValueError as error:  # a step that is not positive
            parser.error(str(error))
        print(json.dumps(result) if args.json else push_limits_table(result))
    elif args.command == "round-trip":
        from cito_ros.cli import round_trip

        bar = progress_bar(2 * args.n, "round trips", "request")
        result = round_trip.round_trip_benchmark(args.n, args.seed, progress=lambda done, _: advance(bar, done))
        bar.close()
        print(json.dumps(result) if args.json else round_trip.report_text(result))
    elif args.command == "refusals":
        from cito_ros.cli import refusals as refusals_module

        bar = progress_bar(args.n * len(refusals_module.REQUESTS), "refusals", "process")
        result = refusals_module.refusal_benchmark(args.n, progress=lambda done: advance(bar, done),
                                                   environment=CALLER_ENVIRONMENT)
        bar.close()
        print(json.dumps(result) if args.json else refusals_module.report_text(result))
    elif args.command == "closed-loop":
        from cito_ros.settings import load_settings
        from cito_ros.studies import closed_loop, targets as targets_module

        settings = load_settings()
        if args.clock_s is not None and (args.ros or not all(math.isfinite(v) and v >= 0 for v in args.clock_s)):
            parser.error("--clock-s takes two finite times of zero or more (s), and only in process (not with --ros: "
                         f"a real clock), got {args.clock_s}{' with --ros' if args.ros else ''}")
        goals, _ = targets_module.draw_goals(args.n, args.seed, settings, args.distribution)
        if args.ros:
            from cito_ros.cli.closed_loop_ros import ros_records

            bar = progress_bar(2 * len(goals) * len(closed_loop.WORLDS), "closed loop (ros)", "episode")
            records = ros_records(goals, args.contact_model, settings, args.out / "bags",
                                  progress=lambda name: advance(bar, bar.n + 1, name))
            bar.close()
        else:
            clock_s = None if args.clock_s is None else dict(zip(("plan", "replan"), args.clock_s, strict=True))
            # on the measured clock one episode at a time, by default: the compute it measures is then one
            # executor's on this machine, not half of it (two at once on two cores: replans 7.1 Hz against 9.8-10.0;
            # docs/results.md: One episode at a time)
            workers = args.workers if args.workers is not None or clock_s is not None else 1
            jobs = closed_loop.jobs(goals, args.contact_model, sweep.settings_for(settings, workers), clock_s=clock_s)
            # a fixed clock's episodes apart from measured ones: a rerun takes the finished cases of its own directory
            clock = "" if clock_s is None else f"-clock{clock_s['plan']:g}-{clock_s['replan']:g}"
            records = sweep.run_sweep(jobs, workers=workers, address=args.address,
                                      out=args.out / f"{args.distribution}-seed{args.seed}{clock}", label="closed loop")
        summary = closed_loop.report(records)
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "closed_loop.md").write_text(closed_loop.markdown(summary))
        (args.out / "closed_loop.json").write_text(json.dumps({"summary": summary, "episodes": records}, indent=1))
        closed_loop.plot(records, args.out / "closed_loop.png", settings.task.success_position_error_m)
        print(json.dumps({"summary": summary, "episodes": records}) if args.json else closed_loop.markdown(summary))
    elif args.command == "plan-hashes":
        hashes = paper.plan_hashes(args.goals, workers=args.workers, address=args.address)
        text = json.dumps(hashes, indent=1, sort_keys=True)
        if args.out is not None:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(text)
        print(text)
    elif args.command == "figures":
        from cito_ros.studies import figures as figure_module

        bar = progress_bar(len(figure_module.RUNS) + 1, "figures", "step")  # each plan, then the drawing
        paths = figure_module.figures(args.out, progress=lambda d, n: advance(bar, d, n))
        advance(bar, len(figure_module.RUNS) + 1)
        bar.close()
        print("written: " + ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
