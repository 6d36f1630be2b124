"""Coverage of a scene or a run: which points the cameras see, from which directions, which
views show what is seen least, and the figure (`inceptiongs coverage`, `inceptiongs info`).

- A scene folder: its sparse points (triangulated from the photos when it has none, as stage I
  would), every view a source; no occlusion test (there is no surface yet).
- A run folder: the Gaussians' centres (opaque ones), the training views as sources, and
  visibility tested against each view's rendered depth, so a wall hides what is behind it.

The pure geometry is ``inceptiongs.evaluation.coverage``.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..io.atomic import atomic_write_bytes
from . import coverage as cov

MAX_POINTS = 3000            # points sampled for the statistics (cost is points x views^2)
DEPTH_WIDTH = 96             # rendered depth maps for the occlusion test, pixels wide
OPAQUE_MIN = 0.2             # Gaussians below this opacity are not surface points
SCARCE_VIEWS_LISTED = 8
THIN_VIEWS = 3               # a point seen by fewer views than this is "thinly seen"


@dataclass
class Coverage:
    """Coverage statistics in the scene's normalised frame (see module doc)."""

    kind: str                         # "scene" or "run"
    point_source: str                 # what the points are
    cameras: list[Camera]
    sources: np.ndarray               # [N] bool: views that count as seen-from
    points: np.ndarray                # [P, 3]
    visible: np.ndarray               # [P, N] bool
    counts: np.ndarray                # [P] views per point
    radius_deg: np.ndarray            # [P] angular radius of those views
    scarcity: np.ndarray              # [N]
    frame: np.ndarray                 # [3, 3] rows east, north, up
    roi: tuple[np.ndarray, np.ndarray]
    in_region: np.ndarray             # [P] bool
    azimuth: np.ndarray               # [A] rad
    elevation: np.ndarray             # [E] rad
    density: np.ndarray               # [E, A] views per steradian per region point
    depth_test: bool
    groups: dict[str, list[int]] = field(default_factory=dict)   # run: "scarce"/"covered" held out


def compute(points: np.ndarray, cameras: list[Camera], sources: np.ndarray, depths=None,
            roi: tuple[np.ndarray, np.ndarray] | None = None, kind: str = "scene",
            point_source: str = "points", groups: dict | None = None) -> Coverage:
    """Every statistic for points [P, 3] seen by cameras (normalised frame)."""
    points = np.asarray(points, np.float64)
    visible = cov.visibility_matrix(points, cameras, depths)
    centers = np.array([c.center for c in cameras])
    directions = cov.view_directions(points, centers)
    frame = cov.hemisphere_frame(cov.up_vector(cameras))
    lo, hi = roi if roi is not None else cov.robust_bounds(points)
    in_region = np.all((points >= lo) & (points <= hi), axis=1)
    azimuth, elevation, grid = cov.hemisphere_grid()
    samples, weights = cov.region_directions(directions, visible & sources[None, :], in_region, frame)
    return Coverage(kind, point_source, list(cameras), sources, points, visible, cov.view_counts(visible & sources),
                    cov.angular_radius_deg(directions, visible & sources),
                    cov.view_scarcity(directions, visible, sources, resolution=cov.view_resolution(points, cameras)),
                    frame, (lo, hi), in_region, azimuth, elevation, cov.directional_density(samples, weights, grid),
                    depths is not None, dict(groups or {}))


def _subsample(points: np.ndarray, count: int, seed: int) -> np.ndarray:
    if len(points) <= count:
        return points
    return points[np.random.default_rng(seed).choice(len(points), count, replace=False)]


def _roi_normalised(roi, normalization) -> tuple[np.ndarray, np.ndarray] | None:
    """A box given in the original frame -> the normalised frame (a translation and a positive
    scale: still axis-aligned)."""
    if roi is None:
        return None
    lo, hi = np.minimum(roi[:3], roi[3:]), np.maximum(roi[:3], roi[3:])
    return normalization.to_normalized(np.asarray(lo)), normalization.to_normalized(np.asarray(hi))


