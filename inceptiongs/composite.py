"""Per-pixel front-to-back alpha compositing: the torch reference, tile-binned.

Implements the composite contract of docs/design.md exactly:

    power = 0.5 (a dx^2 + c dy^2) + b dx dy at pixel centres (i + 0.5, j + 0.5);
    alpha = min(ALPHA_MAX, opacity exp(-power)), skipped when power < 0 or alpha < ALPHA_MIN;
    Gaussians in ascending depth (ties by index); before adding one, if T (1 - alpha) <
    TRANSMITTANCE_MIN the pixel is finished; image = sum T_i alpha_i values_i, alpha = 1 - T.

How it is vectorised: every (tile, Gaussian) pair the footprint boxes touch is listed and
sorted by (tile, depth rank). Tiles are ordered by how many Gaussians they hold, most first,
so in "round" r (the r-th chunk of CHUNK Gaussians of every tile) the tiles still busy are a
prefix of that order. A round evaluates [tiles, TILE_SIZE^2 pixels, CHUNK] alphas, turns them
into transmittances with a cumulative product and carries T and a "finished" flag into the
next round. The stop rule is a mask on the cumulative product: T after a Gaussian only
decreases, so "T (1 - alpha) >= TRANSMITTANCE_MIN" holds on a prefix, exactly the Gaussians
the sequential loop would add. Memory is bounded by PIXEL_PAIR_BUDGET per step, and under
autograd each step is checkpointed (recomputed in the backward pass) so saved activations
do not grow with the number of pairs. Gradients are plain autograd: exact.
"""

from __future__ import annotations

import torch
from torch.utils.checkpoint import checkpoint

from .constants import ALPHA_MAX, ALPHA_MIN, TILE_SIZE, TRANSMITTANCE_MIN

# Gaussians per tile evaluated in one step; more per tile are handled in further rounds.
CHUNK = 64
# Upper bound on (pixel, Gaussian) evaluations held at once (~ tens of MB per saved tensor).
PIXEL_PAIR_BUDGET = 1 << 21


