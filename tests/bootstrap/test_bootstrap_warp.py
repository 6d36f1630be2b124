"""Warping and blending (stage II) on analytic scenes: textured planes ray-cast in float64.

Every depth map and image here is computed in closed form (ray-plane intersections and a
smooth texture defined on the world points), independently of inceptiongs' rasterizer and
of the warp's own projection code.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inceptiongs.bootstrap.warp import (DEFAULT_DELTA, DEFAULT_GRAZING_DEG, WarpResult, blend_views, warp_geometry, warp_to_view)
from inceptiongs.camera import Camera, look_at

W, H, FOCAL = 64, 48, 60.0


def _camera(eye, target=(0.0, 0.0, 0.0), width=W, height=H, focal=FOCAL, up=(0.0, -1.0, 0.0)):
    return Camera("c", width, height, focal, focal * 1.02, width * 0.52, height * 0.47,
                  look_at(np.array(eye, float), np.array(target, float), up=up))


def _rays(camera: Camera):
    """Camera centre [3] and world ray directions [h, w, 3] with camera z = 1 per unit."""
    j, i = np.mgrid[0:camera.height, 0:camera.width] + 0.5
    local = np.stack([(i - camera.cx) / camera.fx, (j - camera.cy) / camera.fy, np.ones_like(i)], -1)
    return camera.center, local @ camera.rotation  # R^T d for each row vector d


def _hit_plane(camera, point, normal, half_size=None, axes=None):
    """Camera z of the first hit with a plane (or a square patch of it): [h, w]; inf = none."""
    centre, rays = _rays(camera)
    normal = np.asarray(normal, float)
    denom = rays @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((np.asarray(point, float) - centre) @ normal) / denom
    s = np.where((np.abs(denom) > 1e-12) & (s > 0), s, np.inf)
    if half_size is not None:
        hit = centre + np.where(np.isfinite(s), s, 0)[..., None] * rays - np.asarray(point, float)
        inside = (np.abs(hit @ axes[0]) <= half_size) & (np.abs(hit @ axes[1]) <= half_size)
        s = np.where(inside, s, np.inf)
    return s


def _texture(points):
    """Smooth colour [..., 3] of world points: periods of ~1 scene unit (~15+ px here)."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    return np.stack([0.5 + 0.3 * np.sin(6.0 * x + 1.0 * y),
                     0.5 + 0.3 * np.cos(5.0 * y - 2.0 * z + 0.4),
                     0.5 + 0.25 * np.sin(4.0 * (x + y + z) + 1.3)], -1)


def _render(camera, depth):
    """Analytic image [h, w, 3] and depth [h, w, 1] (0 where nothing is hit)."""
    centre, rays = _rays(camera)
    finite = np.isfinite(depth)
    points = centre + np.where(finite, depth, 0)[..., None] * rays
    image = np.where(finite[..., None], _texture(points), 0.0)
    return image, np.where(finite, depth, 0.0)[..., None]


PLANE_POINT = np.array([0.0, 0.0, 0.2])
PLANE_NORMAL = np.array([0.2, -0.1, -1.0]) / np.linalg.norm([0.2, -0.1, -1.0])


def _plane_views(src, dst):
    src_image, src_depth = _render(src, _hit_plane(src, PLANE_POINT, PLANE_NORMAL))
    dst_image, dst_depth = _render(dst, _hit_plane(dst, PLANE_POINT, PLANE_NORMAL))
    return src_image, src_depth, dst_image, dst_depth


def _project(camera, points):
    """World points [..., 3] -> (uv [..., 2], z [...]), written out independently."""
    local = points @ camera.rotation.T + camera.world_to_camera[:3, 3]
    z = local[..., 2]
    return np.stack([camera.fx * local[..., 0] / z + camera.cx, camera.fy * local[..., 1] / z + camera.cy], -1), z


def _interior(shape, border=1):
    out = np.zeros(shape, bool)
    out[border:-border, border:-border] = True
    return out