def scene_coverage(scene, roi=None, max_points: int = MAX_POINTS, seed: int = 0, triangulate: bool = True,
                   log: Callable[[str], None] = lambda message: None) -> Coverage:
    """Coverage of a loaded Scene from its sparse points (triangulated when it has none and
    ``triangulate``); every view is a source. InputError when there are no points."""
    points, source = scene.points, "sparse points"
    if not len(points) and triangulate:
        from ..scene.photo_store import photo_tensor
        from ..train.triangulate import training_points

        views = list(range(len(scene.cameras)))
        # One photo at a time, from the decoded-photo cache.
        points, _, _ = training_points(scene, views, lambda i: photo_tensor(scene, i), True, log)
        source = "points triangulated from the photos"
    if not len(points):
        raise InputError(f"{scene.root}: no sparse points to measure coverage on")
    return compute(_subsample(points, max_points, seed), list(scene.cameras), np.ones(len(scene.cameras), bool),
                   roi=_roi_normalised(roi, scene.normalization), kind="scene", point_source=source)


def run_coverage(run_dir: str | Path, roi=None, max_points: int = MAX_POINTS, seed: int = 0,
                 depth_width: int = DEPTH_WIDTH, log: Callable[[str], None] = lambda message: None,
                 rasterizer=None, progress: bool = False) -> Coverage:
    """Coverage of a run: opaque Gaussian centres, training views as sources, occlusion from
    each view's depth rendered at ``depth_width`` pixels wide by ``rasterizer`` (default: the
    one the run's recorded device resolves to, inceptiongs.rasterizer.interface.resolve_device);
    ``progress``: a bar over the views (a 300-view town took minutes on two cores)."""
    import sys

    import torch
    from tqdm import tqdm

    from ..rasterizer.interface import resolve_device
    from ..runs.load import load_run
    from .protocols import Split

    gaussians, scene, config = load_run(run_dir)
    if rasterizer is None:
        rasterizer = resolve_device(config.device, f"{Path(run_dir) / 'config.json'}: device").rasterizer
    split = Split.load(Path(run_dir) / "split.json", scene.cameras)
    opacity = torch.sigmoid(gaussians.opacity_logits.reshape(-1)).numpy()
    if not len(opacity):
        raise InputError(f"{run_dir}: the run has no Gaussians")
    # The sky shell's Gaussians (4 x the scene's extent away, opaque from their start) are no
    # surface of the scene: on a town trained briefly they were most of the opaque ones, and the
    # map measured the sky around the town instead of the town.
    scene_part = ~shell_rows(gaussians.means, scene, split, config).numpy()
    if not scene_part.any():
        raise InputError(f"{run_dir}: the run has no Gaussians inside its sky shell")
    opacity = opacity[scene_part]
    # A barely trained run (every opacity still near its initial 0.1) keeps its more opaque half.
    points = gaussians.means.numpy()[scene_part][opacity >= min(OPAQUE_MIN, float(np.median(opacity)))]
    depths = []
    log(f"rendering depth for {len(scene.cameras)} views")
    with torch.no_grad():
        for camera in tqdm(scene.cameras, desc="coverage: depth", unit="view", file=sys.stderr, leave=False,
                           disable=not progress):
            small = camera.scaled(min(1.0, depth_width / camera.width))
            depths.append(rasterizer(gaussians, small, outputs=("depth",))["depth"][..., 0].cpu().numpy())
    sources = np.zeros(len(scene.cameras), bool)
    sources[split.train] = True
    return compute(_subsample(points, max_points, seed), list(scene.cameras), sources, depths,
                   roi=_roi_normalised(roi, scene.normalization), kind="run", point_source="opaque Gaussian centres",
                   groups={"scarce": list(split.scarce_test), "covered": list(split.covered_test)})


def shell_rows(means, scene, split, config):
    """[N] bool torch: the rows of ``means`` [N, 3] (normalised frame) that lie in the run's sky
    shell, the sphere stage I placed it on (inceptiongs.train.sky.shell_geometry of the training
    cameras and the scene's sparse points); all False for a run without a shell, or one whose
    scene has no sparse points (its shell was placed around triangulated points, not known here)."""
    import torch

    from ..train.sky import in_background, shell_geometry

    if not config.free_space.sky_shell or not len(scene.points) or not len(split.train):
        return torch.zeros(len(means), dtype=torch.bool)
    centre, radius = shell_geometry([scene.cameras[i] for i in split.train], scene.points)
    return in_background(means, torch.tensor([*centre, radius], dtype=means.dtype))


