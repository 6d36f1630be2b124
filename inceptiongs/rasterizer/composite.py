"""Per-pixel front-to-back alpha compositing: the torch reference, tile-binned.

Implements the composite contract of docs/design.md exactly:

    power = 0.5 (a dx^2 + c dy^2) + b dx dy at pixel centres (i + 0.5, j + 0.5) (evaluated
    in a square-completed form that cannot round below zero: see _composite_chunk);
    alpha = min(ALPHA_MAX, opacity exp(-power)), skipped when power < 0 or alpha < ALPHA_MIN;
    Gaussians in ascending depth (ties by index); before adding one, if T (1 - alpha) <
    TRANSMITTANCE_MIN the pixel is finished; image = sum T_i alpha_i values_i, alpha = 1 - T.

How it is vectorised: every (tile, Gaussian) pair the footprint boxes touch is listed and
sorted by (tile, depth rank). Each tile's list is consumed in rounds of ROUND_GAUSSIANS.
Within a round, the tiles (ordered by how many Gaussians they hold, most first) are
processed in steps, each padded to its first tile's count, so a step evaluates a
[tiles, TILE_SIZE^2 pixels, K] block of alphas with at most PIXEL_PAIR_BUDGET entries.
Alphas become transmittances through a cumulative product. The stop rule is a mask on that
product: T after a Gaussian only decreases, so "T (1 - alpha) >= TRANSMITTANCE_MIN" holds
on a prefix, exactly the Gaussians the sequential loop would add. T and a per-pixel
"finished" flag carry from round to round, and a tile whose pixels are all finished drops
out. Under autograd, large images checkpoint each step (recompute it in the backward pass)
so saved activations do not grow with the number of pairs. Gradients are plain autograd:
exact.
"""

from __future__ import annotations

import math

import torch
from torch.utils.checkpoint import checkpoint

from .backend import use_numba
from ..constants import ALPHA_MAX, ALPHA_MIN, TILE_SIZE, TRANSMITTANCE_MIN

# Upper bound on (pixel, Gaussian) evaluations held at once (~ tens of MB per saved tensor).
# A tile with more than PIXEL_PAIR_BUDGET / TILE_SIZE^2 Gaussians is handled in rounds.
PIXEL_PAIR_BUDGET = 1 << 21
# Gaussians per tile handled in one round; after each round, tiles whose pixels have all
# reached the stop rule drop out (dense scenes saturate long before their lists end).
ROUND_GAUSSIANS = 128
# Above this many (pixel, Gaussian) evaluations per image, steps are checkpointed.
CHECKPOINT_ABOVE = 1 << 23
# min(ALPHA_MAX, x) applied in log space.
LOG_ALPHA_MAX = math.log(ALPHA_MAX)


def composite(means2d, conics, opacities, values, depths, extents, width: int, height: int,
              backend: str = "auto"):
    """Dispatch to the numba fast path or the torch reference; arguments as in
    :func:`composite_torch`. "auto" picks numba when it imports and tensors are on the CPU."""
    if use_numba(backend, "composite", means2d):
        from .composite_numba import composite_numba
        return composite_numba(means2d, conics, opacities, values, depths, extents, width, height)
    return composite_torch(means2d, conics, opacities, values, depths, extents, width, height)


