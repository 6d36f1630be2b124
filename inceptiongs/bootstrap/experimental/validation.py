"""Where does the blend beat the render? A leave-one-source-out estimate, per region of the scene.

A virtual view has no photo, so its I* cannot be scored where it is used. A training photo can
stand in for one: I* is built at the photo's own pose from the *other* training photos only
(the loop's own machinery, ``supervise.supervise_view``, with the photo excluded from the
sources and from the splatted depth), and compared with the photo, pixel by pixel, over the
pixels the blend trusts. The model's render at that pose is compared with the same photo on the
same pixels. Per region, the margin is

    margin (dB) = 10 log10(render's summed squared error / blend's summed squared error)
                = PSNR(blend) - PSNR(render) over the region's validated pixels,

positive where the blend is the better picture of the photo. Regions no held-out pixel covers
have no evidence (NaN), never a margin of zero.

Fairness. The blend never saw the photo it is scored against. The render did: the model was
fitted to every training photo, so at a training pose its error is lower than at a pose it was
not trained at (where virtual views lie). The comparison is therefore biased towards the render
only: the margin is a lower bound on what the blend gains at an unseen pose. A positive margin
cannot come from that bias, and the loop adds virtual gradient only where the margin is
positive (placement.py), so the bias can only withhold a repair, never cause a wrong one. The
split's held-out photos would give an unbiased render error, but they are what every run is
scored on: steering the repair with them would grade it on the answers, so they are not used.

Regions. The margins are kept in a coarse world-space voxel grid (:class:`EvidenceGrid`), each
validated pixel back-projected with the model's surface depth at its photo (the depth that also
places the warps). A virtual view is at another pose: tiles of a photo's image cannot be looked
up from there without geometry, while a voxel is found from any pose by its own depth. The cells
are coarse (at most ``VOXELS_PER_SIDE`` over the evidence's robust extent, halved until the
median occupied cell pools ``MIN_VOXEL_PIXELS``) so that each gives a stable dB figure and a few
percent of depth error lands in the same cell.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import torch

from ...camera import Camera
from ..config import BootstrapConfig
from ..source_depth import depth_from_training_views
from ..supervise import supervise_view
from ..view_supervision import ViewContext, ViewSupervision
from ..virtual_views import DEFAULT_K, nearest_training_views
from ...pinhole import unproject

# Cells per side of the evidence's extent (its longest axis).
VOXELS_PER_SIDE = 16
# A cell needs this many validated pixels for a margin (a dB figure of fewer is noise).
MIN_VOXEL_PIXELS = 20
# The extent is taken between these quantiles of the validated points, so a few floaters or
# sky pixels do not stretch the grid (points outside it carry no evidence).
EXTENT_QUANTILES = (0.01, 0.99)
# Squared-error floor per pixel before the ratio: two perfect pictures score 0 dB, not NaN.
_SE_FLOOR = 1e-10


@dataclass
class PhotoEvidence:
    """One held-out training photo: ``index`` into the cameras, the ``sources`` its I* was built
    from, the validated pixels' world points [N, 3] float64 and squared errors [N] (blend's and
    render's, mean over channels), and ``reason`` when it has none."""

    index: int
    sources: list[int]
    points: torch.Tensor
    blend_se: torch.Tensor
    render_se: torch.Tensor
    reason: str | None = None

    @property
    def pixels(self) -> int:
        return int(self.points.shape[0])

    def margin_db(self) -> float | None:
        """The photo's overall margin over its validated pixels (None: no pixels)."""
        return margin_db(self.render_se.sum(), self.blend_se.sum(), self.pixels) if self.pixels else None


def margin_db(render_sse, blend_sse, count) -> float:
    """PSNR(blend) - PSNR(render) from summed squared errors over ``count`` pixels (scalars;
    each floored so the ratio and the log are always finite)."""
    floor = _SE_FLOOR * max(float(count), 1.0)
    return float(10.0 * np.log10((float(render_sse) + floor) / (float(blend_sse) + floor)))


def squared_error(image: torch.Tensor, photo: torch.Tensor) -> torch.Tensor:
    """[H, W, 3] x 2 -> [H, W] float64 mean squared error over channels (NaN where either is)."""
    return ((image.double() - photo.double()) ** 2).mean(-1)


def world_points(depth: torch.Tensor, camera: Camera) -> torch.Tensor:
    """depth [H, W, 1] camera z (0 = none) -> [H, W, 3] float64 world points (meaningless where
    the depth is not positive; callers mask those out)."""
    z = depth[..., 0].double()
    z = torch.where(torch.isfinite(z) & (z > 0), z, torch.zeros_like(z))
    local = unproject(z, camera)
    to_world = torch.as_tensor(camera.camera_to_world, dtype=torch.float64)
    return local @ to_world[:3, :3].T + to_world[:3, 3]


