"""Flow alignment (the variant "align", off by default): warped photos moved onto the render by dense
optical flow, before they are blended. Measured: it closes most of the misplacement on
statuette but costs the courtyard's I* 0.6 dB, where the render is a blur the flow cannot lock
onto (docs/bootstrap.md), so it stays off.

A photo warped with a stage-I depth lands a few pixels off where that depth is a few percent
wrong (statuette: the warps score 2.9 dB below the render on the very pixels they are trusted
on). The render is blurred but in place. DIS optical flow from the render to each warp finds,
per pixel, where the warp holds the render's content; the warp is resampled there, so the
photo's detail and colour arrive where the render has that content. A shift beyond
``max_shift_px`` is not a misplacement but a different surface (or no match): that pixel is
left untrusted.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import cv2
import numpy as np
import torch

from ...errors import InputError
from ..options import VARIANT, option
from ..variants import Variant
from ..warp import WarpResult

# DIS works on an image pyramid with 8 x 8 patches: smaller images have no pyramid to search.
MIN_SIZE_PX = 16
DEFAULT_MAX_SHIFT_PX = 3.0


def _grey_u8(image: np.ndarray) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> [H, W] uint8 luminance (what DIS takes)."""
    grey = image @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return np.clip(np.rint(grey * 255.0), 0, 255).astype(np.uint8)


def flow_to(reference: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """Dense flow [H, W, 2] (x, y in pixels) with reference(p) ~ moving(p + flow(p)).

    reference, moving: [H, W, 3] float32 in [0, 1], the same size (at least MIN_SIZE_PX).
    """
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    flow = dis.calc(_grey_u8(reference), _grey_u8(moving), None)
    # DIS returns finite flow; a non-finite value (never seen) must not reach remap.
    return np.where(np.isfinite(flow), flow, 0.0).astype(np.float32)


def align_warp(render: torch.Tensor, warp: WarpResult, max_shift_px: float = DEFAULT_MAX_SHIFT_PX) -> WarpResult:
    """``warp`` resampled where the flow from ``render`` to it points -> WarpResult of the same size.

    render: [H, W, 3] in [0, 1]; warp.image [H, W, 3], warp.mask [H, W, 1] in {0, 1}. The warp's
    untrusted pixels take the render's colour before the flow is computed (holes must not pull
    the flow), and a pixel stays trusted only where the flow moved it by at most
    ``max_shift_px`` and every bilinear tap it reads was trusted. A warp with nothing trusted,
    or an image under MIN_SIZE_PX, is returned unchanged.
    """
    if not max_shift_px > 0:
        raise ValueError(f"max_shift_px must be positive, got {max_shift_px}")
    h, w = warp.mask.shape[:2]
    if h < MIN_SIZE_PX or w < MIN_SIZE_PX or not bool((warp.mask > 0).any()):
        return warp
    reference = render.detach().cpu().float().numpy()
    mask = warp.mask.detach().cpu().float().numpy()
    moving = np.where(mask > 0, warp.image.detach().cpu().float().numpy(), reference)
    flow = flow_to(reference, moving)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    map_x, map_y = xs + flow[..., 0], ys + flow[..., 1]
    image = cv2.remap(moving, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # The mask is resampled the same way: a pixel whose taps include an untrusted one reads below 1.
    taps_trusted = cv2.remap(mask[..., 0], map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                             borderValue=0.0) >= 1.0 - 1e-4
    small = np.hypot(flow[..., 0], flow[..., 1]) <= max_shift_px
    trusted = (taps_trusted & small)[..., None]
    out_mask = torch.from_numpy(trusted.astype(np.float32)).to(warp.mask)
    return WarpResult(image=torch.from_numpy(image * trusted).to(warp.image), mask=out_mask)


@dataclass(frozen=True)
class Align(Variant):
    """The blend's warps moved onto the render by optical flow before they are blended."""

    NAME: ClassVar[str] = "align"

    max_shift_px: float = option(DEFAULT_MAX_SHIFT_PX, "a warped pixel the flow moves farther than this is "
                                                       "left untrusted (a different surface, not a misplacement)",
                                 "px", VARIANT)

    def check(self, source: str, config) -> None:
        if not self.max_shift_px > 0:
            raise InputError(f"{source}: max_shift_px must be a positive number of pixels, got {self.max_shift_px}")

    def adjust_warps(self, context, warps: list[WarpResult]) -> list[WarpResult]:
        """Each warp aligned to the view's render (view_supervision.ViewContext.render)."""
        reference = context.render()
        return [align_warp(reference, warp, self.max_shift_px) for warp in warps]
