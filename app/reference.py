"""The live GL-vs-torch cross-check: the torch reference rasterizer renders the current view
at reduced resolution on a worker thread; the UI compares it with the GL image of the same
small camera (side by side, or an error heat-map with its PSNR)."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from inceptiongs.camera import Camera

from .capabilities import one_line

# The heat-map's colour scale saturates at this absolute error (per pixel, mean over RGB):
# GL and torch should agree to ~1e-2, so 0.1 already means a visible bug.
HEATMAP_ERROR_MAX = 0.1


def error_heatmap(image_a: np.ndarray, image_b: np.ndarray,
                  error_max: float = HEATMAP_ERROR_MAX) -> np.ndarray:
    """[H, W, 3] float32 in [0, 1]: black (no error) -> red -> yellow (>= error_max)."""
    error = np.abs(image_a.astype(np.float32) - image_b.astype(np.float32)).mean(axis=2)
    t = np.clip(error / error_max, 0.0, 1.0)
    return np.stack([np.clip(2.0 * t, 0, 1), np.clip(2.0 * t - 1.0, 0, 1), np.zeros_like(t)], axis=2)


def side_by_side(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Left half of ``left`` next to the right half of ``right`` (both [H, W, 3]): the split
    runs down the middle, so the same scene content meets at the seam."""
    out = left.copy()
    half = left.shape[1] // 2
    out[:, half:] = right[:, half:]
    out[:, half:half + 1] = (1.0, 1.0, 1.0)  # the seam, so it is clear which side is which
    return out


@dataclass(frozen=True)
class ReferenceResult:
    camera: Camera
    model_version: int
    rgb: np.ndarray  # [H, W, 3] float32
    seconds: float


class ReferenceWorker:
    """Renders requests with the CPU's reference rasterizer (``inceptiongs.rasterizer.interface.
    cpu_rasterizer``: the torch reference with its numba kernels) on one background thread. Only the
    newest request is kept: while torch works, newer camera moves replace the pending one."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._pending = None
        self._result: ReferenceResult | None = None
        self._closed = False
        self.error: str | None = None
        self.busy = False
        self._thread = threading.Thread(target=self._loop, name="inceptiongs-reference", daemon=True)
        self._thread.start()

    def request(self, arrays: dict, model_version: int, camera: Camera, background=(0.0, 0.0, 0.0),
                sh_degree: int | None = None) -> None:
        with self._lock:
            self._pending = (arrays, model_version, camera, tuple(background), sh_degree)
            self._wake.notify()

    @property
    def idle(self) -> bool:
        """Nothing pending and nothing rendering: the newest request's result (or error) is in."""
        with self._lock:
            return self._pending is None and not self.busy

    def result(self) -> ReferenceResult | None:
        with self._lock:
            return self._result

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._wake.notify()
        self._thread.join(timeout=10.0)

    def _loop(self) -> None:
        import time

        import torch

        from inceptiongs.gaussians import Gaussians
        from inceptiongs.rasterizer.interface import cpu_rasterizer

        render = cpu_rasterizer()

        while True:
            with self._lock:
                while self._pending is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                arrays, version, camera, background, sh_degree = self._pending
                self._pending = None
                self.busy = True
            start = time.perf_counter()
            try:
                with torch.no_grad():
                    out = render(Gaussians.from_numpy(arrays), camera, outputs=("rgb",),
                                 background=torch.tensor(background, dtype=torch.float32),
                                 sh_degree=sh_degree)
                rgb = out["rgb"].detach().cpu().numpy().astype(np.float32)
                result = ReferenceResult(camera, version, rgb, time.perf_counter() - start)
                with self._lock:
                    self._result = result
                    self.error = None
            except Exception as exc:  # noqa: BLE001 - shown in the panel; the viewer keeps going
                with self._lock:
                    self.error = one_line(exc)
            finally:
                self.busy = False
