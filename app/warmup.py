"""What the window's first frame needs, loaded on a background thread while the model is read.

Without it the first frame took 1.7-2.1 s (a 1M or 5M model, two cores): the CPU renderer's
numba kernels loaded from numba's cache (or compiled, the first time after an install), numba's
thread pool started, and the module the training panel imports on its first draw. Started
before the model is read, a low-priority thread does that meanwhile: the first frame then
took 0.5-1.0 s and the 1M model's settled frame came ~0.5 s sooner (docs/large_scenes.md). A frame that needs a
kernel still loading waits for it (numba's compile lock), so the thread can only help.
"""

from __future__ import annotations

import os
import threading

import numpy as np

# Below the main thread: on two cores the model's read keeps its core.
WARMUP_NICENESS = 10


def start_warmup() -> threading.Thread:
    """Start the warm-up (a daemon thread) and return it."""
    thread = threading.Thread(target=_warm_up, name="warm-up", daemon=True)
    thread.start()
    return thread


def _warm_up() -> None:
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), WARMUP_NICENESS)
    except (AttributeError, OSError):   # not Linux, or not allowed: run at the normal priority
        pass
    try:
        import inceptiongs.bootstrap.runner  # noqa: F401, PLC0415 (the training panel's first draw)
        tiny_frame()
    except Exception:  # noqa: BLE001 - only a head start: the first frame reports any real error itself
        pass


def tiny_frame() -> np.ndarray:
    """A 64 x 48 frame of 64 Gaussians through the CPU renderer's kernels (rgb, SH degree 0)
    -> [48, 64, 3] float32."""
    from inceptiongs.camera import Camera, look_at  # noqa: PLC0415
    from inceptiongs.renderer.cpu_composite import colour_over_background, composite_splats  # noqa: PLC0415
    from inceptiongs.renderer.gl_camera import shader_camera  # noqa: PLC0415
    from inceptiongs.renderer.layout import MODES  # noqa: PLC0415
    from inceptiongs.renderer.preprocess_numba import preprocess_splats  # noqa: PLC0415
    from inceptiongs.renderer.sorting import visible_depth_order  # noqa: PLC0415
    from inceptiongs.renderer.splats import pack_gaussians  # noqa: PLC0415

    rng = np.random.default_rng(0)
    count = 64
    texels, anchor, _ = pack_gaussians({
        "means": rng.normal(size=(count, 3)).astype(np.float32),
        "log_scales": np.full((count, 3), -3.0, np.float32),
        "quats": np.tile(np.float32([1.0, 0.0, 0.0, 0.0]), (count, 1)),
        "opacity_logits": np.ones(count, np.float32), "sh": rng.normal(size=(count, 1, 3)).astype(np.float32)})
    camera = Camera("warm-up", 64, 48, 50.0, 50.0, 32.0, 24.0, look_at(np.array([0.0, 0.0, -5.0]), np.zeros(3)))
    cam = shader_camera(camera, anchor)
    splats = preprocess_splats(texels, 0, cam, MODES["rgb"], 1.0)
    order = visible_depth_order(texels[:, 0, :3], splats[:, 1, 3] > 0.0, cam.rotation, cam.translation)
    return colour_over_background(composite_splats(splats, order, 64, 48), (0.0, 0.0, 0.0))
