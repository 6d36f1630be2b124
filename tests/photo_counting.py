"""Counting decoded photos alive at once: every photo a reader hands out is followed (a weak
reference), so a test can assert that a pass over many views never held them all."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import torch


class AliveCount:
    """``track(array)`` registers a decoded photo; ``alive`` is how many registered ones still
    exist (held by anyone, views and tensors sharing their memory included), ``peak`` the
    most at once, ``reads`` how many were handed out."""

    def __init__(self):
        self.alive = self.peak = self.reads = 0
        self._followed: set[int] = set()

    def track(self, array: np.ndarray) -> np.ndarray:
        self.alive += 1
        self.reads += 1
        self.peak = max(self.peak, self.alive)
        weakref.finalize(array, self._gone)
        return array

    def track_once(self, obj):
        """track(obj) unless it is already being followed (a cached photo handed out again)."""
        if id(obj) not in self._followed:
            self._followed.add(id(obj))
            weakref.finalize(obj, self._followed.discard, id(obj))
            self.track(obj)
        return obj

    def _gone(self) -> None:
        self.alive -= 1

    def counting(self, read):
        """read(i) -> [H, W, 3] array or tensor, as the same reader whose photos are tracked
        (a tensor comes back sharing the tracked array's memory)."""
        def counted(*args):
            photo = read(*args)
            if isinstance(photo, torch.Tensor):
                array = self.track(np.array(photo.numpy()))
                return torch.from_numpy(array)
            return self.track(np.array(photo))
        return counted


def tensors_of_shape(shape: tuple[int, ...]) -> int:
    """How many distinct tensor buffers of ``shape`` the interpreter holds now."""
    gc.collect()
    return len({t.data_ptr() for t in gc.get_objects() if issubclass(type(t), torch.Tensor) and tuple(t.shape) == shape})