def summary(c: Coverage, listed: int = SCARCE_VIEWS_LISTED) -> dict:
    """JSON-able figures: views per point, thinly seen fraction, hemisphere density, the views
    whose content is seen least."""
    counts = c.counts[c.in_region] if c.in_region.any() else c.counts
    density = c.density
    peak = float(density.max())
    # Cell areas on the sphere: cos(elevation) d(elevation) d(azimuth).
    area = np.cos(c.elevation)[:, None] * np.ones_like(density)
    order = cov.scarcest_views(c.scarcity, listed)
    return {
        "points": int(len(c.points)),
        "point_source": c.point_source,
        "occlusion_tested": c.depth_test,
        "views": int(len(c.cameras)),
        "source_views": int(c.sources.sum()),
        "views_per_point": {"median": float(np.median(counts)), "p10": float(np.percentile(counts, 10)),
                            "p90": float(np.percentile(counts, 90))},
        "thinly_seen_fraction": float(np.mean(counts < THIN_VIEWS)),
        "thin_threshold_views": THIN_VIEWS,
        "angular_radius_deg_median": float(np.median(c.radius_deg)),
        "hemisphere": {
            "up": c.frame[2].tolist(),
            "peak_views_per_sr": peak,
            "mean_views_per_sr": float((density * area).sum() / area.sum()),
            # Share of the hemisphere (by area) seen at under 10 % of the peak density.
            "sparse_fraction": float((area * (density < 0.1 * peak)).sum() / area.sum()) if peak > 0 else 1.0,
        },
        "scarcest_views": [{"name": c.cameras[i].name, "index": int(i), "scarcity": round(float(c.scarcity[i]), 4)}
                           for i in order],
    }


