"""LPIPS (Zhang et al., 2018, AlexNet variant) as the project's own network definition, its
weights read as plain tensors.

A weights file is a ``torch.save``d dict of tensors with exactly the keys and shapes of
:func:`lpips_shapes` and nothing else; it is read with ``torch.load(weights_only=True)``, which
builds tensors and never runs code from the file. A TorchScript file is refused: running one can
create and overwrite files, and a bootstrap's config or checkpoint, which can come from someone
else, names this file. ``scripts/lpips_weights.py`` makes such a file from the published
AlexNet and LPIPS linear-layer state dicts (also read with ``weights_only=True``).

The distance: both images [1, 3, H, W] in [-1, 1] are shifted and scaled per channel (the
constants LPIPS was trained with), passed through AlexNet's five conv+ReLU stages; at each stage
the features are normalised to unit length per pixel, their squared difference weighted per
channel by the stage's non-negative 1x1 layer and averaged over the pixels; the five averages are
summed.
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F

from ..errors import InputError
from ..io.pickles import file_names_code

# LPIPS's input normalisation (per channel, for images in [-1, 1]).
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
# AlexNet's conv stages: (in, out, kernel, stride, padding); a 3x3/2 max-pool precedes stages 2 and 3.
STAGES = ((3, 64, 11, 4, 2), (64, 192, 5, 1, 2), (192, 384, 3, 1, 1), (384, 256, 3, 1, 1), (256, 256, 3, 1, 1))
POOL_BEFORE = (1, 2)
# Added to each feature vector's length before dividing by it: a pixel whose features are all 0
# (ReLU) gives 0 / eps = 0, not NaN. The value LPIPS itself uses.
NORM_EPS = 1e-10
# AlexNet's strides and pools leave no feature pixel for an image side under this; smaller
# images are scaled up to it first.
MIN_SIDE = 32


def lpips_shapes() -> dict[str, tuple[int, ...]]:
    """The weights file's keys and their shapes."""
    shapes: dict[str, tuple[int, ...]] = {}
    for i, (cin, cout, k, _, _) in enumerate(STAGES):
        shapes[f"conv{i}.weight"] = (cout, cin, k, k)
        shapes[f"conv{i}.bias"] = (cout,)
        shapes[f"lin{i}.weight"] = (1, cout, 1, 1)
    return shapes


class Lpips(torch.nn.Module):
    """The LPIPS distance with given weights: forward(a, b) [1, 3, H, W] in [-1, 1] -> [1]."""

    def __init__(self, weights: dict[str, torch.Tensor]):
        super().__init__()
        for name, tensor in weights.items():
            self.register_buffer(name.replace(".", "_"), tensor.float())
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1))

    def stages(self, x: torch.Tensor) -> list[torch.Tensor]:
        """x [B, 3, H, W] normalised -> the five stages' features."""
        out = []
        for i, (_, _, _, stride, padding) in enumerate(STAGES):
            if i in POOL_BEFORE:
                x = F.max_pool2d(x, kernel_size=3, stride=2)
            x = F.relu(F.conv2d(x, getattr(self, f"conv{i}_weight"), getattr(self, f"conv{i}_bias"),
                                stride=stride, padding=padding))
            out.append(x)
        return out

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        a, b = at_least_min_side(a), at_least_min_side(b)
        features_a = self.stages((a - self.shift) / self.scale)
        features_b = self.stages((b - self.shift) / self.scale)
        total = a.new_zeros(a.shape[0])
        for i, (fa, fb) in enumerate(zip(features_a, features_b)):
            fa = fa / (fa.pow(2).sum(1, keepdim=True).sqrt() + NORM_EPS)
            fb = fb / (fb.pow(2).sum(1, keepdim=True).sqrt() + NORM_EPS)
            weighted = F.conv2d((fa - fb).pow(2), getattr(self, f"lin{i}_weight"))
            total = total + weighted.mean(dim=(1, 2, 3))
        return total


def at_least_min_side(x: torch.Tensor) -> torch.Tensor:
    """x [B, 3, H, W], scaled up bilinearly so that its shorter side is MIN_SIDE when it is
    shorter (AlexNet's strides and pools leave no feature pixel below that)."""
    short = min(x.shape[-2:])
    if short >= MIN_SIDE:
        return x
    size = [max(MIN_SIDE, round(side * MIN_SIDE / short)) for side in x.shape[-2:]]
    return F.interpolate(x, size=size, mode="bilinear", align_corners=False)


def is_torchscript(path: Path) -> bool:
    """A zip archive holding TorchScript code (torch.jit.save writes code/ and constants.pkl)."""
    import zipfile
    if not zipfile.is_zipfile(path):
        return False
    with zipfile.ZipFile(path) as archive:
        names = archive.namelist()
    return any("/code/" in name or name.endswith("constants.pkl") for name in names)


def read_weights(path: str | Path, what: str = "LPIPS weights") -> dict[str, torch.Tensor]:
    """A dict of tensors from ``path`` (torch.save), read with weights_only=True; a TorchScript
    file, a pickle carrying anything but tensors and plain containers, or a file torch cannot
    read is an InputError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} file does not exist")
    if is_torchscript(path):
        raise InputError(f"{path}: a TorchScript file; {what} must be plain tensors (torch.save of a dict "
                         f"of tensors, see scripts/lpips_weights.py): TorchScript can run code, so it is never loaded")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many kinds for a foreign file
        if file_names_code(path, str(exc)):
            raise InputError(f"{path}: holds Python objects, not only tensors; {what} are read as plain "
                             f"tensors and this file is refused") from None
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if "Weights only load failed" in first:   # torch's advice to load it unsafely is not repeated
            first = "the weights-only loader refused it"
        raise InputError(f"{path}: not a {what} file ({first[:200]})") from None
    if not isinstance(data, dict) or not all(isinstance(v, torch.Tensor) for v in data.values()):
        raise InputError(f"{path}: {what} must be a dict of tensors")
    return data


def load_lpips(path: str | Path) -> Lpips:
    """The LPIPS network with the weights in ``path`` (keys and shapes of lpips_shapes(); the
    linear layers' weights must be finite and non-negative, the conv weights finite)."""
    weights = read_weights(path)
    expected = lpips_shapes()
    missing = sorted(set(expected) - set(weights))
    extra = sorted(set(weights) - set(expected))
    if missing or extra:
        what = f"lacks {missing[0]!r}" if missing else f"has an unknown key {extra[0]!r}"
        raise InputError(f"{path}: not AlexNet-LPIPS weights: {what} ({len(expected)} keys expected)")
    for name, shape in expected.items():
        tensor = weights[name]
        if tuple(tensor.shape) != shape:
            raise InputError(f"{path}: {name} has shape {tuple(tensor.shape)}, expected {shape}")
        if not torch.isfinite(tensor).all():
            raise InputError(f"{path}: {name} holds a non-finite value")
        if name.startswith("lin") and (tensor < 0).any():
            raise InputError(f"{path}: {name} has a negative weight (LPIPS's linear layers are non-negative)")
    return Lpips(weights).eval()