def composite(means2d, conics, opacities, values, depths, extents, width: int, height: int,
              backend: str = "auto"):
    """Dispatch to the numba fast path or the torch reference; arguments as in
    :func:`composite_torch`. "auto" picks numba when it imports and tensors are on the CPU."""
    if backend not in ("auto", "torch", "numba"):
        raise ValueError(f"composite backend must be auto, torch or numba, got {backend!r}")
    if backend in ("auto", "numba"):
        try:
            from .composite_numba import composite_numba
        except ImportError:
            if backend == "numba":
                raise
        else:
            if backend == "numba" or means2d.device.type == "cpu":
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

    # Pixel centres of each busy tile: [B, pixels, 2].
    local = torch.arange(pixels, device=device)
    offsets = torch.stack([local % TILE_SIZE, local // TILE_SIZE], -1).to(dtype) + 0.5
    corners = torch.stack([busy_tiles % tiles_x, busy_tiles // tiles_x], -1).to(dtype) * TILE_SIZE
    pixel_xy = corners[:, None, :] + offsets[None]

    # Row M of the padded parameter table is a dummy with opacity 0: padding slots never add.
    table_means = torch.cat([means2d, means2d.new_zeros(1, 2)])
    table_conics = torch.cat([conics, conics.new_zeros(1, 3)])
    table_opacities = torch.cat([opacities, opacities.new_zeros(1)])
    table_values = torch.cat([values, values.new_zeros(1, values.shape[1])])
    pad_id = means2d.shape[0]

    counts_host = counts.tolist()
    n_rounds = -(-counts_host[0] // CHUNK)
    transmittance = torch.ones(busy_count, pixels, dtype=dtype, device=device)
    finished = torch.zeros(busy_count, pixels, dtype=torch.bool, device=device)
    round_images, round_trans, round_active = [], [], []
    chunk_slots = torch.arange(CHUNK, device=device)
    use_checkpoint = torch.is_grad_enabled() and any(
        t.requires_grad for t in (means2d, conics, opacities, values))
    rows_per_step = max(1, PIXEL_PAIR_BUDGET // (pixels * CHUNK))
    for r in range(n_rounds):
        # Tiles still holding Gaussians at this round: a prefix, since counts are descending.
        active = _count_greater(counts_host, r * CHUNK)
        slot = r * CHUNK + chunk_slots  # [CHUNK]
        valid = slot[None, :] < counts[:active, None]
        pair = torch.where(valid, starts[:active, None] + slot[None, :], torch.zeros_like(valid, dtype=torch.int64))
        ids = torch.where(valid, gaussian_ids[pair], torch.full_like(pair, pad_id))  # [active, CHUNK]

        images, trans_list, finished_list = [], [], []
        for row0 in range(0, active, rows_per_step):
            row1 = min(active, row0 + rows_per_step)
            args = (pixel_xy[row0:row1], ids[row0:row1], transmittance[row0:row1],
                    finished[row0:row1], table_means, table_conics, table_opacities, table_values)
            if use_checkpoint:
                out = checkpoint(_composite_chunk, *args, use_reentrant=False)
            else:
                out = _composite_chunk(*args)
            images.append(out[0])
            trans_list.append(out[1])
            finished_list.append(out[2])
        round_images.append(torch.cat(images))
        transmittance = torch.cat(trans_list)
        finished = torch.cat(finished_list)
        round_trans.append(transmittance)
        round_active.append(active)

    # Sum each tile's rounds, last round first: round r covers tiles [0, active_r).
    image = round_images[-1]
    trans_final = round_trans[-1]
    for r in range(n_rounds - 2, -1, -1):
        done_here = round_active[r + 1]
        image = torch.cat([round_images[r][:done_here] + image, round_images[r][done_here:]])
        trans_final = torch.cat([trans_final, round_trans[r][done_here:]])
    return busy_tiles, image, trans_final


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


def _composite_chunk(pixel_xy, ids, transmittance, finished, table_means, table_conics,
                     table_opacities, table_values):
    """One step: rows of up to CHUNK depth-sorted Gaussians over their tile's pixels.

    pixel_xy [R, P, 2], ids [R, K] (rows into the tables), transmittance [R, P] and
    finished [R, P] on entry -> (image [R, P, C], transmittance [R, P], finished [R, P]).
    """
    mean = table_means[ids]  # [R, K, 2]
    conic = table_conics[ids]  # [R, K, 3]
    dx = pixel_xy[:, :, None, 0] - mean[:, None, :, 0]  # [R, P, K]
    dy = pixel_xy[:, :, None, 1] - mean[:, None, :, 1]
    a, b, c = conic[:, None, :, 0], conic[:, None, :, 1], conic[:, None, :, 2]
    power = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    negative = power < 0
    # exp(-power) of a negative power can overflow; those pixels are skipped anyway and the
    # zeroed power keeps the discarded branch (and its gradient) finite.
    power = torch.where(negative, torch.zeros_like(power), power)
    alpha = torch.clamp_max(table_opacities[ids][:, None, :] * torch.exp(-power), ALPHA_MAX)
    skip = negative | (alpha < ALPHA_MIN)
    alpha = torch.where(skip, torch.zeros_like(alpha), alpha)

    # T after each Gaussian; 1 - alpha >= 1 - ALPHA_MAX > 0, so the product never hits 0 early.
    after = transmittance[:, :, None] * torch.cumprod(1.0 - alpha, dim=-1)
    added = (after >= TRANSMITTANCE_MIN) & ~finished[:, :, None]
    before = torch.cat([transmittance[:, :, None], after[:, :, :-1]], dim=-1)
    weights = torch.where(added, before * alpha, torch.zeros_like(alpha))  # [R, P, K]
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
