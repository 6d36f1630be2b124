"""The job <-> viewer hand-off helpers: pause/stop and the job's last word."""

from __future__ import annotations

import threading
import time

from inceptiongs.live import JobControl, JobPublisher, SnapshotBox, wait_while_paused


def test_wait_while_paused_blocks_until_resumed_and_reports_the_paused_time():
    control = JobControl()
    assert wait_while_paused(None) == (False, 0.0)
    assert wait_while_paused(control) == (False, 0.0)
    control.pause.set()
    threading.Timer(0.3, control.pause.clear).start()
    began = time.perf_counter()
    stop, paused_s = wait_while_paused(control, poll_s=0.01)
    waited = time.perf_counter() - began
    assert not stop and 0.25 <= paused_s <= waited + 1e-6


def test_stop_ends_a_pause():
    control = JobControl()
    control.pause.set()
    threading.Timer(0.1, control.stop.set).start()
    stop, _ = wait_while_paused(control, poll_s=0.01)
    assert stop


def test_finish_publishes_the_final_state_with_scores_and_keeps_the_model():
    box = SnapshotBox()
    out = JobPublisher(box)
    box.publish(7, {"means": [1]}, {})
    out.finish("training", 9, True, {"all_psnr": 21.5})
    snapshot = box.latest()
    assert snapshot.message == "training finished at iteration 9"
    assert snapshot.metrics == {"all_psnr": 21.5} and snapshot.gaussians == {"means": [1]}
    out.finish("bootstrap", 3, False, {}, "2 virtual views, out")
    assert box.latest().message == "bootstrap stopped (checkpoint written) at iteration 3: 2 virtual views, out"