def composite_torch(means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor,
                    values: torch.Tensor, depths: torch.Tensor, extents: torch.Tensor,
                    width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """means2d [M, 2], conics [M, 3], opacities [M], values [M, C], depths [M], extents [M, 2]
    -> (image [H, W, C], alpha [H, W, 1]). Differentiable w.r.t. means2d, conics, opacities
    and values; depths and extents only order and bin."""
    device, dtype = values.device, values.dtype
    channels = values.shape[1]
    tiles_x = -(-width // TILE_SIZE)
    tiles_y = -(-height // TILE_SIZE)
    tile_ids, gaussian_ids, tile_counts = _bin_pairs(means2d.detach(), extents.detach(),
                                                     depths.detach(), tiles_x, tiles_y)

    n_tiles = tiles_x * tiles_y
    pixels = TILE_SIZE * TILE_SIZE
    image_tiles = torch.zeros(n_tiles, pixels, channels, dtype=dtype, device=device)
    trans_tiles = torch.ones(n_tiles, pixels, dtype=dtype, device=device)
    if gaussian_ids.numel() > 0:
        busy_tiles, image_busy, trans_busy = _composite_busy_tiles(
            tile_ids, gaussian_ids, tile_counts, tiles_x, means2d, conics, opacities, values)
        image_tiles = image_tiles.index_put((busy_tiles,), image_busy)
        trans_tiles = trans_tiles.index_put((busy_tiles,), trans_busy)

    image = _untile(image_tiles, tiles_x, tiles_y)[:height, :width]
    alpha = 1.0 - _untile(trans_tiles[..., None], tiles_x, tiles_y)[:height, :width]
    return image, alpha


def _bin_pairs(means2d: torch.Tensor, extents: torch.Tensor, depths: torch.Tensor,
               tiles_x: int, tiles_y: int):
    """List the (tile, Gaussian) pairs of the footprint boxes, sorted by tile then depth.

    means2d [M, 2], extents [M, 2], depths [M] -> (tile_ids [P], gaussian_ids [P],
    tile_counts [tiles] int64), both id lists sorted by (tile, depth rank).
    """
    device = means2d.device
    m = means2d.shape[0]
    lo = torch.floor((means2d - extents) / TILE_SIZE)
    hi = torch.floor((means2d + extents) / TILE_SIZE)
    # Clamp in floating point first: a footprint 1e8 px wide must not overflow int64 maths.
    x0 = lo[:, 0].clamp(0, tiles_x - 1).long()
    x1 = hi[:, 0].clamp(0, tiles_x - 1).long()
    y0 = lo[:, 1].clamp(0, tiles_y - 1).long()
    y1 = hi[:, 1].clamp(0, tiles_y - 1).long()
    inside = (hi[:, 0] >= 0) & (lo[:, 0] <= tiles_x - 1) & (hi[:, 1] >= 0) & (lo[:, 1] <= tiles_y - 1)
    span_x = x1 - x0 + 1
    counts = torch.where(inside, span_x * (y1 - y0 + 1), torch.zeros_like(span_x))

    gaussian_ids = torch.repeat_interleave(torch.arange(m, device=device), counts)
    # Position of each pair inside its Gaussian's box, row-major over the box.
    starts = torch.cumsum(counts, 0) - counts
    local = torch.arange(gaussian_ids.numel(), device=device) - starts[gaussian_ids]
    tx = x0[gaussian_ids] + local % span_x[gaussian_ids]
    ty = y0[gaussian_ids] + local // span_x[gaussian_ids]
    tile_ids = ty * tiles_x + tx

    # Depth rank: stable, so equal depths keep index order (the contract's tie rule).
    rank = torch.empty(m, dtype=torch.int64, device=device)
    rank[torch.sort(depths, stable=True).indices] = torch.arange(m, device=device)
    order = torch.argsort(tile_ids * m + rank[gaussian_ids])
    tile_ids, gaussian_ids = tile_ids[order], gaussian_ids[order]
    tile_counts = torch.bincount(tile_ids, minlength=tiles_x * tiles_y)
    return tile_ids, gaussian_ids, tile_counts


def _composite_busy_tiles(tile_ids, gaussian_ids, tile_counts, tiles_x, means2d, conics,
                          opacities, values):
    """Composite every tile that holds at least one pair.

    Returns (busy tile ids [B], image [B, TILE_SIZE^2, C], final transmittance [B, TILE_SIZE^2]).
    """
    device, dtype = values.device, values.dtype
    pixels = TILE_SIZE * TILE_SIZE
    busy_order = torch.argsort(tile_counts, descending=True, stable=True)
    busy_count = int((tile_counts > 0).sum())
    busy_tiles = busy_order[:busy_count]  # [B], most crowded first
    counts = tile_counts[busy_tiles]
    starts = torch.cumsum(tile_counts, 0)[busy_tiles] - counts  # first pair of each busy tile
    corners = torch.stack([busy_tiles % tiles_x, busy_tiles // tiles_x], -1).to(dtype) * TILE_SIZE

    # Row M of the parameter tables pads short rows: opacity below ALPHA_MIN, so its alpha
    # (<= opacity) is always skipped, and its log is finite (no NaN in any gradient).
    table_means = torch.cat([means2d, means2d.new_zeros(1, 2)])
    table_conics = torch.cat([conics, conics.new_tensor([[1.0, 0.0, 1.0]])])
    table_opacities = torch.cat([opacities, opacities.new_full((1,), 0.5 * ALPHA_MIN)])
    table_values = torch.cat([values, values.new_zeros(1, values.shape[1])])
    pad_id = means2d.shape[0]
    last_pair = gaussian_ids.numel() - 1

    counts_host = counts.tolist()
    per_round = max(1, min(ROUND_GAUSSIANS, PIXEL_PAIR_BUDGET // pixels))  # per tile and round
    total_work = sum(counts_host) * pixels
    # Recomputing in the backward pass costs a second forward; only worth it when keeping
    # every step's activations would take real memory.
    use_checkpoint = total_work > CHECKPOINT_ABOVE and torch.is_grad_enabled() and any(
        t.requires_grad for t in (means2d, conics, opacities, values))
    transmittance = torch.ones(busy_count, pixels, dtype=dtype, device=device)
    finished = torch.zeros(busy_count, pixels, dtype=torch.bool, device=device)
    image = torch.zeros(busy_count, pixels, values.shape[1], dtype=dtype, device=device)
    for first in range(0, counts_host[0], per_round):
        # Tiles with Gaussians left in this round (a prefix: counts are descending) whose
        # pixels are not all finished; a finished tile skips the rest of its list.
        candidates = _count_greater(counts_host, first)
        alive = torch.nonzero(~finished[:candidates].all(-1)).squeeze(-1)  # ascending
        if alive.numel() == 0:
            break
        alive_counts = counts[alive].tolist()
        images, trans_list, finished_list = [], [], []
        row0 = 0
        while row0 < len(alive_counts):
            # Rows are padded to the first (largest) row's count, so each step's padding is small.
            k = min(per_round, alive_counts[row0] - first)
            row1 = min(len(alive_counts), row0 + max(1, PIXEL_PAIR_BUDGET // (pixels * k)))
            rows = alive[row0:row1]
            slot = first + torch.arange(k, device=device)  # [k]
            valid = slot[None, :] < counts[rows, None]
            pair = torch.clamp_max(starts[rows, None] + slot[None, :], last_pair)
            ids = torch.where(valid, gaussian_ids[pair], torch.full_like(pair, pad_id))  # [rows, k]
            args = (corners[rows], ids, transmittance[rows], finished[rows],
                    table_means, table_conics, table_opacities, table_values)
            if use_checkpoint:
                out = checkpoint(_composite_chunk, *args, use_reentrant=False)
            else:
                out = _composite_chunk(*args)
            images.append(out[0])
            trans_list.append(out[1])
            finished_list.append(out[2])
            row0 = row1
        image = image.index_add(0, alive, torch.cat(images))
        transmittance = transmittance.index_put((alive,), torch.cat(trans_list))
        finished = finished.index_put((alive,), torch.cat(finished_list))
    return busy_tiles, image, transmittance


def _count_greater(descending: list[int], threshold: int) -> int:
    """How many leading entries of a descending list exceed ``threshold`` (binary search)."""
    lo, hi = 0, len(descending)
    while lo < hi:
        mid = (lo + hi) // 2
        if descending[mid] > threshold:
            lo = mid + 1
        else:
            hi = mid
    return lo


def _composite_chunk(corners, ids, transmittance, finished, table_means, table_conics,
                     table_opacities, table_values):
    """One step: rows of K depth-sorted Gaussians over their tile's pixels.

    corners [R, 2] (tile's top-left pixel corner), ids [R, K] (rows into the tables),
    transmittance [R, P] and finished [R, P] on entry (P = TILE_SIZE^2, row-major)
    -> (image [R, P, C], transmittance [R, P], finished [R, P]).

    The power is evaluated with the square completed on the larger diagonal entry of the
    conic (here a >= c; otherwise x and y swap roles):

        power = 0.5 a (dx + (b / a) dy)^2 + 0.5 max(c - b^2 / a, 0) dy^2.

    Mathematically this equals 0.5 (a dx^2 + c dy^2) + b dx dy; numerically it cannot go
    negative. The expanded form cancels catastrophically in float32 for needle-like
    Gaussians (a nearly singular conic) and turns slightly negative along the needle, where
    the contract's "power < 0 -> skip" rule would then drop the Gaussian exactly where it is
    densest. For the positive-definite conics the projection produces, the two forms differ
    only by rounding; a conic with no positive diagonal entry is skipped. Since |b / pivot| <= 1
    for a positive-definite conic, the form is also well conditioned for gradients.

    The tile's pixel grid makes everything except two [R, rows, cols, K] passes depend on the
    row or the column only, which keeps the number of full-size passes low.
    """
    rows, k = ids.shape
    mean = table_means[ids]  # [R, K, 2]
    a, b, c = table_conics[ids].unbind(-1)  # [R, K] each
    x_pivot = a >= c
    pivot = torch.where(x_pivot, a, c)
    valid = pivot > 0
    safe_pivot = torch.where(valid, pivot, torch.ones_like(pivot))
    ratio = b / safe_pivot  # |ratio| <= 1 for positive-definite conics
    remainder = torch.clamp_min(torch.where(x_pivot, c, a) - b * ratio, 0.0)
    ones, zeros = torch.ones_like(ratio), torch.zeros_like(ratio)
    # u = p_x dx + p_y dy with (p_x, p_y) = (1, ratio) or (ratio, 1); the remainder multiplies
    # dy^2 (x pivot) or dx^2 (y pivot).
    p_x, p_y = torch.where(x_pivot, ones, ratio), torch.where(x_pivot, ratio, ones)
    rem_x, rem_y = torch.where(x_pivot, zeros, remainder), torch.where(x_pivot, remainder, zeros)

    centres = torch.arange(TILE_SIZE, dtype=mean.dtype, device=mean.device) + 0.5  # [S]
    dx = corners[:, 0, None, None] + centres[None, :, None] - mean[:, None, :, 0]  # [R, S cols, K]
    dy = corners[:, 1, None, None] + centres[None, :, None] - mean[:, None, :, 1]  # [R, S rows, K]
    u = (p_x[:, None] * dx)[:, None, :, :] + (p_y[:, None] * dy)[:, :, None, :]  # [R, rows, cols, K]
    rest = (0.5 * rem_x[:, None] * dx * dx)[:, None, :, :] + (0.5 * rem_y[:, None] * dy * dy)[:, :, None, :]
    power = torch.addcmul(rest, (0.5 * safe_pivot)[:, None, None, :], u * u).reshape(rows, -1, k)  # [R, P, K]

    # alpha = min(ALPHA_MAX, opacity exp(-power)) as one exp of a clamped log.
    log_opacity = torch.log(table_opacities[ids])[:, None, :]  # opacities > 0
    alpha = torch.exp(torch.clamp_max(log_opacity - power, LOG_ALPHA_MAX))
    alpha = torch.where((alpha >= ALPHA_MIN) & valid[:, None, :], alpha, 0.0)  # the skip rule

    # T after each Gaussian; 1 - alpha >= 1 - ALPHA_MAX > 0, so the product never hits 0 early.
    after = transmittance[:, :, None] * torch.cumprod(1.0 - alpha, dim=-1)
    added = (after >= TRANSMITTANCE_MIN) & ~finished[:, :, None]
    before = torch.cat([transmittance[:, :, None], after[:, :, :-1]], dim=-1)
    weights = torch.where(added, before * alpha, 0.0)  # [R, P, K]
    image = torch.bmm(weights, table_values[ids])  # [R, P, C]

    # The prefix property makes "number added" index the last added Gaussian's T.
    n_added = added.sum(-1)  # [R, P]
    last = torch.gather(after, -1, (n_added - 1).clamp_min(0)[..., None])[..., 0]
    new_transmittance = torch.where(n_added > 0, last, transmittance)
    new_finished = finished | (after[..., -1] < TRANSMITTANCE_MIN)
    return image, new_transmittance, new_finished


def _untile(tiles: torch.Tensor, tiles_x: int, tiles_y: int) -> torch.Tensor:
    """[tiles_y * tiles_x, TILE_SIZE^2, C] -> [tiles_y * TILE_SIZE, tiles_x * TILE_SIZE, C]."""
    c = tiles.shape[-1]
    grid = tiles.reshape(tiles_y, tiles_x, TILE_SIZE, TILE_SIZE, c)
    return grid.permute(0, 2, 1, 3, 4).reshape(tiles_y * TILE_SIZE, tiles_x * TILE_SIZE, c)