def validation_photos(target: Camera, cameras: Sequence[Camera], train: Sequence[int], k: int = DEFAULT_K,
                      limit: int | None = None) -> list[int]:
    """The training photos the evidence is measured at: the k nearest to ``target`` (the loop's
    sources there) and each one's k nearest others (the neighbours that would replace it),
    nearest to the target first, at most ``limit``."""
    nearest = nearest_training_views(target, cameras, list(train), k)
    chosen = list(nearest)
    for index in nearest:
        others = [i for i in train if i != index]
        chosen.extend(i for i in nearest_training_views(cameras[index], cameras, others, k) if i not in chosen)
    ranked = nearest_training_views(target, cameras, chosen, len(chosen))
    return ranked if limit is None else ranked[:limit]


def leave_one_out_blend(index: int, cameras: Sequence[Camera], train: Sequence[int], photos: dict,
                        config: BootstrapConfig, depth_of: Callable[[Camera], torch.Tensor],
                        render_of: Callable[[Camera], torch.Tensor]) -> tuple[ViewSupervision, list[int]]:
    """I* at photo ``index``'s own pose from the other training photos (the loop's
    ``supervise_view``; the photo is neither a source nor one of the splatted depths) ->
    (the supervision, its sources)."""
    camera = cameras[index]
    others = [i for i in train if i != index]
    sources = nearest_training_views(camera, cameras, others, config.k or DEFAULT_K) if config.blending else []
    context = ViewContext(config, camera, render_of(camera), sources, cameras, photos, depth_of, render_of,
                          source_depth=lambda: depth_from_training_views(camera, cameras, others, config.splat_views,
                                                                         depth_of))
    return supervise_view(context), sources


def photo_evidence(index: int, cameras: Sequence[Camera], train: Sequence[int], photos: dict,
                   config: BootstrapConfig, depth_of: Callable[[Camera], torch.Tensor],
                   render_of: Callable[[Camera], torch.Tensor]) -> PhotoEvidence:
    """The validated pixels of photo ``index`` (module doc): trusted by its leave-one-out blend,
    with depth, every value finite."""
    camera = cameras[index]
    empty = torch.zeros(0, dtype=torch.float64)
    supervision, sources = leave_one_out_blend(index, cameras, train, photos, config, depth_of, render_of)
    if not sources:
        return PhotoEvidence(index, [], empty.reshape(0, 3), empty, empty,
                             "no other training photo to blend (or blending is off)")
    photo = torch.as_tensor(photos[index]).float()
    depth = torch.as_tensor(depth_of(camera)).double()
    blend_se = squared_error(supervision.image, photo)
    render_se = squared_error(torch.as_tensor(render_of(camera)).float(), photo)
    points = world_points(depth, camera)
    valid = ((supervision.mask[..., 0] > 0) & (depth[..., 0] > 0) & torch.isfinite(blend_se)
             & torch.isfinite(render_se) & torch.isfinite(points).all(-1))
    if not bool(valid.any()):
        return PhotoEvidence(index, sources, empty.reshape(0, 3), empty, empty,
                             "none of its pixels is trusted in the blend of the other photos")
    return PhotoEvidence(index, sources, points[valid], blend_se[valid], render_se[valid])