def test_exact_warp_of_a_textured_plane():
    src = _camera((-0.6, 0.25, -3.0))
    dst = _camera((0.5, -0.3, -2.7), target=(0.1, 0.0, 0.0))
    src_image, src_depth, dst_image, dst_depth = _plane_views(src, dst)

    # Geometry first: where each destination pixel lands in the source, to rounding.
    centre, rays = _rays(dst)
    world = centre + dst_depth * rays
    uv_expected, z_expected = _project(src, world)
    geometry = warp_geometry(dst_depth, dst, src)
    np.testing.assert_allclose(geometry.uv.numpy(), uv_expected, atol=1e-9)
    np.testing.assert_allclose(geometry.points_src[..., 2].numpy(), z_expected, atol=1e-12)

    result = warp_to_view(torch.tensor(src_image, dtype=torch.float32), src_depth, src, dst_depth, dst)
    assert result.image.shape == (H, W, 3) and result.mask.shape == (H, W, 1)
    assert result.image.dtype == torch.float32
    mask = result.mask[..., 0].numpy()
    assert set(np.unique(mask)) <= {0.0, 1.0}
    # Interior pixels: not on the destination border (normals) and projecting at least one
    # pixel inside the source image (all bilinear taps real).
    interior = (_interior((H, W)) & (uv_expected[..., 0] >= 1.5) & (uv_expected[..., 0] <= W - 1.5)
                & (uv_expected[..., 1] >= 1.5) & (uv_expected[..., 1] <= H - 1.5))
    assert interior.mean() > 0.6
    assert np.all(mask[interior] == 1.0)
    # Outside the source image nothing is trusted.
    outside = ((uv_expected[..., 0] < 0.5) | (uv_expected[..., 0] > W - 0.5)
               | (uv_expected[..., 1] < 0.5) | (uv_expected[..., 1] > H - 0.5))
    assert outside.any() and np.all(mask[outside] == 0.0)
    # Colour: bilinear resampling of a texture with a >= 15 px period; the second-order
    # interpolation error bound is ~(2 pi / 15)^2 / 8 * 0.3 ~ 0.007.
    error = np.abs(result.image.numpy() - dst_image)[interior]
    assert error.max() < 0.01, error.max()
    assert error.mean() < 0.003


def test_occluded_pixels_are_rejected():
    src = _camera((-0.9, 0.2, -3.0))
    dst = _camera((0.7, -0.1, -2.8))
    # Background plane, and a square occluder halfway between the source and the plane.
    background = (np.array([0.0, 0.0, 0.3]), np.array([0.0, 0.0, -1.0]))
    occ_point = 0.5 * (src.center + np.array([0.05, 0.0, 0.3]))
    occ_normal = -src.rotation[2]
    occ_axes = (src.rotation[0], src.rotation[1])
    occ_half = 0.35

    def depth_of(camera):
        return np.minimum(_hit_plane(camera, *background),
                          _hit_plane(camera, occ_point, occ_normal, occ_half, occ_axes))

    src_image, src_depth = _render(src, depth_of(src))
    _, dst_depth = _render(dst, depth_of(dst))

    # Which destination points the source cannot see: the occluder cuts the segment
    # from the source centre to the point before the point itself.
    centre, rays = _rays(dst)
    points = centre + dst_depth * rays
    segment = points - src.center
    denom = segment @ occ_normal
    s = ((occ_point - src.center) @ occ_normal) / denom
    hit = src.center + s[..., None] * segment - occ_point
    occluded = ((s > 0) & (s < 1 - 1e-6) & (np.abs(hit @ occ_axes[0]) <= occ_half)
                & (np.abs(hit @ occ_axes[1]) <= occ_half) & (dst_depth[..., 0] > 0))
    assert occluded.sum() > 50  # the scene really has hidden pixels

    result = warp_to_view(src_image, src_depth, src, dst_depth, dst)
    mask = result.mask[..., 0].numpy().astype(bool)
    assert not mask[occluded].any()
    # ... while most visible interior pixels are still trusted (the mask is not just empty).
    uv, _ = _project(src, points)
    visible_inside = (~occluded & _interior((H, W)) & (uv[..., 0] > 2) & (uv[..., 0] < W - 2)
                      & (uv[..., 1] > 2) & (uv[..., 1] < H - 2))
    assert mask[visible_inside].mean() > 0.8
    # Without the depth test (a huge delta) the occluded pixels would pass: the test is what rejects them.
    loose = warp_to_view(src_image, src_depth, src, dst_depth, dst, delta=10.0)
    assert loose.mask[..., 0].numpy().astype(bool)[occluded].mean() > 0.5


def test_pixels_without_depth_are_rejected():
    src = _camera((-0.6, 0.25, -3.0))
    dst = _camera((0.5, -0.3, -2.7))
    src_image, src_depth, _, dst_depth = _plane_views(src, dst)
    baseline = warp_to_view(src_image, src_depth, src, dst_depth, dst).mask[..., 0].numpy()

    holed_dst = dst_depth.copy()
    holed_dst[10:20, 20:35] = 0.0
    mask = warp_to_view(src_image, src_depth, src, holed_dst, dst).mask[..., 0].numpy()
    assert baseline[10:20, 20:35].all() and not mask[10:20, 20:35].any()
    assert mask[30:40, 5:15].all()  # far from the hole nothing changes

    holed_src = src_depth.copy()
    holed_src[15:30, 25:40] = 0.0
    mask = warp_to_view(src_image, holed_src, src, dst_depth, dst).mask[..., 0].numpy()
    uv = warp_geometry(dst_depth, dst, src).uv.numpy()
    # Any destination pixel whose bilinear taps touch the hole is rejected.
    touches = ((uv[..., 0] > 25 - 0.5) & (uv[..., 0] < 40 + 0.5) & (uv[..., 1] > 15 - 0.5)
               & (uv[..., 1] < 30 + 0.5))
    assert touches.sum() > 50 and not mask[touches].any()
    assert baseline[~touches & _interior((H, W))].mean() > 0.5

    nan_dst = dst_depth.copy()
    nan_dst[:5] = np.nan
    mask = warp_to_view(src_image, src_depth, src, nan_dst, dst).mask[..., 0].numpy()
    assert not mask[:5].any() and np.isfinite(mask).all()


