"""One rasterizer interface: the ``Rasterizer`` protocol, its typed result, and the registry.

Every rasterizer is a callable with the signature of the torch reference
(:func:`inceptiongs.rasterizer.rasterize.render`) that returns a :class:`RenderResult`:

- ``torch``: the reference, every stage in torch (any device);
- ``numba``: the CPU fast path (the numba kernels wherever they cover the case, torch elsewhere);
- ``gsplat``: gsplat's fused CUDA kernels (optional extra ``pip install inceptiongs[cuda]``),
  imported only when chosen.

A command resolves its ``--device auto|cpu|cuda`` with :func:`resolve_device`, the one device
rule, into a :class:`Device` (the rasterizer, the torch device, why), and carries it; nothing
outside the torch backend calls ``render`` itself.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import torch

from ..camera import Camera
from ..constants import DEVICES
from ..errors import InputError
from ..gaussians import Gaussians
from .backend import numba_installed
from .result import RenderResult

CUDA_EXTRA = "pip install 'inceptiongs[cuda]'"


class Rasterizer(Protocol):
    """Renders Gaussians from a camera. ``name``: its registry name; ``device``: where its
    tensors live ("cpu" or "cuda")."""

    name: str
    device: str

    def __call__(self, gaussians: Gaussians, camera: Camera, outputs: Sequence[str] = ("rgb",),
                 background=None, features: torch.Tensor | None = None, sh_degree: int | None = None,
                 world_to_camera: torch.Tensor | None = None) -> RenderResult: ...


@dataclass(frozen=True)
class ReferenceRasterizer:
    """The torch reference ``render`` with one stage backend ("torch": every stage in torch;
    "auto": the numba kernels for CPU tensors where they cover the case)."""

    name: str
    backend: str
    device: str = "cpu"

    def __call__(self, gaussians: Gaussians, camera: Camera, outputs: Sequence[str] = ("rgb",),
                 background=None, features: torch.Tensor | None = None, sh_degree: int | None = None,
                 world_to_camera: torch.Tensor | None = None) -> RenderResult:
        from .rasterize import render
        return RenderResult.from_dict(render(gaussians, camera, outputs=outputs, background=background,
                                             features=features, sh_degree=sh_degree,
                                             world_to_camera=world_to_camera, backend=self.backend))


def _gsplat_rasterizer() -> Rasterizer:
    from .gsplat_backend import GsplatRasterizer   # gsplat is imported only when chosen
    return GsplatRasterizer()


# name -> a factory making that rasterizer. "numba" is the reference with backend "auto": on CPU
# tensors it takes every numba kernel that covers the case, which is today's training path.
RASTERIZERS: dict[str, Callable[[], Rasterizer]] = {
    "torch": lambda: ReferenceRasterizer("torch", "torch"),
    "numba": lambda: ReferenceRasterizer("numba", "auto"),
    "gsplat": _gsplat_rasterizer,
}


def rasterizer_device(rasterizer) -> str:
    """Where ``rasterizer`` renders ("cpu", "cuda"): where a run keeps its tensors. A stand-in
    callable without ``device`` (tests, plain render functions) renders on the CPU."""
    return getattr(rasterizer, "device", "cpu")


def get_rasterizer(name: str) -> Rasterizer:
    """The rasterizer registered as ``name``; ValueError naming the choices otherwise."""
    if name not in RASTERIZERS:
        raise ValueError(f"unknown rasterizer {name!r}; choose from {', '.join(RASTERIZERS)}")
    return RASTERIZERS[name]()


def cpu_rasterizer() -> Rasterizer:
    """The CPU's best: numba when it is installed, else the torch reference."""
    return get_rasterizer("numba" if numba_installed() else "torch")


def rasterizer_for(device) -> Rasterizer:
    """The rasterizer for tensors already on ``device`` when a caller names none, by the one
    device rule (``resolve_device``): CUDA tensors get what "auto" chooses (gsplat when nothing it
    needs is missing, else the torch reference, which runs there too), host tensors the CPU's best."""
    return resolve_device("auto" if torch.device(device).type == "cuda" else "cpu").rasterizer


def gsplat_installed() -> bool:
    return importlib.util.find_spec("gsplat") is not None


def cuda_compiler() -> str | None:
    """Where nvcc is (gsplat builds its kernels with it on first use), or None."""
    from torch.utils.cpp_extension import CUDA_HOME   # finds nvcc on PATH, $CUDA_HOME or /usr/local/cuda
    return None if CUDA_HOME is None else str(CUDA_HOME)


