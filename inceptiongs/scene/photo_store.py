"""Photos out of core: every reader of a scene's photos (training, stage II, evaluation, the
viewer's overlay) gets them from a :class:`PhotoStore`.

A photo is decoded once per scene and training resolution into the cache folder
(``<scene cache>/photos/<WxH>/<name>.<size>-<mtime_ns>.npy``: the RGB array exactly as the
float conversion starts from it, uint8 for 8-bit photos), so later reads are a memory map and
float32 tensors are bit for bit what decoding the photo gives. A photo whose file changes
(size or modification time) gets a new key, so it is decoded again and the stale file removed.

The store holds float32 photos up to a byte budget (``--photo-memory``), least recently used
first out, and a prefetch thread loads the views the sampler will ask for next; on a device
other than the CPU each read uploads one photo, so the device never holds them all.
"""

from __future__ import annotations

import collections
import os
import queue
import threading
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from ..io.atomic import atomic_open
from ..io.photo_memory import default_budget, photo_memory
from .loader import float_rgb

PREFETCH_DEPTH = 4                       # views loaded ahead of the one in use (when the budget allows)


def photo_bytes(scene, index: int) -> int:
    """Bytes of photo ``index`` as a float32 [H, W, 3] tensor."""
    cam = scene.cameras[index]
    return cam.width * cam.height * 3 * 4


def _source_key(path: Path) -> str:
    try:
        stat = path.stat()
    except OSError:
        raise InputError(f"{path}: image file does not exist (or cannot be read)") from None
    return f"{stat.st_size}-{stat.st_mtime_ns}"


def cache_file(scene, index: int) -> Path | None:
    """Where photo ``index`` is cached decoded at its training resolution (None: no usable
    cache folder). The name carries the photo file's size and modification time."""
    try:
        folder = scene.work_dir / "photos" / scene.resolution_key(index)
    except InputError:
        return None
    name = scene.cameras[index].name.replace("/", "__").replace("\\", "__")
    return folder / f"{name}.{_source_key(scene.image_paths[index])}.npy"


def stored_photo(scene, index: int) -> np.ndarray:
    """Photo ``index`` as the float conversion starts from it: [H, W, 3] RGB (uint8 for 8-bit
    photos), memory-mapped from the cache, decoded and cached first when missing or stale."""
    path = cache_file(scene, index)
    if path is not None and path.is_file():
        try:
            return np.load(path, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError):   # a damaged cache file is decoded again
            pass
    rgb = scene.load_stored_rgb(index)
    cam = scene.cameras[index]
    if tuple(rgb.shape[:2]) != (cam.height, cam.width):
        raise InputError(f"{scene.image_paths[index]}: image is {rgb.shape[1]}x{rgb.shape[0]}, "
                         f"camera says {cam.width}x{cam.height}")
    if path is not None:
        _write_cache(path, rgb)
    return rgb


def _write_cache(path: Path, rgb: np.ndarray) -> None:
    try:
        with atomic_open(path, "wb") as f:
            np.save(f, rgb, allow_pickle=False)
        for old in _earlier_versions(path):   # the same photo before it changed
            (path.parent / old).unlink(missing_ok=True)
    except (InputError, OSError):   # a full or read-only cache only costs speed
        pass


# Per cache folder, the names found in it when this process first wrote there, by photo: a
# folder is listed once, not once per photo written (3,000 photos: 9 million names read).
_FOLDER_NAMES: dict[Path, dict[str, list[str]]] = {}
_FOLDER_LOCK = threading.Lock()


def _photo_of(name: str) -> tuple[str, int]:
    """A cache file's photo: its name's first part and its number of dots (a camera name with
    dots of its own is another photo than one that only shares the first part)."""
    return name.split(".")[0], name.count(".")


def _earlier_versions(path: Path) -> list[str]:
    """Names of ``path``'s photo in its folder other than ``path`` (files of the photo before it
    changed), from one listing of the folder per process."""
    with _FOLDER_LOCK:
        names = _FOLDER_NAMES.get(path.parent)
        if names is None:
            names = {}
            for entry in os.scandir(path.parent):
                if entry.name.endswith(".npy"):
                    names.setdefault(_photo_of(entry.name)[0], []).append(entry.name)
            _FOLDER_NAMES[path.parent] = names
        listed = names.get(_photo_of(path.name)[0], [])
        names[_photo_of(path.name)[0]] = [path.name] + [name for name in listed if _photo_of(name) != _photo_of(path.name)]
    return [name for name in listed if name != path.name and _photo_of(name) == _photo_of(path.name)]


def photo_tensor(scene, index: int) -> torch.Tensor:
    """Photo ``index``: [H, W, 3] float32 in [0, 1] on the CPU (Scene.load_image's values)."""
    return torch.from_numpy(np.ascontiguousarray(float_rgb(np.asarray(stored_photo(scene, index))),
                                                 dtype=np.float32))


