"""cito-bench refusals: how soon a one-shot cito-plan answers a goal it refuses, the process's start included.

A request no push can serve (a pull the arm cannot make from where the cube is, a turn in place, a goal beyond the
reach or off the table, a scene that does not exist) is refused before anything is solved; issue 39 asks for every
refusal within 0.5 s. A planning node answers within milliseconds (`cito-bench targets` reports its slowest); a
one-shot `cito-plan` also pays its interpreter's start and its imports, and this measures that, each request `n`
times in a fresh process, wall clock, one after another.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

# (name, cito-plan arguments after --json): the default scene, its cube 0.99 m out, the start pose q0(5)
REQUESTS = (("pull back", ["--target", "0.80", "0.0", "0.0"]),
            ("turn in place", ["--target", "0.99", "0.0", "0.6"]),
            ("beyond the reach", ["--target", "1.30", "0.0", "0.0"]),
            ("off the table", ["--target", "0.99", "1.5", "0.0"]),
            ("unknown scene", ["--target", "1.10", "0.0", "0.0", "--scene", "no_such_scene"]))


def refusal_benchmark(n: int, progress: Callable[[int], None] | None = None,
                      environment: dict[str, str] | None = None) -> dict:
    """Each of REQUESTS `n` times through `cito-plan --json` (the console script beside this interpreter) in a
    fresh process with `environment` (default: this process's): its wall times (s), median and 90th percentile,
    and its answer; ValueError if one is not refused (exit 2, status invalid_request), which would make its time
    no refusal's."""
    command = [str(Path(sys.executable).with_name("cito-plan")), "--contact-model", "vscm", "--beta", "5", "--json"]
    rows, done = [], 0
    for name, arguments in REQUESTS:
        seconds, message = [], ""
        for _ in range(n):
            began = time.perf_counter()
            answer = subprocess.run(command + arguments, capture_output=True, text=True, check=False, env=environment)
            seconds.append(time.perf_counter() - began)
            try:
                printed = json.loads(answer.stdout)
                message, refused = printed["message"], answer.returncode == 2 and printed["status"] == "invalid_request"
            except (ValueError, KeyError):
                refused = False
            if not refused:
                raise ValueError(f"{name}: cito-plan {' '.join(arguments)} was not refused (exit "
                                 f"{answer.returncode}): {answer.stdout[-300:]} {answer.stderr[-300:]}")
            done += 1
            if progress is not None:
                progress(done)
        rows.append({"request": name, "arguments": arguments, "seconds": seconds,
                     "median_s": float(np.median(seconds)), "p90_s": float(np.percentile(seconds, 90)),
                     "message": message})
    every = [s for row in rows for s in row["seconds"]]
    return {"n": n, "requests": rows, "median_s": float(np.median(every)), "p90_s": float(np.percentile(every, 90)),
            "max_s": float(max(every))}


def report_text(result: dict) -> str:
    lines = [f"one-shot cito-plan refusals, {result['n']} fresh process(es) each (wall clock, the start included):",
             "| request | median (s) | p90 (s) | answer |", "|---|---|---|---|"]
    lines += [f"| {row['request']} | {row['median_s']:.3f} | {row['p90_s']:.3f} | {row['message'][:90]}... |"
              for row in result["requests"]]
    lines.append(f"all: median {result['median_s']:.3f} s, p90 {result['p90_s']:.3f} s, slowest {result['max_s']:.3f} s")
    return "\n".join(lines)
