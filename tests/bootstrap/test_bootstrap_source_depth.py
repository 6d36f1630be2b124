"""The virtual view's depth splatted from the training views' depths (source_depth.py), on an
analytic plane: exact where the sources see it, robust to one source's floater, empty where no
source reaches."""

from __future__ import annotations

import numpy as np
import torch

from inceptiongs.bootstrap.source_depth import close_holes, splat_into, splatted_depth
from plane_cases import HEIGHT, PLANE_Z, WIDTH, camera_at


def plane_depth(camera) -> torch.Tensor:
    """[H, W, 1] camera z of the plane z = PLANE_Z for an axis-aligned camera."""
    return torch.full((HEIGHT, WIDTH, 1), PLANE_Z - float(camera.center[2]))


def test_a_near_view_gets_the_plane_from_two_far_sources_with_its_holes_closed():
    sources = [camera_at("a", (-0.5, 0.0, 0.0)), camera_at("b", (0.5, 0.0, 0.0))]
    near = camera_at("v", (0.1, 0.0, 2.5))          # half as far from the plane: 2 x 2 pixels per splat
    splats = splat_into(plane_depth(sources[0]), sources[0], near)
    assert float(torch.isinf(splats).float().mean()) > 0.5          # one splat per ~4 pixels: holes
    depth = splatted_depth(near, [(plane_depth(c), c) for c in sources])
    assert bool((depth > 0).all())                                  # every hole closed
    np.testing.assert_allclose(depth.numpy(), PLANE_Z - 2.5, rtol=1e-5)


def test_one_sources_floater_is_outvoted_by_the_median():
    sources = [camera_at(n, c) for n, c in (("a", (-0.5, 0.0, 0.0)), ("b", (0.5, 0.0, 0.0)), ("c", (0.0, 0.4, 0.0)))]
    depths = [plane_depth(c) for c in sources]
    floater = depths[0].clone()
    floater[10:30, 20:40] = 2.0                                   # a blob 3 units in front of the plane
    target = camera_at("v", (0.0, 0.1, 1.0))
    pairs = [(floater, sources[0])] + list(zip(depths[1:], sources[1:]))
    with_floater = splatted_depth(target, pairs)[..., 0]
    # Where all three sources land, two of three see the plane: the median is the plane. (Where
    # only two land and disagree there is no majority; the lower median keeps the nearer.)
    all_three = torch.stack([~torch.isinf(close_holes(splat_into(d, c, target), 4)) for d, c in pairs]).all(0)
    assert float(all_three.float().mean()) > 0.5
    assert float((with_floater[all_three] - (PLANE_Z - 1.0)).abs().max()) < 1e-4
    # One source alone keeps its floater (nearest point per pixel).
    alone = splatted_depth(target, [(floater, sources[0])])
    assert float((alone < 2.0).float().mean()) > 0.05


def test_nothing_reaches_a_view_facing_away_and_empty_depth_splats_nothing():
    source = camera_at("a", (0.0, 0.0, 0.0))
    away = camera_at("v", (0.0, 0.0, 0.0))
    pose = away.world_to_camera.copy()
    pose[:3, :3] = np.diag([-1.0, 1.0, -1.0])                     # turned 180 degrees about y
    away = away.with_pose(pose)
    assert float(splatted_depth(away, [(plane_depth(source), source)]).abs().max()) == 0.0
    assert float(splatted_depth(source, [(torch.zeros(HEIGHT, WIDTH, 1), source)]).abs().max()) == 0.0
    assert float(splatted_depth(source, []).abs().max()) == 0.0


def test_close_holes_takes_the_nearest_depth_and_leaves_far_holes_empty():
    z = torch.full((9, 9), float("inf"), dtype=torch.float64)
    z[4, 4], z[4, 6] = 3.0, 2.0
    closed = close_holes(z, 1)
    assert float(closed[4, 5]) == 2.0 and float(closed[3, 3]) == 3.0   # both within 1 px: the nearer wins
    assert bool(torch.isinf(closed[0, 0]))                              # 4 px away: left empty
    assert torch.equal(close_holes(z, 0), z)


def test_both_depths_take_the_renders_warps_where_trusted_and_the_splatted_elsewhere():
    """--virtual-depth both: where the view's own depth places a trusted warp, its blend; where
    it has no depth (a hole in the render), the blend placed with the splatted depth."""
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.supervise import ViewContext, supervise_view
    from test_bootstrap_photo_depth import photo_of_plane

    cameras = [camera_at("a", (-0.3, 0.0, 0.0)), camera_at("b", (0.3, 0.0, 0.0)), camera_at("v", (0.0, 0.05, 0.5))]
    photos = {0: photo_of_plane(cameras[0]), 1: photo_of_plane(cameras[1])}
    own = plane_depth(cameras[2]).clone()
    own[:, : WIDTH // 2] = 0.0                                        # the render left a hole
    depth_of = lambda cam: own if cam.name == "v" else plane_depth(cam)  # noqa: E731
    render = torch.zeros(HEIGHT, WIDTH, 3)
    splat = splatted_depth(cameras[2], [(plane_depth(c), c) for c in cameras[:2]])

    def blend(virtual_depth: str, splatted: torch.Tensor = splat):
        config = BootstrapConfig(fill="render", virtual_depth=virtual_depth)
        out = supervise_view(ViewContext(config, cameras[2], render.numpy(), [0, 1], cameras, photos, depth_of,
                                         source_depth=lambda: splatted))
        return out.image, out.mask, out.report

    alone, alone_mask, _ = blend("render")
    both, both_mask, _ = blend("both")
    splat_only, _, _ = blend("sources")
    left = both_mask[:, 4: WIDTH // 2 - 4, 0]
    assert float(alone_mask[:, : WIDTH // 2].max()) == 0.0 and float(left.mean()) > 0.8
    right = alone_mask[..., 0] > 0
    assert torch.equal(both[right], alone[right])
    hole = (both_mask[..., 0] > 0) & ~right
    assert torch.allclose(both[hole], splat_only[hole])
    # "auto": the depth whose blend trusts more pixels, whole; the report names it.
    auto, _, report = blend("auto")
    assert report["depth"] == "sources" and torch.equal(auto, splat_only)
    auto, _, report = blend("auto", torch.zeros_like(splat))
    assert report["depth"] == "render" and torch.equal(auto, alone)