def test_points_behind_the_source_camera_are_rejected():
    dst = _camera((0.0, 0.0, -3.0))
    _, _, _, dst_depth = _plane_views(dst, dst)
    # The source sits between the camera and the plane's far side... looking away from it.
    src = _camera((0.0, 0.0, -4.0), target=(0.0, 0.0, -8.0))
    centre, rays = _rays(dst)
    points = centre + dst_depth * rays
    uv, z = _project(src, points)
    assert np.all(z < 0)
    # Sign-flipped projections land inside the image: only the in-front test stops them.
    inside = (uv[..., 0] > 1) & (uv[..., 0] < W - 1) & (uv[..., 1] > 1) & (uv[..., 1] < H - 1)
    assert inside.mean() > 0.5
    src_image = np.full((H, W, 3), 0.7)
    src_depth = np.full((H, W, 1), float(np.median(-z)))  # depths a sign flip would match
    result = warp_to_view(src_image, src_depth, src, dst_depth, dst)
    assert result.mask.sum() == 0 and result.image.abs().sum() == 0


def _angle_to_normal(camera, points, normal):
    rays = points - camera.center
    cos = np.abs(rays @ normal) / np.linalg.norm(rays, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


@pytest.mark.parametrize("src_angle_deg", [50.0, 82.0])
def test_grazing_views_are_rejected(src_angle_deg):
    normal = np.array([0.0, 0.0, -1.0])
    point = np.zeros(3)
    dst = _camera((0.0, 0.0, -3.0))
    a = math.radians(src_angle_deg)
    src = _camera((3.0 * math.sin(a), 0.0, -3.0 * math.cos(a)), focal=90.0, width=96, height=64)
    src_image, src_depth = _render(src, _hit_plane(src, point, normal))
    _, dst_depth = _render(dst, _hit_plane(dst, point, normal))
    mask = warp_to_view(src_image, src_depth, src, dst_depth, dst).mask[..., 0].numpy()
    centre, rays = _rays(dst)
    points = centre + dst_depth * rays
    angle = _angle_to_normal(src, points, normal)
    uv, _ = _project(src, points)
    usable = (_interior((H, W)) & (uv[..., 0] > 1.5) & (uv[..., 0] < src.width - 1.5)
              & (uv[..., 1] > 1.5) & (uv[..., 1] < src.height - 1.5))
    grazing = angle > DEFAULT_GRAZING_DEG + 0.5
    frontal = angle < DEFAULT_GRAZING_DEG - 0.5
    assert not mask[grazing].any()
    if src_angle_deg < DEFAULT_GRAZING_DEG:
        assert (usable & frontal).sum() > 100 and mask[usable & frontal].all()
    else:
        assert (usable & grazing).sum() > 100
        # With the grazing test switched off these pixels would pass: it is what rejects them.
        loose = warp_to_view(src_image, src_depth, src, dst_depth, dst, grazing_deg=90.0)
        assert loose.mask[..., 0].numpy()[usable & grazing].mean() > 0.5


def test_back_side_of_a_surface_is_rejected():
    # A thin plane: the source sees its back, at exactly the depth the visibility test expects.
    normal = np.array([0.0, 0.0, -1.0])
    point = np.zeros(3)
    dst = _camera((0.3, 0.0, -3.0))
    src = _camera((-0.3, 0.2, 3.0))
    src_image, src_depth = _render(src, _hit_plane(src, point, normal))
    _, dst_depth = _render(dst, _hit_plane(dst, point, normal))
    geometry = warp_geometry(dst_depth, dst, src)
    uv = geometry.uv.numpy()
    inside = (uv[..., 0] > 2) & (uv[..., 0] < W - 2) & (uv[..., 1] > 2) & (uv[..., 1] < H - 2)
    assert inside.mean() > 0.3
    assert warp_to_view(src_image, src_depth, src, dst_depth, dst).mask.sum() == 0
    # Same geometry seen from the front side is trusted.
    front = _camera((-0.3, 0.2, -3.0))
    front_image, front_depth = _render(front, _hit_plane(front, point, normal))
    assert warp_to_view(front_image, front_depth, front, dst_depth, dst).mask.mean() > 0.5


def test_bad_inputs():
    cam = _camera((0.0, 0.0, -3.0))
    image, depth = np.zeros((H, W, 3)), np.ones((H, W, 1))
    with pytest.raises(ValueError, match="src_depth"):
        warp_to_view(image, depth[:-1], cam, depth, cam)
    with pytest.raises(ValueError, match="delta"):
        warp_to_view(image, depth, cam, depth, cam, delta=0.0)
    with pytest.raises(ValueError, match="float"):
        warp_to_view(image.astype(np.uint8), depth, cam, depth, cam)
    assert DEFAULT_DELTA > 0


def test_blend_is_mask_weighted_mean_then_generated_elsewhere():
    gen = torch.Generator().manual_seed(0)
    h, w = 5, 7
    generated = torch.rand(h, w, 3, generator=gen)
    warps = []
    for _ in range(3):
        mask = (torch.rand(h, w, 1, generator=gen) > 0.5).float()
        warps.append(WarpResult(torch.rand(h, w, 3, generator=gen) * mask, mask))
    image, trust = blend_views(generated, warps)
    for j in range(h):
        for i in range(w):
            accepted = [wr.image[j, i] for wr in warps if wr.mask[j, i, 0] == 1]
            if accepted:
                expected = sum(accepted) / len(accepted)
                assert trust[j, i, 0] == 1
            else:
                expected = generated[j, i]
                assert trust[j, i, 0] == 0
            torch.testing.assert_close(image[j, i], expected)
    empty_image, empty_mask = blend_views(generated, [])
    torch.testing.assert_close(empty_image, generated)
    assert empty_mask.sum() == 0
    with pytest.raises(ValueError):
        blend_views(generated[:-1], warps)


def test_warp_with_rasterized_depth_of_a_splatted_plane():
    """The rasterizer's depth convention (camera z, 0 = none) fits the warp: a plane tiled with
    flat Gaussians, rendered in two views, warps one render onto the other."""
    from inceptiongs.gaussians import Gaussians
    from inceptiongs.rasterizer.rasterize import render

    # A 24 x 24 grid of flat (log-scale -8 across) Gaussians on the plane z = 0.3 - 0.15 x.
    u, v = np.meshgrid(np.linspace(-1.2, 1.2, 24), np.linspace(-1.0, 1.0, 24))
    means = np.stack([u.ravel(), v.ravel(), 0.3 - 0.15 * u.ravel()], -1)
    tangent = np.array([1.0, 0.0, -0.15]) / np.linalg.norm([1.0, 0.0, -0.15])
    # Rotation taking the local x axis to the tangent (about y), local z to the plane normal.
    angle = math.atan2(0.15, 1.0)
    quat = np.array([math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0])
    assert np.allclose(quat_rotate_x(quat), tangent)
    # A low-frequency texture (0.4 x the analytic tests'): neighbouring splats then differ
    # little, so the views' different compositing orders change the renders little.
    colours = _texture(0.4 * means)
    n = len(means)
    sh0 = (colours - 0.5) / 0.28209479177387814
    g = Gaussians(means=torch.tensor(means), log_scales=torch.tensor([[math.log(0.07), math.log(0.06), -8.0]] * n),
                  quats=torch.tensor(np.repeat(quat[None], n, 0)), opacity_logits=torch.full((n,), 4.0),
                  sh=torch.tensor(sh0[:, None, :]))
    src = _camera((-0.4, 0.15, -3.0))
    dst = _camera((0.35, -0.2, -2.8))
    out_src = render(g, src, outputs=("rgb", "depth"), backend="torch")
    out_dst = render(g, dst, outputs=("rgb", "depth", "alpha"), backend="torch")
    result = warp_to_view(out_src["rgb"], out_src["depth"], src, out_dst["depth"], dst)
    mask = result.mask[..., 0].numpy().astype(bool)
    covered = (out_dst["alpha"][..., 0].numpy() > 0.99) & _interior((H, W), 3)
    assert covered.sum() > 500
    assert mask[covered].mean() > 0.9
    error = (result.image - out_dst["rgb"]).abs().numpy()[mask & covered]
    # Splat compositing order differs between the views (nearly opaque neighbours overlap),
    # so the renders are not an exact texture map of each other; still the warp must explain
    # most of the difference between the two renders.
    unwarped = (out_src["rgb"] - out_dst["rgb"]).abs().numpy()[mask & covered]
    # Measured: 0.018 against 0.051 between the unwarped renders (geometry itself is checked
    # exactly by the analytic tests; here the renders' own order effects dominate).
    assert error.mean() < 0.03 and error.mean() < 0.5 * unwarped.mean(), (error.mean(), unwarped.mean())


def quat_rotate_x(q):
    """The image of the x axis under the rotation of unit quaternion q (w, x, y, z)."""
    w, x, y, z = q
    return np.array([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)])
