"""One thread that writes every bag, so that whoever produced the data never waits for its recording.

A producer (the node's worker once a plan is answered, a controller's loop) opens a `Recording` and hands
it messages as they come: ROS message objects or their CDR bytes, with their log times. Every call only
queues; the recorder's thread serializes message objects (cito_ros.ros.bag.BagWriter), writes them and
finishes each bag when it is closed. A producer can also queue a job (any callable) to run on that thread
in turn, such as building and publishing a plan's per-state messages after its answer has gone out.

Bags are written in the order their work was queued, each `.partial` until complete; a bag whose job fails
is discarded and the failure reported, and the recorder goes on. `drain` waits until everything queued so
far is done, as a node does before it exits: no bag is lost.
"""
from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Any, Callable

from cito_ros.ros.bag import BagWriter, TopicQos


class Recording:
    """A bag being recorded. write() and close() return at once; `finished` is set when the bag is complete
    under its final name, or discarded after a failure (`error` then says why)."""

    def __init__(self, recorder: "Recorder", path: Path, topics: dict[str, tuple[str, TopicQos]]):
        self.recorder, self.path, self.topics = recorder, Path(path), topics
        self.finished = threading.Event()
        self.error: str | None = None
        self._writer: BagWriter | None = None

    def write(self, topic: str, message: Any, stamp_ns: int) -> None:
        """Queue a message (CDR bytes or a message object) on `topic`, logged and published at stamp_ns."""
        self.recorder.submit(self.write_now, topic, message, stamp_ns, recording=self)

    def write_now(self, topic: str, message: Any, stamp_ns: int) -> None:
        """Write a message at once: only from a job running on the recorder's thread."""
        self._bag().write(topic, message, stamp_ns)

    def close(self) -> None:
        """Queue the end of the bag, after every message queued before it."""
        self.recorder.submit(self._close, recording=self)

    def _bag(self) -> BagWriter:
        """The bag's writer, created on the recorder's thread by the first thing written (or the close)."""
        if self._writer is None:
            self._writer = BagWriter(self.path)
            for name, (type_name, qos) in self.topics.items():
                self._writer.add_topic(name, type_name, qos)
        return self._writer

    def _close(self) -> None:
        self._bag().close()
        self.finished.set()

    def _fail(self, error: str) -> None:
        self.error = error
        if self._writer is not None:
            self._writer.abort()
        self.finished.set()


class Recorder:
    """The recording thread (see the module docstring). `on_error` hears of every failed job."""

    def __init__(self, on_error: Callable[[str], None] | None = None, name: str = "cito_recorder"):
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._done = threading.Condition()
        self._queued = self._finished = 0
        self._on_error = on_error
        threading.Thread(target=self._run, name=name, daemon=True).start()

    def open(self, path: str | Path, topics: dict[str, tuple[str, TopicQos]]) -> Recording:
        """A new bag at `path` (written as path.partial until complete) on these topics: (type name, QoS)."""
        return Recording(self, Path(path), dict(topics))

    def submit(self, job: Callable[..., None], *args: Any, recording: Recording | None = None) -> None:
        """Run job(*args) on the recording thread after everything queued before it. If it raises, the error
        goes to on_error and `recording` (if given) is discarded; the jobs queued after it still run."""
        with self._done:
            self._queued += 1
        self._queue.put((job, args, recording))

    def drain(self, timeout_s: float | None = None) -> bool:
        """Wait until everything queued so far is done; False if timeout_s ran out first."""
        with self._done:
            target = self._queued
            return self._done.wait_for(lambda: self._finished >= target, timeout_s)

    def _run(self) -> None:
        while True:
            job, args, recording = self._queue.get()
            try:
                if recording is None or recording.error is None:
                    job(*args)
            except Exception as error:  # one bag's failure, not the recorder's
                message = f"recording {recording.path if recording else ''}: {type(error).__name__}: {error}"
                if recording is not None:
                    recording._fail(message)
                if self._on_error is not None:
                    self._on_error(message)
            finally:
                with self._done:
                    self._finished += 1
                    self._done.notify_all()
