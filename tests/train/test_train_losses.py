"""PGSR loss terms on analytic geometry: planes seen by two pinhole cameras."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.train import losses
from inceptiongs.train.neighbours import neighbour_views

W, H = 64, 48


def _camera(eye, target=(0.0, 0.0, 4.0), name="cam") -> Camera:
    return Camera(name, W, H, 60.0, 60.0, W / 2, H / 2, look_at(np.array(eye, float), np.array(target, float)))


# World plane n_w . X = d_w (tilted, in front of the cameras).
PLANE_NORMAL = np.array([0.2, -0.3, -1.0]) / np.linalg.norm([0.2, -0.3, -1.0])
PLANE_POINT = np.array([0.0, 0.0, 4.0])


def _plane_in_camera(cam: Camera) -> tuple[np.ndarray, float]:
    """The plane as n . X = delta in camera coordinates, n facing the camera."""
    rotation, translation = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    n = rotation @ PLANE_NORMAL
    delta = float(n @ (rotation @ PLANE_POINT + translation))
    if delta > 0:  # facing the camera means n . X < 0 for points on the plane
        n, delta = -n, -delta
    return n, delta


def _plane_depth(cam: Camera) -> torch.Tensor:
    """Exact camera z of the plane at every pixel centre: [H, W, 1] (float64)."""
    n, delta = _plane_in_camera(cam)
    pixels = losses.pixel_grid(H, W, torch.float64).numpy()
    rays = np.stack([(pixels[..., 0] - cam.cx) / cam.fx, (pixels[..., 1] - cam.cy) / cam.fy,
                     np.ones(pixels.shape[:2])], -1)
    return torch.from_numpy(delta / (rays @ n))[..., None]


def _texture(points_world: np.ndarray) -> np.ndarray:
    x, y = points_world[..., 0], points_world[..., 1]
    return 0.5 + 0.25 * np.sin(7.0 * x + 1.0) * np.cos(5.0 * y) + 0.2 * np.sin(3.0 * x * y + 2.0 * y)


def _photo(cam: Camera) -> torch.Tensor:
    """Grey image of the textured plane: [H, W, 1] (float64)."""
    depth = _plane_depth(cam)[..., 0]
    k = torch.tensor(cam.intrinsics)
    points = losses.unproject(losses.pixel_grid(H, W, torch.float64), depth, k).numpy()
    world = points @ cam.camera_to_world[:3, :3].T + cam.camera_to_world[:3, 3]
    return torch.from_numpy(_texture(world))[..., None]


def _k(cam: Camera) -> torch.Tensor:
    return torch.tensor(cam.intrinsics)


def _ref_to_nb(ref: Camera, nb: Camera) -> torch.Tensor:
    return torch.tensor(nb.world_to_camera @ ref.camera_to_world)


REF = _camera((0.0, 0.0, 0.0), name="ref")
NB = _camera((0.4, 0.1, 0.0), name="nb")


def test_photometric_loss_is_l1_without_ssim_and_zero_for_equal_images():
    a = torch.rand(20, 24, 3, generator=torch.Generator().manual_seed(0))
    b = torch.rand(20, 24, 3, generator=torch.Generator().manual_seed(1))
    loss, l1 = losses.photometric_loss(a, b, 0.0)
    assert float(loss) == pytest.approx(float(np.abs(a.numpy() - b.numpy()).mean()), rel=1e-6)
    mixed, _ = losses.photometric_loss(a, a, 0.2)
    assert float(mixed) == pytest.approx(0.0, abs=1e-6)


def test_flatten_loss_is_mean_smallest_scale():
    log_scales = torch.log(torch.tensor([[0.1, 0.5, 0.2], [3.0, 2.0, 4.0]]))
    assert float(losses.flatten_loss(log_scales)) == pytest.approx((0.1 + 2.0) / 2, rel=1e-6)


def test_normals_from_depth_recover_the_plane_normal_facing_the_camera():
    depth = _plane_depth(REF)
    normals, valid = losses.normals_from_depth(depth, _k(REF))
    n, _ = _plane_in_camera(REF)
    assert valid.sum() == (H - 2) * (W - 2)
    np.testing.assert_allclose(normals[valid].numpy(), np.broadcast_to(n, (int(valid.sum()), 3)), atol=1e-6)


def test_normal_consistency_is_zero_on_a_perfect_plane_and_not_for_a_wrong_normal():
    depth = _plane_depth(REF)
    n, _ = _plane_in_camera(REF)
    alpha = torch.ones(H, W, 1, dtype=torch.float64)
    weight = torch.ones(H, W, dtype=torch.float64)
    # Rendered normals are blended, not unit length: scale them to check the renormalisation.
    rendered = torch.from_numpy(np.broadcast_to(0.7 * n, (H, W, 3)).copy())
    loss = losses.normal_consistency_loss(rendered, depth, alpha, _k(REF), weight)
    assert float(loss) < 1e-6
    wrong = torch.from_numpy(np.broadcast_to(np.array([0.0, 0.0, -1.0]), (H, W, 3)).copy())
    assert float(losses.normal_consistency_loss(wrong, depth, alpha, _k(REF), weight)) > 0.1
    assert losses.normal_consistency_loss(rendered, depth, torch.zeros_like(alpha), _k(REF), weight) is None


def test_edge_aware_weight_is_low_on_edges_and_one_on_flat_images():
    flat = torch.full((10, 12, 3), 0.3)
    assert torch.all(losses.edge_aware_weight(flat) == 1.0)
    step = torch.zeros(10, 12, 3)
    step[:, 6:] = 1.0
    weight = losses.edge_aware_weight(step)
    assert float(weight[5, 6]) == pytest.approx(0.0) and float(weight[5, 2]) == pytest.approx(1.0)


def test_reprojection_error_is_zero_for_consistent_depth():
    error, valid = losses.reprojection_error(_plane_depth(REF), _k(REF), _plane_depth(NB), _k(NB),
                                             _ref_to_nb(REF, NB))
    assert valid.float().mean() > 0.5
    assert float(error[valid].max()) < 1e-3
    assert float(losses.geometric_consistency_loss(error, valid, 1.0)) < 1e-3


def test_reprojection_error_grows_for_inconsistent_depth():
    error, valid = losses.reprojection_error(_plane_depth(REF), _k(REF), 1.1 * _plane_depth(NB), _k(NB),
                                             _ref_to_nb(REF, NB))
    assert float(error[valid].median()) > 0.5


def test_reprojection_error_accepts_a_smaller_neighbour_depth_map():
    small = NB.scaled(2.0)
    depth_small = torch.nn.functional.avg_pool2d(_plane_depth(NB).permute(2, 0, 1)[None], 2)[0].permute(1, 2, 0)
    error, valid = losses.reprojection_error(_plane_depth(REF), _k(REF), depth_small, _k(small),
                                             _ref_to_nb(REF, NB))
    # Averaging 2x2 depths of a plane is exact up to the plane's curvature in z: small error.
    assert float(error[valid].median()) < 0.05


def test_geometric_consistency_skips_when_nothing_is_valid():
    error = torch.zeros(4, 4)
    assert losses.geometric_consistency_loss(error, torch.zeros(4, 4, dtype=torch.bool), 1.0) is None


def test_ncc_is_one_for_identical_and_affine_patches_and_minus_one_for_negated():
    patches = torch.rand(5, 49, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    ncc, valid = losses.normalized_cross_correlation(patches, patches)
    assert valid.all() and torch.allclose(ncc, torch.ones(5, dtype=torch.float64), atol=1e-9)
    ncc, _ = losses.normalized_cross_correlation(patches, 0.5 * patches + 0.2)
    assert torch.allclose(ncc, torch.ones(5, dtype=torch.float64), atol=1e-9)
    ncc, _ = losses.normalized_cross_correlation(patches, -patches)
    assert torch.allclose(ncc, -torch.ones(5, dtype=torch.float64), atol=1e-9)
    _, valid = losses.normalized_cross_correlation(torch.ones(2, 49), patches[:2].float())
    assert not valid.any()


def _ncc_inputs(normal_override=None):
    rng = torch.Generator().manual_seed(0)
    pixels = torch.stack([torch.randint(8, W - 8, (200,), generator=rng),
                          torch.randint(8, H - 8, (200,), generator=rng)], -1).double() + 0.5
    depth_map = _plane_depth(REF)
    cols, rows = pixels[:, 0].long(), pixels[:, 1].long()
    depth = depth_map[rows, cols, 0]
    n, _ = _plane_in_camera(REF)
    normal = n if normal_override is None else normal_override
    normals = torch.from_numpy(np.broadcast_to(normal, (200, 3)).copy())
    return _photo(REF), _photo(NB), pixels, depth, normals


def test_ncc_loss_is_near_zero_when_the_plane_is_right():
    ref, nb, pixels, depth, normals = _ncc_inputs()
    loss = losses.ncc_loss(ref, nb, pixels, depth, normals, _k(REF), _k(NB), _ref_to_nb(REF, NB), radius=3)
    assert loss is not None and float(loss) < 0.02


def test_ncc_loss_is_larger_for_a_wrong_plane_and_sends_gradients_to_depth():
    ref, nb, pixels, depth, normals = _ncc_inputs()
    k_ref, k_nb, pose = _k(REF), _k(NB), _ref_to_nb(REF, NB)
    right = losses.ncc_loss(ref, nb, pixels, depth, normals, k_ref, k_nb, pose, 3)
    # A plane 20% too far moves every patch centre off its match in the neighbour.
    wrong_depth = (1.2 * depth).requires_grad_(True)
    bad = losses.ncc_loss(ref, nb, pixels, wrong_depth, normals, k_ref, k_nb, pose, 3)
    assert float(bad.detach()) > float(right) + 0.05
    bad.backward()
    assert wrong_depth.grad is not None and float(wrong_depth.grad.abs().sum()) > 0


def test_neighbours_respect_angle_and_count_and_can_be_empty():
    cams = [_camera((0.1 * i, 0.0, 0.0), name=f"c{i}") for i in range(12)]
    # One camera looking sideways (90 degrees away): nobody's neighbour, and it has none.
    cams.append(Camera("side", W, H, 60, 60, W / 2, H / 2, look_at(np.zeros(3), np.array([4.0, 0, 0]))))
    result = neighbour_views(cams, list(range(len(cams))), max_count=8, max_angle_deg=30)
    assert result[12] == []
    assert all(12 not in v for v in result.values())
    assert len(result[0]) == 8 and result[0][:2] == [1, 2]  # nearest first
    for i, nbs in result.items():
        for j in nbs:
            angle = math.degrees(math.acos(np.clip((np.trace(cams[i].rotation @ cams[j].rotation.T) - 1) / 2, -1, 1)))
            assert angle <= 30 + 1e-9
