"""Free space stays free, and view-dependent colour only where it was observed.

Unstructured captures put cameras inside the scene, and a Gaussian fitted in the space the
training cameras look *through* (background pulled onto the camera rig) is invisible in the
photos it was fitted to but covers a held-out view from the rig. Three rules find them:

* a Gaussian whose ellipsoid holds a training camera centre (:func:`contains_camera`);
* a Gaussian in front of a camera's near bound and inside its image (:func:`before_near_bound`);
  the bound is per camera, from the sparse points' nearest depths (:func:`near_bounds`), since
  walk-through captures have real content close to some cameras and none near others;
* a Gaussian that every training view seeing it looks through: in each view it lies in front of
  the rendered surface at its own pixel (:class:`ViewStats`, gathered from the training renders).
  The surface is the scene's own, without the sky shell (:func:`surface_depth_features`): a
  half-transparent shell far behind a faint surface pulls the blended depth back past it.

:class:`ViewStats` also gathers the directions a Gaussian was seen from; their spread limits its
SH degree (:func:`allowed_sh_degree`): a Gaussian seen from one direction has no view-dependent
colour to fit, and higher bands there only learn the photo's noise and ring in other views.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..camera import Camera
from .point_projection import project_cloud
from ..constants import ALPHA_EPS, LOG_SCALE_MAX, LOG_SCALE_MIN, NEAR_PLANE, SH_MAX_DEGREE
from ..rasterizer.backend import use_numba
from ..rasterizer.projection import quat_to_rotation
from .free_space_numba import before_near_bound_numba, contains_camera_numba, near_a_camera_numba

# A camera needs this many sparse points in its image for a percentile to mean anything;
# with fewer it keeps only the renderer's NEAR_PLANE.
NEAR_MIN_POINTS = 8
# Gaussian-camera pairs evaluated at once in the [N, C] tests (float64 [pairs, 3] ~ 100 MB).
_PAIR_BUDGET = 1 << 22


def _camera_block(n: int) -> int:
    """Cameras per block so that n x block pairs stay within _PAIR_BUDGET (at least 1)."""
    return max(1, _PAIR_BUDGET // max(n, 1))


def camera_depths(points: np.ndarray, camera: Camera) -> np.ndarray:
    """Camera z of the ``points`` [P, 3] that project inside ``camera``'s image in front of it: [Q]."""
    _, z, inside = project_cloud(points, camera)
    return z[inside]