@dataclass
class EvidenceGrid:
    """Margins per world voxel: ``origin`` [3] float64 (the grid's lower corner), ``voxel`` (cell
    size, scene units), ``dims`` (cells per axis), ``margin_db`` [V] float64 (NaN: no evidence) and
    ``pixels`` [V] int64 (validated pixels per cell), V = prod(dims), x-major."""

    origin: np.ndarray
    voxel: float
    dims: tuple[int, int, int]
    margin_db: torch.Tensor
    pixels: torch.Tensor
    photos: list[dict] = field(default_factory=list)

    def cells(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points [..., 3] -> (flat cell index [...] int64, inside [...] bool); non-finite points are outside."""
        scaled = (points.double() - torch.as_tensor(self.origin)) / self.voxel
        finite = torch.isfinite(scaled).all(-1)
        ijk = torch.floor(torch.where(torch.isfinite(scaled), scaled, torch.full_like(scaled, -1.0))).long()
        dims = torch.as_tensor(self.dims)
        inside = finite & (ijk >= 0).all(-1) & (ijk < dims).all(-1)
        ijk = torch.where(inside[..., None], ijk, torch.zeros_like(ijk))
        return (ijk[..., 0] * dims[1] + ijk[..., 1]) * dims[2] + ijk[..., 2], inside

    def occupied(self, points: torch.Tensor) -> torch.Tensor:
        """points [..., 3] -> [V] bool: the cells at least one of them falls in."""
        index, inside = self.cells(points)
        hit = torch.zeros(self.margin_db.numel(), dtype=torch.bool)
        hit[index[inside]] = True
        return hit

    def lookup(self, points: torch.Tensor) -> torch.Tensor:
        """points [..., 3] -> margin [...] float64 (NaN: outside the grid or no evidence)."""
        index, inside = self.cells(points)
        margin = self.margin_db[index]
        return torch.where(inside, margin, torch.full_like(margin, float("nan")))

    def summary(self) -> dict:
        """What summary.json records of the estimate."""
        known = ~torch.isnan(self.margin_db)
        values = self.margin_db[known]
        return {"voxel": self.voxel, "dims": list(self.dims), "voxels_with_evidence": int(known.sum()),
                "voxels_positive": int((values > 0).sum()),
                "median_margin_db": float(values.median()) if values.numel() else None,
                "photos": self.photos}


def grid_extent(points: torch.Tensor, voxels_per_side: int) -> tuple[np.ndarray, float, tuple[int, int, int]]:
    """[N, 3] points (N >= 1) -> (origin [3], voxel size > 0, dims) covering their robust extent."""
    low = torch.quantile(points, EXTENT_QUANTILES[0], dim=0).numpy()
    high = torch.quantile(points, EXTENT_QUANTILES[1], dim=0).numpy()
    longest = float((high - low).max())
    # Coincident points (a degenerate extent) still get cells of a positive size.
    voxel = longest / voxels_per_side if longest > 0 else 1.0
    dims = tuple(int(d) for d in np.maximum(np.ceil((high - low) / voxel + 1e-9), 1).astype(int))
    return low, voxel, dims


def evidence_grid(evidence: Sequence[PhotoEvidence], voxels_per_side: int = VOXELS_PER_SIDE,
                  min_pixels: int = MIN_VOXEL_PIXELS) -> EvidenceGrid | None:
    """The photos' validated pixels pooled per voxel (module doc); None when none has any."""
    if voxels_per_side < 1 or min_pixels < 1:
        raise ValueError(f"voxels_per_side and min_pixels must be >= 1, got {voxels_per_side}, {min_pixels}")
    with_pixels = [e for e in evidence if e.pixels]
    if not with_pixels:
        return None
    points = torch.cat([e.points for e in with_pixels])
    blend = torch.cat([e.blend_se for e in with_pixels])
    render = torch.cat([e.render_se for e in with_pixels])
    # Coarser until a typical occupied cell pools enough pixels (few or small photos).
    side = voxels_per_side
    while True:
        origin, voxel, dims = grid_extent(points, side)
        grid = EvidenceGrid(origin, voxel, dims, torch.empty(0), torch.empty(0),
                            photos=[photo_record(e) for e in evidence])
        index, inside = grid.cells(points)
        size = int(np.prod(dims))
        counts = torch.zeros(size, dtype=torch.int64).index_add_(0, index[inside], torch.ones_like(index[inside]))
        occupied = counts[counts > 0]
        if side == 1 or occupied.numel() == 0 or float(occupied.double().median()) >= min_pixels:
            break
        side = max(side // 2, 1)
    blend_sum = torch.zeros(size, dtype=torch.float64).index_add_(0, index[inside], blend[inside])
    render_sum = torch.zeros(size, dtype=torch.float64).index_add_(0, index[inside], render[inside])
    floor = _SE_FLOOR * counts.clamp_min(1).double()
    margin = 10.0 * torch.log10((render_sum + floor) / (blend_sum + floor))
    grid.margin_db = torch.where(counts >= min_pixels, margin, torch.full_like(margin, float("nan")))
    grid.pixels = counts
    return grid


def photo_record(evidence: PhotoEvidence) -> dict:
    margin = evidence.margin_db()
    return {"view": evidence.index, "sources": evidence.sources, "pixels": evidence.pixels,
            "margin_db": margin, **({"reason": evidence.reason} if evidence.reason else {})}


def view_margins(grid: EvidenceGrid | None, camera: Camera, depth: torch.Tensor) -> torch.Tensor:
    """The evidence under each pixel of a view: depth [H, W, 1] (0 = none) -> [H, W] float64
    margin (NaN: no depth, or no evidence where the pixel lands)."""
    depth = torch.as_tensor(depth)
    if grid is None:
        return torch.full(depth.shape[:2], float("nan"), dtype=torch.float64)
    margins = grid.lookup(world_points(depth, camera))
    has_depth = torch.isfinite(depth[..., 0]) & (depth[..., 0] > 0)
    return torch.where(has_depth, margins, torch.full_like(margins, float("nan")))


def seen_cells(grid: EvidenceGrid | None, camera: Camera, depth: torch.Tensor) -> torch.Tensor | None:
    """[V] bool: the cells a view's pixels with depth (depth [H, W, 1]) fall in; None without a grid."""
    if grid is None:
        return None
    depth = torch.as_tensor(depth)
    has_depth = torch.isfinite(depth[..., 0]) & (depth[..., 0] > 0)
    return grid.occupied(world_points(depth, camera)[has_depth])


def evidence_weights(margins: torch.Tensor) -> torch.Tensor:
    """[H, W] margins -> [H, W, 1] float32 loss weight: 1 where the blend is validated to beat the
    render (margin > 0), 0 where it is not or where there is no evidence (NaN compares False)."""
    return (margins > 0).float()[..., None]


def measure_evidence(photo_indices: Sequence[int], cameras: Sequence[Camera], train: Sequence[int], photos: dict,
                     config: BootstrapConfig, depth_of: Callable[[Camera], torch.Tensor],
                     render_of: Callable[[Camera], torch.Tensor]) -> EvidenceGrid | None:
    """The leave-one-out evidence of the given training photos, pooled in a grid (None: none)."""
    return evidence_grid([photo_evidence(i, cameras, train, photos, config, depth_of, render_of)
                          for i in photo_indices])