def plot(c: Coverage, out_path: str | Path, title: str = "") -> None:
    """Three panels written as a PNG: bird's-eye view (points coloured by views, camera centres
    and headings, the region box), the hemisphere's viewing density (polar, zenith at the centre,
    azimuth as in the bird's-eye view), and the scarcest views' scores."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    if Path(out_path).suffix.lower() != ".png":
        raise InputError(f"{out_path}: the coverage figure must be a .png file")
    figure = Figure(figsize=(16, 5.2), dpi=100)
    top = figure.add_subplot(1, 3, 1)
    polar = figure.add_subplot(1, 3, 2, projection="polar")
    bars = figure.add_subplot(1, 3, 3)

    centers = np.array([cam.center for cam in c.cameras])
    _plot_from_above(figure, top, c, centers)
    _plot_hemisphere(figure, polar, c, centers)
    _plot_scarcest(bars, c)
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", bbox_inches="tight")  # the legend sits below the axes
    atomic_write_bytes(out_path, buffer.getvalue())


def _plot_from_above(figure, top, c: Coverage, centers: np.ndarray) -> None:
    """Bird's-eye panel on axes ``top``: points coloured by views seeing them, camera centres
    [N, 3] with their headings by role, and the region box."""
    east, north = c.frame[0], c.frame[1]
    px, py = c.points @ east, c.points @ north
    dots = top.scatter(px, py, c=c.counts, s=3, cmap="inferno", vmin=0,
                       vmax=max(float(np.percentile(c.counts, 95)), 1.0))
    figure.colorbar(dots, ax=top, label="training views seeing the point")
    forward = np.array([cam.world_to_camera[2, :3] for cam in c.cameras])
    extent = max(float(np.ptp(np.r_[px, centers @ east])), float(np.ptp(np.r_[py, centers @ north])), 1e-6)
    held = set(c.groups.get("scarce", [])) | set(c.groups.get("covered", []))
    styles = [("source views", [i for i in range(len(c.cameras)) if c.sources[i]], "tab:blue"),
              ("held out: covered", c.groups.get("covered", []), "tab:green"),
              ("held out: scarce", c.groups.get("scarce", []), "tab:red"),
              ("other views", [i for i in range(len(c.cameras)) if not c.sources[i] and i not in held], "tab:gray")]
    for label, members, colour in styles:
        if not members:
            continue
        m = np.asarray(members)
        top.quiver(centers[m] @ east, centers[m] @ north, forward[m] @ east, forward[m] @ north, color=colour,
                   angles="xy", scale_units="xy", scale=1.0 / (0.06 * extent), width=0.004, label=label)
    lo, hi = c.roi
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    cx, cy = corners @ east, corners @ north
    top.plot([cx.min(), cx.max(), cx.max(), cx.min(), cx.min()], [cy.min(), cy.min(), cy.max(), cy.max(), cy.min()],
             "k--", linewidth=0.8, label="region of interest (bounds)")
    # Frame the cameras and the region; stray points (a few far outliers in real SfM clouds)
    # would otherwise shrink the scene to a dot.
    xs = np.r_[centers @ east, cx, np.percentile(px, [2, 98])]
    ys = np.r_[centers @ north, cy, np.percentile(py, [2, 98])]
    margin = 0.08 * max(float(np.ptp(xs)), float(np.ptp(ys)), 1e-6)
    top.set_xlim(xs.min() - margin, xs.max() + margin)
    top.set_ylim(ys.min() - margin, ys.max() + margin)
    top.set_aspect("equal", adjustable="box")
    top.set_xlabel("east (scene units)")
    top.set_ylabel("north")
    top.set_title("from above: points by views seeing them", fontsize=10)
    top.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=3)


def _plot_hemisphere(figure, polar, c: Coverage, centers: np.ndarray) -> None:
    """Polar panel: theta = azimuth (0 = east, counter-clockwise as in the bird's-eye view),
    r = zenith angle; the viewing density and the cameras' directions from the region's centre."""
    theta_edges = np.linspace(0, 2 * math.pi, len(c.azimuth) + 1)
    r_edges = np.degrees(np.linspace(0, math.pi / 2, len(c.elevation) + 1))
    zenith_density = c.density[::-1]          # row 0 = highest elevation = smallest zenith angle
    mesh = polar.pcolormesh(theta_edges, r_edges, zenith_density, cmap="viridis", shading="flat")
    figure.colorbar(mesh, ax=polar, label="views per steradian (per region point)", pad=0.1)
    directions = cov.view_directions(c.points[c.in_region].mean(axis=0, keepdims=True), centers)[0] @ c.frame.T
    above = directions[:, 2] >= 0
    polar.scatter(np.arctan2(directions[above, 1], directions[above, 0]),
                  90.0 - np.degrees(np.arcsin(np.clip(directions[above, 2], -1, 1))),
                  s=8, c=np.where(c.sources[above], "white", "red"), edgecolors="black", linewidths=0.3)
    polar.set_ylim(0, 90)
    polar.set_yticks([30, 60, 90])
    polar.set_yticklabels(["60°", "30°", "0°"], fontsize=7)
    polar.set_title("viewing density over the region's hemisphere", fontsize=10)
    polar.text(0.5, -0.12, "centre: seen from straight above, rim: from the horizon;\ndots: cameras "
               "(white: sources, red: others)", transform=polar.transAxes, ha="center", va="top", fontsize=7)


def _plot_scarcest(bars, c: Coverage) -> None:
    """Bar panel: the 15 scarcest views' scores, coloured by held-out group."""
    shown = cov.scarcest_views(c.scarcity, 15)
    colours = ["tab:red" if i in c.groups.get("scarce", []) else "tab:green" if i in c.groups.get("covered", [])
               else "tab:blue" for i in shown]
    bars.barh(range(len(shown)), [c.scarcity[i] for i in shown], color=colours)
    bars.set_yticks(range(len(shown)))
    bars.set_yticklabels([c.cameras[i].name for i in shown], fontsize=7)
    bars.invert_yaxis()
    bars.set_xlim(0, 1)
    bars.set_xlabel(f"scarcity: mean over what it shows of 1 / (1 + other source views within "
                    f"{cov.DIRECTION_WINDOW_DEG:g}°\nof its direction at >= 1/{cov.SCALE_RATIO:g} of its resolution)", fontsize=8)
    bars.set_title("views whose content is seen least" + (" (red: held-out scarce)" if c.groups else ""),
                   fontsize=10)
