"""Where a block of a run in blocks starts: the Gaussians of the whole run's global stage.

A block's training photos often see far past its cell (an object captured from all around: every
block sees nearly all of it). What they see outside the cell must already be there when the
block starts, or the block fits it with Gaussians densified inside its cell, which the merge
keeps and which float in front of every other view. So a block starts from the global stage's
Gaussians inside its cell widened by its margin, the sky shell's (far beyond every cell, a few
thousand) and (``start_keep`` "seen") every one its training photos see; "cell" leaves out
those. The merge keeps only the block's Gaussians inside its cell.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ..camera import Camera
from ..errors import InputError
from ..gaussians import Gaussians, gaussians_from_params
from ..runs.checkpoint import latest_checkpoint, load_newest_checkpoint
from .partition import Cell, block_plane, visible_points
from .sky import in_background


def start_rows(means: np.ndarray, block, cameras: Sequence[Camera], background: np.ndarray) -> np.ndarray:
    """means [N, 3] (the scene's normalised frame), background [N] bool (the sky shell's rows)
    -> [N] bool: the rows block ``block`` (runs.config.Block) starts from (module doc);
    ``cameras``: the block's training cameras."""
    keep = Cell(*block.cell).contains(block_plane(block).coordinates(means), block.margin) | background
    if block.start_keep == "cell":
        return keep
    for camera in cameras:
        keep |= visible_points(camera, means)
    return keep


def with_sh_degree(gaussians: Gaussians, degree: int) -> Gaussians:
    """``gaussians`` with SH coefficients up to ``degree``: cut above it, zeros added up to it."""
    count = (degree + 1) ** 2
    sh = gaussians.sh[:, :count]
    if sh.shape[1] < count:
        sh = torch.cat([sh, sh.new_zeros(sh.shape[0], count - sh.shape[1], 3)], dim=1)
    return Gaussians(gaussians.means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits, sh)


def block_start(block, cameras: Sequence[Camera], sh_degree: int, log
                ) -> tuple[Gaussians, torch.Tensor | None, str]:
    """The block's first Gaussians from the last checkpoint of ``block.start`` (the global
    stage's run folder) -> (Gaussians with ``sh_degree``, the global stage's sky sphere [4] or
    None, one line saying what was taken). cameras: the block's training cameras."""
    folder = Path(block.start)
    if latest_checkpoint(folder) is None:
        raise InputError(f"{folder}: the global stage block {block.index} starts from has no checkpoint; run the "
                         f"same command again to train it")
    path, payload = load_newest_checkpoint(folder, warn=log)
    gaussians = gaussians_from_params(payload["params"]).detach().to("cpu")
    sky = payload.get("sky")
    background = in_background(gaussians.means, sky).numpy()
    rows = start_rows(gaussians.means.double().numpy(), block, cameras, background)
    start = with_sh_degree(gaussians.subset(torch.from_numpy(rows)), sh_degree)
    return (start, sky, f"starts from {len(start)} of the {len(gaussians)} Gaussians of the global stage "
                        f"({path.name}: {block.start_keep} of block {block.index})")
