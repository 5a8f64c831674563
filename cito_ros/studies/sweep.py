"""Sweeps of solves: every job a Ray task (or, with workers=0, a call in this process).

ROS-free. A job is a key (unique within the sweep), a module-level function and its arguments; it
returns one JSON-serialisable record. `run_sweep` returns the records in the jobs' order, whatever
the order they finish in, so a report never depends on the number of workers:

- Ray: `address` joins a running cluster ("auto" or host:port); without it an embedded local Ray
  sized to this machine starts and stops with the sweep (no dashboard). With more than one task at
  a time, every task plans with one linearization thread and its starts one after the other
  (`settings_for`; results are the same bits as with more threads, tested), so the workers do not
  oversubscribe the cores; one at a time (workers=1), a task plans as configured (threaded).
- In process (workers=0): the jobs one after the other, with the settings as configured (threaded).
- Failures: a job that raises, or whose worker dies, becomes a record {"key", "failed": true,
  "error"}; the sweep goes on and its report says so.
- Resumption: with `out`, each finished record is written to out/cases/<key>.json as it arrives, and
  a rerun with the same `out` loads those and runs only the rest (failed cases again too).
"""
from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

from tqdm import tqdm

from cito_ros.settings import Settings

Job = tuple[str, Callable[..., dict[str, Any]], tuple]
TASK_OVERRIDES = {"gradient.threads": 1, "stages.parallel": False}


def settings_for(settings: Settings, workers: int | None) -> Settings:
    """The settings a sweep's solves plan with: as configured one at a time (in process, workers=0, or on Ray,
    workers=1), one thread each where several run at once (workers None: as many as cores)."""
    return settings if workers in (0, 1) else settings.with_overrides(TASK_OVERRIDES)


def split_failures(records: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(the records of finished solves, the failure records) of a sweep."""
    return [r for r in records if not r.get("failed")], [r for r in records if r.get("failed")]


def _case_path(out: Path, key: str) -> Path:
    return out / "cases" / (re.sub(r"[^A-Za-z0-9_.=+-]+", "_", key) + ".json")


def _failure(key: str, error: BaseException | str) -> dict[str, Any]:
    text = error if isinstance(error, str) else f"{type(error).__name__}: {error}".strip().rstrip(":")
    return {"key": key, "failed": True, "error": " ".join(text.split())[:500]}


def run_sweep(jobs: Sequence[Job], *, workers: int | None = None, address: str | None = None,
              out: Path | None = None, label: str = "sweep") -> list[dict[str, Any]]:
    """Run the jobs; records in job order. workers=0 runs them in this process; otherwise on Ray with
    at most `workers` tasks at once (default: this machine's cores, or the cluster's)."""
    keys = [key for key, _, _ in jobs]
    if len(set(keys)) != len(keys):
        raise ValueError("sweep job keys must be unique")
    done: dict[str, dict[str, Any]] = {}
    if out is not None:
        (out / "cases").mkdir(parents=True, exist_ok=True)
        for key in keys:
            path = _case_path(out, key)
            if path.is_file():
                done[key] = json.loads(path.read_text())
    pending = [job for job in jobs if job[0] not in done]
    if done:
        tqdm.write(f"{label}: {len(done)} of {len(jobs)} cases already in {out / 'cases'} (delete them to rerun)",
                   file=sys.stderr)
    bar = tqdm(total=len(jobs), initial=len(done), desc=label, unit="solve", dynamic_ncols=True,
               mininterval=0.2 if sys.stderr.isatty() else 5.0)

    def finished(key: str, record: dict[str, Any]) -> None:
        record = {"key": key, **record}
        done[key] = record
        if out is not None and not record.get("failed"):
            path = _case_path(out, key)
            partial = path.with_suffix(".partial")
            partial.write_text(json.dumps(record))
            os.replace(partial, path)
        bar.update(1)
        bar.set_postfix_str(key[-40:])

    try:
        if workers == 0:
            for key, function, args in pending:
                try:
                    finished(key, function(*args))
                except Exception as error:  # a case's failure, not the sweep's
                    finished(key, _failure(key, error))
        elif pending:
            _run_on_ray(pending, workers, address, finished)
    finally:
        bar.close()
    return [done[key] for key in keys]


def _run_on_ray(jobs: Sequence[Job], workers: int | None, address: str | None,
                finished: Callable[[str, dict[str, Any]], None]) -> None:
    import ray

    started_here = not ray.is_initialized()
    if started_here:
        if address is None:
            ray.init(num_cpus=os.cpu_count(), include_dashboard=False, log_to_driver=False,
                     configure_logging=False, runtime_env={"env_vars": {"OMP_NUM_THREADS": "1"}})
        else:
            ray.init(address=address, log_to_driver=False, configure_logging=False)
    try:
        call = ray.remote(max_retries=0, num_cpus=1)(_call)
        limit = workers or int(ray.cluster_resources().get("CPU", 1))
        queue = list(jobs)
        running: dict[Any, str] = {}
        while queue or running:
            while queue and len(running) < limit:
                key, function, args = queue.pop(0)
                running[call.remote(function, args)] = key
            ready, _ = ray.wait(list(running), num_returns=1)
            for reference in ready:
                key = running.pop(reference)
                try:
                    finished(key, ray.get(reference))
                except Exception as error:  # the task raised, or its worker died
                    finished(key, _failure(key, error))
    finally:
        if started_here:
            ray.shutdown()


def _call(function: Callable[..., dict[str, Any]], args: tuple) -> dict[str, Any]:
    return function(*args)