class _Held:
    """The photos a store holds (least recently used first) and the prefetch thread; shared
    by every device view of one store."""

    def __init__(self, scene, views: list[int], budget: int):
        self.scene, self.views, self.budget = scene, views, budget
        self.photos: collections.OrderedDict[int, torch.Tensor] = collections.OrderedDict()
        self.held_bytes = self.peak_bytes = 0
        self.lock = threading.Lock()
        self.queue: queue.Queue = queue.Queue()
        self.queued: set[int] = set()
        self.stopping = threading.Event()
        self.thread: threading.Thread | None = None

    def get(self, index: int) -> torch.Tensor:
        with self.lock:
            photo = self.photos.get(index)
            if photo is not None:
                self.photos.move_to_end(index)
                return photo
        photo = photo_tensor(self.scene, index)   # errors (a photo deleted) name the file here
        self.put(index, photo)
        return photo

    def put(self, index: int, photo: torch.Tensor) -> None:
        with self.lock:
            if index in self.photos:
                return
            size = photo.numel() * photo.element_size()
            while self.photos and self.held_bytes + size > self.budget:
                _, old = self.photos.popitem(last=False)
                self.held_bytes -= old.numel() * old.element_size()
            if self.held_bytes + size <= self.budget:
                self.photos[index] = photo
                self.held_bytes += size
                self.peak_bytes = max(self.peak_bytes, self.held_bytes)

    def prefetch(self, views: list[int]) -> None:
        if self.stopping.is_set():
            return
        if self.thread is None:
            self.thread = threading.Thread(target=self._work, name="photo-prefetch", daemon=True)
            self.thread.start()
        for view in views:
            with self.lock:
                if view in self.photos or view in self.queued:
                    continue
                self.queued.add(view)
            self.queue.put(view)

    def _work(self) -> None:
        while not self.stopping.is_set():
            view = self.queue.get()
            if view is None:
                break
            try:
                if not self.stopping.is_set():
                    self.put(view, photo_tensor(self.scene, view))
            except Exception:  # noqa: BLE001  (the reader's own load reports it, naming the file)
                pass
            finally:
                with self.lock:
                    self.queued.discard(view)

    def close(self) -> None:
        self.stopping.set()
        if self.thread is not None:
            self.queue.put(None)
            self.thread.join(timeout=30.0)
            self.thread = None


def photo_budget(scene, views, budget: int | None = None) -> int:
    """Bytes a store of ``scene``'s ``views`` may hold: ``budget``, else --photo-memory, else the
    default (all of them within a share of the free memory, at least one photo). InputError when
    a budget given is smaller than the largest photo: a command checks it before it writes."""
    largest = max((photo_bytes(scene, v) for v in views), default=0)
    if budget is None:
        budget = photo_memory()
    if budget is None:
        budget = max(default_budget(sum(photo_bytes(scene, v) for v in views)), largest)
    if views and budget < largest:
        raise InputError(f"--photo-memory: {budget} bytes is smaller than one photo "
                         f"({largest} bytes as float32 at the training resolution)")
    return budget


class PhotoStore(Mapping):
    """index -> photo [H, W, 3] float32 on ``device``, for the views ``views`` of ``scene``,
    holding at most ``budget`` bytes of photos on the host (the device gets one per read)."""

    def __init__(self, scene, views, budget: int | None = None, device: torch.device | str = "cpu",
                 _held: _Held | None = None):
        if _held is None:
            views = sorted({int(v) for v in views})
            _held = _Held(scene, views, photo_budget(scene, views, budget))
        self._held, self.device = _held, torch.device(device)

    @property
    def budget(self) -> int:
        return self._held.budget

    @property
    def held_bytes(self) -> int:
        """Bytes of photos held now (never more than the budget)."""
        return self._held.held_bytes

    @property
    def peak_bytes(self) -> int:
        """The most bytes of photos held at once."""
        return self._held.peak_bytes

    def on(self, device: torch.device | str) -> PhotoStore:
        """This store read onto ``device`` (the same held photos and thread)."""
        return PhotoStore(None, None, device=device, _held=self._held)

    def cpu_photo(self, index: int) -> torch.Tensor:
        if index not in self._held.views:
            raise KeyError(index)
        return self._held.get(index)

    def __getitem__(self, index: int) -> torch.Tensor:
        photo = self.cpu_photo(index)
        return photo if self.device.type == "cpu" else photo.to(self.device, non_blocking=True)

    def __iter__(self) -> Iterator[int]:
        return iter(self._held.views)

    def __len__(self) -> int:
        return len(self._held.views)

    def __contains__(self, index) -> bool:
        return index in self._held.views

    def prefetch(self, views: list[int]) -> None:
        """Load ``views`` (the next ones the sampler draws) in the background, as many as
        the budget holds beside the photo in use."""
        one = max(1, max((photo_bytes(self._held.scene, v) for v in views[:1]), default=1))
        depth = min(PREFETCH_DEPTH, max(0, self.budget // one - 1))
        if depth:
            self._held.prefetch([v for v in views[:depth] if v in self._held.views])

    def close(self) -> None:
        """Stops the prefetch thread (it finishes the photo it is decoding)."""
        self._held.close()


class DerivedPhotos(Mapping):
    """index -> ``derive(cpu photo)`` on ``device``, computed when asked (a few kept)."""

    def __init__(self, store: PhotoStore, views, derive, device: torch.device | str = "cpu", keep: int = 4):
        self.store, self.views, self.derive = store, set(views), derive
        self.device, self.keep = torch.device(device), keep
        self._recent: collections.OrderedDict[int, torch.Tensor] = collections.OrderedDict()

    def on(self, device: torch.device | str) -> DerivedPhotos:
        return DerivedPhotos(self.store, self.views, self.derive, device, self.keep)

    def __getitem__(self, index: int) -> torch.Tensor:
        if index not in self.views:
            raise KeyError(index)
        value = self._recent.get(index)
        if value is None:
            value = self.derive(self.store.cpu_photo(index)).to(self.device)
            self._recent[index] = value
            while len(self._recent) > self.keep:
                self._recent.popitem(last=False)
        return value

    def __iter__(self) -> Iterator[int]:
        return iter(sorted(self.views))

    def __len__(self) -> int:
        return len(self.views)


def check_photo_files(scene, views) -> None:
    """One line naming the first photo of ``views`` whose file is missing."""
    for view in views:
        path = scene.image_paths[view]
        if not os.path.isfile(path):
            raise InputError(f"{path}: image file does not exist")