def near_bounds(cameras: list[Camera], points: np.ndarray, percentile: float, margin: float) -> np.ndarray:
    """Per-camera near bound [C]: ``margin`` x the ``percentile``-th percentile of the depths of
    the sparse points in its image; NEAR_PLANE for a camera with fewer than NEAR_MIN_POINTS.

    A low percentile rather than the minimum: one mis-triangulated point in front of a camera
    would otherwise open the whole space before it.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    out = np.full(len(cameras), NEAR_PLANE)
    for index, camera in enumerate(cameras):
        depths = camera_depths(points, camera)
        if depths.size >= NEAR_MIN_POINTS:
            out[index] = max(NEAR_PLANE, margin * float(np.percentile(depths, percentile)))
    return out


def _poses(cameras: list[Camera], dtype, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    rotations = torch.tensor(np.stack([c.rotation for c in cameras]), dtype=dtype, device=device)   # [C, 3, 3]
    translations = torch.tensor(np.stack([c.world_to_camera[:3, 3] for c in cameras]), dtype=dtype, device=device)
    return rotations, translations


def _intrinsics_table(cameras: list[Camera], device=None) -> torch.Tensor:
    """[C, 6] float64: fx, fy, cx, cy, width, height."""
    return torch.tensor([[c.fx, c.fy, c.cx, c.cy, c.width, c.height] for c in cameras], dtype=torch.float64,
                        device=device)


def before_near_bound(means: torch.Tensor, cameras: list[Camera], near: torch.Tensor,
                      backend: str = "auto") -> torch.Tensor:
    """means [N, 3], near [C] -> [N] bool: the centre lies in front of some camera (0 < z) and
    closer than its near bound, and projects inside its image. ``backend``: as the rasterizer's
    (:mod:`inceptiongs.rasterizer.backend`); "auto" takes the numba loop for CPU tensors."""
    out = torch.zeros(means.shape[0], dtype=torch.bool, device=means.device)
    if means.shape[0] == 0 or not cameras:
        return out
    means = means.detach().to(torch.float64)
    near = near.to(means.device, torch.float64)
    rotations, translations = _poses(cameras, torch.float64, means.device)                 # [C, 3, 3], [C, 3]
    intrinsics = _intrinsics_table(cameras, means.device)
    if use_numba(backend, "free space", means):
        return torch.from_numpy(before_near_bound_numba(
            *(np.ascontiguousarray(t.cpu().numpy()) for t in (means, rotations, translations, near, intrinsics))))
    step = _camera_block(means.shape[0])
    for start in range(0, len(cameras), step):
        block = slice(start, start + step)
        r, t, k = rotations[block], translations[block], intrinsics[block]
        x, y, z = (means @ r[:, axis, :].T + t[:, axis] for axis in range(3))              # [N, B] each
        close = (z > 0) & (z < near[block])
        safe_z = torch.where(z > 0, z, torch.ones_like(z))  # only read where z > 0
        u = k[:, 0] * x / safe_z + k[:, 2]
        v = k[:, 1] * y / safe_z + k[:, 3]
        inside = (u >= 0) & (u < k[:, 4]) & (v >= 0) & (v < k[:, 5])
        out |= (close & inside).any(1)
    return out


def near_a_camera(means: torch.Tensor, centers: torch.Tensor, radii: torch.Tensor,
                  backend: str = "auto") -> torch.Tensor:
    """means [N, 3], centers [C, 3], radii [C] -> [N] bool: the Gaussian's centre lies within some
    camera's radius of that camera's centre, in any direction.

    The near bound only speaks for the space in front of a camera; beside and behind it no photo
    constrains anything, and training fills that space with background seen at a grazing angle by
    cameras across the rig (on the demo at 2400 steps: sky-coloured disks 0.01-0.1 units from a
    training camera, drawn over held-out views 001/007 on the same rig as fog, 8 and 11 dB). The
    camera and its operator stand there: it is free in every direction. ``backend`` as
    :func:`before_near_bound`'s (the numba loop stops at the first camera that flags a Gaussian;
    the torch path writes an [N, B] distance table per block of cameras: at 200k Gaussians and
    197 cameras 1.3 s, every maintenance step).
    """
    n = means.shape[0]
    out = torch.zeros(n, dtype=torch.bool, device=means.device)
    if n == 0 or centers.shape[0] == 0:
        return out
    means = means.detach().to(torch.float64)
    centers = centers.to(means.device, torch.float64)
    radii = radii.to(means.device, torch.float64)
    if use_numba(backend, "free space", means):
        return torch.from_numpy(near_a_camera_numba(
            *(np.ascontiguousarray(t.cpu().numpy()) for t in (means, centers, radii))))
    step = _camera_block(n)
    for start in range(0, centers.shape[0], step):
        distances = torch.cdist(means, centers[start:start + step])                           # [N, B]
        out |= (distances < radii[None, start:start + step]).any(1)
    return out


def nearest_camera_distance(means: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """Distance of each of means [N, 3] to the nearest of centers [C >= 1, 3]: [N] (cameras in
    blocks of _PAIR_BUDGET pairs, as the other [N, C] tests)."""
    nearest = torch.full((means.shape[0],), float("inf"), dtype=means.dtype, device=means.device)
    step = _camera_block(means.shape[0])
    for start in range(0, centers.shape[0], step):
        block = torch.cdist(means, centers[start:start + step].to(means.device, means.dtype))                # [N, B]
        nearest = torch.minimum(nearest, block.amin(1))
    return nearest


def contains_camera(means: torch.Tensor, log_scales: torch.Tensor, quats: torch.Tensor,
                    centers: torch.Tensor, sigmas: float, backend: str = "auto") -> torch.Tensor:
    """means [N, 3], log_scales [N, 3], quats [N, 4] (w, x, y, z), centers [C, 3] -> [N] bool:
    some camera centre lies within ``sigmas`` standard deviations (Mahalanobis) of the Gaussian.
    ``backend`` as :func:`before_near_bound`'s.

    The Mahalanobis distance is at least the Euclidean one over the largest scale, so only
    centres within ``sigmas`` x that scale can qualify: the torch path finds those pairs with
    one squared-distance matrix per block of cameras and tests only them exactly."""
    n = means.shape[0]
    out = torch.zeros(n, dtype=torch.bool, device=means.device)
    if n == 0 or centers.shape[0] == 0:
        return out
    means = means.detach().to(torch.float64)
    centers = centers.to(means.device, torch.float64)
    if use_numba(backend, "free space", means):
        return torch.from_numpy(contains_camera_numba(
            *(np.ascontiguousarray(t.detach().cpu().to(torch.float64).numpy())
              for t in (means, log_scales, quats, centers)), sigmas))
    # Clamped like the renderer's: exp(+-log_scale) stays finite.
    log_scales = log_scales.detach().to(torch.float64).clamp(LOG_SCALE_MIN, LOG_SCALE_MAX)
    reach_sq = (sigmas * torch.exp(log_scales.amax(1))) ** 2                                  # [N]
    means_sq = means.square().sum(-1)                                                        # [N]
    step = _camera_block(n)
    for start in range(0, centers.shape[0], step):
        block = centers[start:start + step]
        block_sq = block.square().sum(-1)
        # |m - c|^2 as |m|^2 + |c|^2 - 2 m.c (a matrix product); it cancels, so the pre-test
        # is widened by far more than its rounding error: it may only let extra pairs through.
        scale = means_sq[:, None] + block_sq[None]
        dist_sq = scale - 2.0 * (means @ block.T)                                            # [N, B]
        rows, cols = torch.nonzero(dist_sq < reach_sq[:, None] + 1e-9 * scale, as_tuple=True)
        if rows.numel() == 0:
            continue
        hit = _mahalanobis_sq(block[cols] - means[rows], log_scales[rows], quats.detach()[rows]) < sigmas * sigmas
        out[rows[hit]] = True
    return out


def _mahalanobis_sq(offsets: torch.Tensor, log_scales: torch.Tensor, quats: torch.Tensor) -> torch.Tensor:
    """|R^T d / s|^2 for offsets d [P, 3] (float64), clamped log scales [P, 3], quats [P, 4] -> [P].
    A quaternion too short to normalise counts as the identity rotation (the renderer's rule)."""
    rotation = quat_to_rotation(quats.to(torch.float64))                                     # [P, 3, 3]
    local = (rotation * offsets[:, :, None]).sum(1) * torch.exp(-log_scales)                # R^T d / s
    return local.square().sum(-1)


@dataclass
class ViewStats:
    """Per-Gaussian statistics of the training renders that see it, kept row for row through
    densification (``index`` re-selects them as the parameters are re-selected).

    seen [N]: views since the last prune in which it was on or in front of the rendered surface
    at its pixel; through [N]: of those, views in which it was in front of that surface by the
    tolerance (the view looks through it); dir_sum [N, 3] and dir_count [N]: the unit viewing
    directions (camera to Gaussian) over the whole run; sh_degree [N]: the SH degree allowed so far.
    """

    seen: torch.Tensor
    through: torch.Tensor
    dir_sum: torch.Tensor
    dir_count: torch.Tensor
    sh_degree: torch.Tensor

    @staticmethod
    def zeros(n: int, device: torch.device | str = "cpu") -> "ViewStats":
        return ViewStats(torch.zeros(n, device=device), torch.zeros(n, device=device),
                         torch.zeros(n, 3, device=device), torch.zeros(n, device=device),
                         torch.zeros(n, dtype=torch.int64, device=device))

    def to(self, device: torch.device | str) -> "ViewStats":
        return ViewStats(**{name: t.to(device) for name, t in self.tensors().items()})

    def tensors(self) -> dict[str, torch.Tensor]:
        return {"seen": self.seen, "through": self.through, "dir_sum": self.dir_sum,
                "dir_count": self.dir_count, "sh_degree": self.sh_degree}

    def index(self, rows: torch.Tensor) -> "ViewStats":
        """The statistics of rows ``rows`` (int [M] or bool [N]), e.g. a clone copies its source's."""
        return ViewStats(**{name: t[rows].clone() for name, t in self.tensors().items()})

    def reset_window(self) -> None:
        self.seen.zero_()
        self.through.zero_()


def accumulate_views(stats: ViewStats, means: torch.Tensor, camera: Camera, depth: torch.Tensor,
                     radii: torch.Tensor, tolerance: float) -> None:
    """Add one training render. means [N, 3]; depth [H, W, 1] (the render's expected depth, 0 where
    nothing was drawn); radii [N] (0 = culled). A Gaussian counts when visible, its centre projects
    into the image onto a drawn pixel, and it is not behind that pixel's depth by ``tolerance``
    (relative): then it is seen, and seen through when in front of it by ``tolerance``."""
    with torch.no_grad():
        means = means.detach().to(torch.float64)
        rotation = torch.as_tensor(camera.rotation, dtype=torch.float64, device=means.device)
        translation = torch.as_tensor(camera.world_to_camera[:3, 3], dtype=torch.float64, device=means.device)
        local = means @ rotation.T + translation
        z = local[:, 2]
        front = z > NEAR_PLANE
        safe_z = torch.where(front, z, torch.ones_like(z))  # only read where z > NEAR_PLANE > 0
        u = camera.fx * local[:, 0] / safe_z + camera.cx
        v = camera.fy * local[:, 1] / safe_z + camera.cy
        inside = front & (radii > 0) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
        cols = u.clamp(0, camera.width - 1).long()
        rows = v.clamp(0, camera.height - 1).long()
        surface = depth.detach()[..., 0].to(torch.float64)[rows, cols]
        drawn = inside & (surface > 0)
        seen = drawn & (z <= surface * (1.0 + tolerance))
        through = seen & (z < surface * (1.0 - tolerance))
        stats.seen += seen.to(stats.seen.dtype)
        stats.through += through.to(stats.through.dtype)
        center = torch.as_tensor(camera.center, dtype=torch.float64, device=means.device)
        directions = torch.nn.functional.normalize(means - center, dim=-1)  # a centre on the camera: 0 vector
        stats.dir_sum += torch.where(seen[:, None], directions, torch.zeros_like(directions)).to(stats.dir_sum.dtype)
        stats.dir_count += seen.to(stats.dir_count.dtype)


def surface_depth_features(means: torch.Tensor, background: torch.Tensor, camera: Camera) -> torch.Tensor:
    """Per-Gaussian values [N, 2] whose alpha-blend over a view is (sum w z, sum w) over the
    scene's own Gaussians only: means [N, 3], background [N] bool (the sky shell's rows get 0, 0).
    :func:`surface_depth` turns the blend into the surface depth that :func:`accumulate_views` reads.

    Why not the render's depth: a shell Gaussian (depth ~ the shell's radius) behind a faint
    surface holds most of a pixel's weight early on, so the blended depth lies far behind the
    surface and every view "looks through" it. On the README courtyard the rule then removed
    the north facade's Gaussians (288 -> 31 in the facade's middle by step 180) and the close
    views of it rendered the shell's blurred copy of the facade instead."""
    with torch.no_grad():
        rotation = torch.as_tensor(camera.rotation, dtype=means.dtype, device=means.device)
        translation = torch.as_tensor(camera.world_to_camera[:3, 3], dtype=means.dtype, device=means.device)
        z = means.detach() @ rotation[2] + translation[2]                  # camera z, [N]
        scene = (~background).to(means.dtype)
        return torch.stack([z * scene, scene], 1)


def surface_depth(blended: torch.Tensor) -> torch.Tensor:
    """[H, W, 2] blend of :func:`surface_depth_features` -> [H, W, 1] the scene's expected depth,
    0 where its own Gaussians cover less than ALPHA_EPS (no surface there: only the shell, or
    nothing)."""
    weight = blended[..., 1:2]
    covered = weight >= ALPHA_EPS
    # Divided only where covered (weight >= ALPHA_EPS > 0).
    return torch.where(covered, blended[..., 0:1] / weight.clamp_min(ALPHA_EPS), torch.zeros_like(weight))


def render_surface_depth(gaussians, camera: Camera, sphere: torch.Tensor | None, rasterizer=None) -> torch.Tensor:
    """[H, W, 1] camera z of the scene's own surface at ``camera``, without gradients: the render's
    depth without a shell (sphere None), else :func:`surface_depth` of the scene's Gaussians
    only (shell rows: :func:`~inceptiongs.train.sky.in_background`). 0 where nothing covers.

    Stage II warps photos with this depth. With the shell's depth blended in, the courtyard's
    scarce views had 4 % of their pixels within 5 % of the true depth (36 % without it) and
    the warps' occlusion test rejected 95 % of them."""
    from ..rasterizer.interface import cpu_rasterizer
    from .sky import in_background

    rasterizer = cpu_rasterizer() if rasterizer is None else rasterizer
    with torch.no_grad():
        if sphere is None:
            return rasterizer(gaussians, camera, outputs=("depth",))["depth"].float()
        features = surface_depth_features(gaussians.means, in_background(gaussians.means.detach(), sphere), camera)
        out = rasterizer(gaussians, camera, outputs=("features",), features=features)
        return surface_depth(out["features"]).float()


def seen_through(stats: ViewStats, min_views: int) -> torch.Tensor:
    """[N] bool: seen by at least ``min_views`` training renders since the last prune, and looked
    through in every one of them."""
    return (stats.seen >= min_views) & (stats.through >= stats.seen)


def angular_spread_deg(stats: ViewStats) -> torch.Tensor:
    """[N] half-angle (degrees) of the viewing directions: arccos of their mean resultant length
    (two directions at +-a give exactly a; one direction 0; never seen 0)."""
    count = stats.dir_count.clamp_min(1.0)  # never seen: dir_sum is 0, so the length is 0 / 1
    resultant = (stats.dir_sum.norm(dim=-1) / count).clamp(0.0, 1.0)
    spread = torch.rad2deg(torch.arccos(resultant))
    return torch.where(stats.dir_count > 0, spread, torch.zeros_like(spread))


def allowed_sh_degree(stats: ViewStats, deg_per_degree: float, min_views: int) -> torch.Tensor:
    """[N] int64: floor(spread / deg_per_degree) capped at SH_MAX_DEGREE; 0 below ``min_views`` sightings."""
    degree = torch.floor(angular_spread_deg(stats) / deg_per_degree).clamp(0, SH_MAX_DEGREE).long()
    return torch.where(stats.dir_count >= min_views, degree, torch.zeros_like(degree))


def sh_rest_mask(degree: torch.Tensor, rest: int) -> torch.Tensor:
    """degree [N] int -> [N, rest, 1] float: 1 where coefficient k + 1 (band floor(sqrt(k + 1)))
    is within the Gaussian's degree."""
    bands = torch.floor(torch.sqrt(torch.arange(1, rest + 1, dtype=torch.float64,
                                                device=degree.device))).long()               # [rest]
    return (bands[None, :] <= degree[:, None]).to(torch.float32)[..., None]



def floater_fraction(depth: torch.Tensor, near: float) -> float:
    """Fraction of a render's pixels drawn closer than the camera's near bound: depth [H, W, 1]
    (expected depth, 0 where nothing was drawn): the floater measure on training views."""
    drawn = depth[..., 0] > 0
    return float((drawn & (depth[..., 0] < near)).to(torch.float64).mean())
