"""app/warmup.py: the first frame's head start runs the real CPU renderer kernels and ends."""

from __future__ import annotations

import numpy as np

from inceptiongs.app.warmup import start_warmup, tiny_frame


def test_the_warm_up_frame_goes_through_the_cpu_renderer():
    image = tiny_frame()
    assert image.shape == (48, 64, 3) and np.all(np.isfinite(image))
    assert 0.05 < (image.sum(axis=2) > 0.01).mean() < 1.0   # Gaussians drawn, background left


def test_the_warm_up_thread_finishes():
    thread = start_warmup()
    thread.join(timeout=300)
    assert not thread.is_alive() and thread.daemon