def cuda_missing() -> tuple[str, str] | None:
    """What stops gsplat from running here and how to get it, or None when nothing does."""
    if not torch.cuda.is_available():
        return ("no CUDA GPU visible", "torch.cuda.is_available() is False: needs an NVIDIA GPU, its driver "
                "and a CUDA build of torch")
    if not gsplat_installed():
        return "gsplat is not installed", CUDA_EXTRA
    if cuda_compiler() is None:
        return ("no CUDA compiler for gsplat's first build", "install a CUDA toolkit with nvcc and set "
                "CUDA_HOME")
    return None


@dataclass(frozen=True)
class Device:
    """What ``--device auto|cpu|cuda`` resolved to: one answer for everything a command runs on
    (the rasterizer, the run's tensors, the prior and its G-buffer). ``asked``: the value given
    (or the run's recorded one); ``why``: why this device ("--device cpu", "no CUDA GPU visible")."""

    asked: str
    rasterizer: Rasterizer
    why: str

    @property
    def name(self) -> str:
        """The rasterizer's registry name (RASTERIZERS): "numba", "torch" or "gsplat"."""
        return self.rasterizer.name

    @property
    def torch_device(self) -> torch.device:
        """Where tensors live: where the rasterizer renders."""
        return torch.device(rasterizer_device(self.rasterizer))

    @property
    def line(self) -> str:
        """Which device and rasterizer, and why: ``device: cpu (numba rasterizer): no CUDA GPU visible``."""
        return f"device: {rasterizer_device(self.rasterizer)} ({self.name} rasterizer): {self.why}"

    @property
    def note(self) -> str | None:
        """The line a command prints once its work has started: only "auto" says what it chose."""
        return self.line if self.asked == "auto" else None

    def to_json(self) -> dict:
        """What a run records of the choice."""
        return {"asked": self.asked, **device_record(self.rasterizer), "why": self.why}


def device_record(rasterizer) -> dict:
    """{"device", "rasterizer"}: where ``rasterizer`` renders and its registry name."""
    return {"device": rasterizer_device(rasterizer), "rasterizer": getattr(rasterizer, "name", type(rasterizer).__name__)}


def resolve_device(asked: str, source: str = "--device", instead: str | None = None) -> Device:
    """The one device rule: ``asked`` "auto", "cpu" or "cuda" -> the :class:`Device` every part
    of a command uses.

    "cpu": the CPU's best rasterizer (numba, else the torch reference), torch on the CPU.
    "cuda": gsplat and torch on the GPU; without a usable GPU, gsplat or a CUDA compiler
    (``cuda_missing``) an InputError naming what is missing and how to get it. "auto": "cuda"
    when nothing is missing, else "cpu", saying why. ``source`` names where the value came from
    in that error and in ``why`` ("--device", or "RUN/config.json: device"); ``instead`` ends the
    error (what the user can give instead).
    """
    if asked not in DEVICES:
        raise InputError(f"{source} must be one of {', '.join(DEVICES)}, got {asked!r}")
    missing = cuda_missing() if asked != "cpu" else None
    if asked == "cuda":
        if missing is not None:
            raise InputError(f"{source} cuda: {missing[0]} ({missing[1]})" + (f"; {instead}" if instead else ""))
        return Device(asked, get_rasterizer("gsplat"), f"{source} cuda")
    if asked == "auto" and missing is None:
        return Device(asked, get_rasterizer("gsplat"), f"CUDA GPU {torch.cuda.get_device_name()} and gsplat found")
    rasterizer = cpu_rasterizer()
    why = f"{source} cpu" if asked == "cpu" else missing[0]
    if rasterizer.name == "torch":
        why += "; numba is not installed"
    return Device(asked, rasterizer, why)


def render_rgb(gaussians: Gaussians, camera: Camera, rasterizer: Rasterizer | None = None) -> torch.Tensor:
    """The colour render [H, W, 3] float32 in [0, 1] on black, without gradients: what
    evaluation scores and what the prior's sampler starts from. ``rasterizer``: default the one
    for the Gaussians' device (``rasterizer_for``)."""
    rasterizer = rasterizer_for(gaussians.means.device) if rasterizer is None else rasterizer
    with torch.no_grad():
        return rasterizer(gaussians, camera, outputs=("rgb",))["rgb"].to(torch.float32).clamp(0.0, 1.0)
