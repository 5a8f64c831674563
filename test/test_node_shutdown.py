"""The planner node stopped while it works: SIGTERM during a solve cancels it and finishes every bag. The node
in its own process, a client in this one, over Fast DDS on an isolated domain."""
import os
import signal
import time
from pathlib import Path

from cito_msgs.srv import PlanPush

from node_harness import LONG_GOAL, node_process, read_with_mcap, read_with_rosbags, recorded_counts, request

LONG = request(**LONG_GOAL)


def test_sigterm_during_a_solve(tmp_path):
    with node_process(101 + os.getpid() % 100, tmp_path) as (process, c):
        done = c.call(request("scm"))
        assert done.success
        c.spin_for(0.5)
        c.received["/cito/progress"].clear()
        future = c.call_async(LONG)
        deadline = time.monotonic() + 60
        while len(c.received["/cito/progress"]) < 3 and time.monotonic() < deadline:
            c.spin_for(0.05)
        assert len(c.received["/cito/progress"]) >= 3 and not future.done()
        assert {m.request_id for m in c.received["/cito/progress"]} == {2}
        process.send_signal(signal.SIGTERM)
        sent = time.monotonic()
        process.wait(timeout=5.0)
        assert time.monotonic() - sent < 5.0
        bags = sorted(p for p in tmp_path.iterdir() if not p.name.endswith(".partial"))
        assert len(bags) == 2 and not list(tmp_path.glob("*.partial"))
        first = read_with_rosbags(Path(done.bag_path))
        assert first["/cito/plan_result"][0][1].metrics.position_error_m == done.metrics.position_error_m
        cancelled = read_with_mcap(bags[-1])  # the interrupted plan's bag was finished too
        (_, result), = cancelled["/cito/plan_result"]
        assert result.status == PlanPush.Response.STATUS_CANCELLED and result.metrics.status == "cancelled"


def test_sigterm_while_a_bag_is_written_finishes_it(tmp_path):
    """The answer comes before its bag is written; a SIGTERM right after it still leaves the bag whole."""
    with node_process(131 + os.getpid() % 100, tmp_path) as (process, c):
        answered = c.call(request("scm"))
        assert answered.success
        bag = Path(answered.bag_path)
        recording = bag.with_name(bag.name + ".partial").exists()
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=60.0)
        assert recording, "the bag was finished before the answer: nothing to test"
        assert not list(tmp_path.glob("*.partial")) and (bag / "metadata.yaml").is_file()
        recorded = read_with_rosbags(bag)
        assert {topic: len(messages) for topic, messages in recorded.items() if topic != "/cito/progress"} == \
            recorded_counts(answered)
