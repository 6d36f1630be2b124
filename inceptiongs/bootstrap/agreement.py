"""Do the warped photos deserve to replace the render at a virtual view?

Warped photos carry every error of the depth they were placed with, and the render carries the
model's. Neither can be scored at a virtual view (it has no photo), but they can be scored
against each other. The K warps of one view are K independent witnesses of the same pixels:

    source agreement = mean PSNR between two warps, over the pixels both trust (every pair);
    render agreement = mean PSNR between the render and one warp, over its trusted pixels.

When the photos agree with each other better than (or nearly as well as) each agrees with the
render, the render is what disagrees: the view is supervised by the photos. When the render
agrees with every photo better than the photos agree among themselves, the render is already
their best consensus and the warps would only add their misplacement: the view is left out
of the refinement (its steps go back to the photos).

Measured over 31 held-out views of three scenes, as if they were virtual views (blend of the
3 nearest photos warped with the splatted depth, over the render; docs/bootstrap.md): the
margin (source - render agreement) was +0.5 to +7.2 dB on the README courtyard, where
the blend beat the render against the held-out photo on every view (+0.22 to +2.05 dB);
-0.6 to +1.0 dB on bonsai, where it beat the render on every view (+0.07 to +1.21 dB); and
-1.5 to -3.2 dB on statuette, where it lost on 6 of 8 views (down to -1.73 dB) and gained
at most +0.11. Hence the threshold -1 dB.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch

from ..evaluation.metrics import mse
from .warp import WarpResult

# Views whose margin (dB) is below this are left out of the refinement (module doc).
DEFAULT_AGREEMENT_MIN_DB = -1.0
# A comparison needs this many pixels in common, or it is not made.
MIN_COMMON_PIXELS = 50
# MSE floor before the logarithm: identical images score 100 dB, not infinity.
_MSE_FLOOR = 1e-10


def masked_psnr(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> float | None:
    """PSNR (dB, peak 1) of a, b [h, w, 3] over mask [h, w] bool; None below MIN_COMMON_PIXELS."""
    count = int(mask.sum())
    if count < MIN_COMMON_PIXELS:
        return None
    error = float(mse(a.float(), b.float(), mask))
    return 10.0 * math.log10(1.0 / max(error, _MSE_FLOOR))


def agreement_margin_db(render: torch.Tensor, warps: Sequence[WarpResult]) -> float | None:
    """Source agreement minus render agreement (module doc), in dB. render: [h, w, 3];
    warps: WarpResults of the same size. None when no two warps share MIN_COMMON_PIXELS
    trusted pixels (nothing to compare the render with)."""
    trusted = [w.mask[..., 0] > 0 for w in warps]
    images = [w.image for w in warps]
    pairs = [masked_psnr(images[a], images[b], trusted[a] & trusted[b])
             for a in range(len(warps)) for b in range(a + 1, len(warps))]
    pairs = [p for p in pairs if p is not None]
    renders = [masked_psnr(render, image, mask) for image, mask in zip(images, trusted)]
    renders = [r for r in renders if r is not None]
    if not pairs or not renders:
        return None
    return sum(pairs) / len(pairs) - sum(renders) / len(renders)
