"""render() against the brute-force per-pixel float64 reference, plus the contract details
(outputs, background, SH cap, empty scenes, plane depth on synthetic planes)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inceptiongs.rasterizer import composite as composite_module
from inceptiongs.camera import Camera, look_at
from inceptiongs.rasterizer.composite import composite_torch
from inceptiongs.gaussians import Gaussians
from inceptiongs.rasterizer.rasterize import render

from rasterize_cases import brute_force_render, make_camera, random_gaussians

ALL = ("rgb", "alpha", "depth", "normal", "plane_depth", "features")


def _with_opaque_stack(g: Gaussians) -> Gaussians:
    """Append 6 large, nearly opaque Gaussians stacked along the view axis: enough layers for
    the transmittance to drop below TRANSMITTANCE_MIN, so the stop rule is exercised."""
    n = 6
    extra = Gaussians(
        means=torch.tensor([[0.05 * i, -0.03 * i, -0.6 + 0.2 * i] for i in range(n)], dtype=g.dtype),
        log_scales=torch.full((n, 3), -1.0, dtype=g.dtype),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n, dtype=g.dtype),
        opacity_logits=torch.full((n,), 4.0, dtype=g.dtype),
        sh=0.5 * torch.ones(n, g.sh.shape[1], 3, dtype=g.dtype),
    )
    return Gaussians(**{k: torch.cat([getattr(g, k), getattr(extra, k)]) for k in g.tensors()})


def _with_offscreen_giants(g: Gaussians) -> Gaussians:
    """Append large Gaussians whose centres lie outside the clamped frustum (x/z ~ 2) but
    whose footprints reach into the image: they exercise the EWA Jacobian clamp."""
    dtype = g.dtype
    extra = Gaussians(
        means=torch.tensor([[2.0, 0.3, -2.0], [-1.8, -0.2, -1.9], [0.2, 1.7, -2.1]], dtype=dtype),
        log_scales=torch.tensor([[0.0, -0.5, -1.0], [-0.3, 0.1, -2.0], [-0.2, -0.2, -0.2]], dtype=dtype),
        quats=torch.tensor([[1.0, 0.2, 0.1, 0.0], [0.5, 0.5, 0.1, 0.3], [1.0, 0.0, 0.0, 0.0]], dtype=dtype),
        opacity_logits=torch.tensor([0.0, 1.0, -0.5], dtype=dtype),
        sh=0.3 * torch.ones(3, g.sh.shape[1], 3, dtype=dtype),
    )
    return Gaussians(**{k: torch.cat([getattr(g, k), getattr(extra, k)]) for k in g.tensors()})


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_matches_brute_force_float64(degree):
    g = _with_offscreen_giants(_with_opaque_stack(random_gaussians(n=30, degree=degree, seed=degree)))
    camera = make_camera()
    features = torch.randn(len(g), 2, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    background = (0.2, 0.5, 0.9)
    out = render(g, camera, outputs=ALL, background=background, features=features, backend="torch")
    ref = brute_force_render(g, camera, features=features.numpy(), background=background)
    assert float(ref["alpha"].max()) > 1 - 2e-4  # the stack really reached the stop rule
    for name in ALL:
        np.testing.assert_allclose(out[name].detach().numpy(), ref[name], atol=1e-5, rtol=0, err_msg=name)


def test_matches_brute_force_float32():
    g = _with_opaque_stack(random_gaussians(n=30, degree=2, seed=11))
    camera = make_camera(40, 28)
    out = render(g.to(dtype=torch.float32), camera, outputs=("rgb", "alpha", "depth"), backend="torch")
    ref = brute_force_render(g, camera)
    for name in ("rgb", "alpha", "depth"):
        # float32 rounding in the conic and the cumulative product: ~1e-6 relative.
        np.testing.assert_allclose(out[name].numpy(), ref[name], atol=1e-4, rtol=0, err_msg=name)


def test_sh_degree_cap_equals_truncated_model():
    g = random_gaussians(n=20, degree=3, seed=3)
    camera = make_camera()
    capped = render(g, camera, sh_degree=1, backend="torch")["rgb"]
    truncated = Gaussians(g.means, g.log_scales, g.quats, g.opacity_logits, g.sh[:, :4])
    np.testing.assert_allclose(capped.numpy(), render(truncated, camera, backend="torch")["rgb"].numpy(), atol=1e-12)
    full = render(g, camera, backend="torch")["rgb"]
    assert float((full - capped).abs().max()) > 1e-3  # the cap really removed bands


def test_returns_exactly_the_requested_outputs():
    g = random_gaussians(n=10)
    out = render(g, make_camera(), outputs=("alpha", "depth"), backend="torch")
    assert set(out) == {"alpha", "depth", "means2d", "radii"}
    assert out["means2d"].shape == (10, 2) and out["radii"].shape == (10,)
    assert out["radii"].dtype == torch.int64
    with pytest.raises(ValueError):
        render(g, make_camera(), outputs=("colour",))
    with pytest.raises(ValueError):
        render(g, make_camera(), outputs=("features",))


def test_means2d_gradient_is_retained():
    g = random_gaussians(n=15)
    g.means.requires_grad_(True)
    out = render(g, make_camera(), backend="torch")
    out["rgb"].sum().backward()
    grad = out["means2d"].grad
    assert grad is not None and grad.shape == (15, 2)
    visible = out["radii"] > 0
    assert torch.all(grad[~visible] == 0)
    assert float(grad[visible].abs().sum()) > 0


def test_zero_gaussians_give_background():
    g = Gaussians.empty(sh_degree=2, dtype=torch.float64)
    out = render(g, make_camera(), outputs=ALL, background=torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64),
                 features=torch.zeros(0, 4, dtype=torch.float64), backend="torch")
    assert torch.allclose(out["rgb"], torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64).expand(24, 32, 3))
    for name in ("alpha", "depth", "normal", "plane_depth", "features"):
        assert torch.all(out[name] == 0), name
    assert out["features"].shape == (24, 32, 4)


def test_result_does_not_depend_on_generous_extents():
    """Binning with boxes 3x too large must not change a pixel (extents only bin)."""
    gen = torch.Generator().manual_seed(2)
    m = 40
    means2d = torch.rand(m, 2, generator=gen, dtype=torch.float64) * torch.tensor([48.0, 40.0])
    cov = torch.rand(m, 3, generator=gen, dtype=torch.float64)
    xx, xy, yy = 4 + 20 * cov[:, 0], 3 * (cov[:, 1] - 0.5), 4 + 20 * cov[:, 2]
    det = xx * yy - xy * xy
    conics = torch.stack([yy / det, -xy / det, xx / det], -1)
    opacities = 0.05 + 0.9 * torch.rand(m, generator=gen, dtype=torch.float64)
    values = torch.rand(m, 3, generator=gen, dtype=torch.float64)
    depths = torch.rand(m, generator=gen, dtype=torch.float64)
    level = torch.log(opacities / (1 / 255))
    extents = torch.sqrt(2 * level[:, None] * torch.stack([xx, yy], -1))
    tight = composite_torch(means2d, conics, opacities, values, depths, extents, 48, 40)
    loose = composite_torch(means2d, conics, opacities, values, depths, 3 * extents, 48, 40)
    for a, b in zip(tight, loose):
        np.testing.assert_allclose(a.numpy(), b.numpy(), atol=1e-13)


def test_many_gaussians_per_tile_and_small_memory_budget(monkeypatch):
    """Rounds of 5 Gaussians per tile and steps of one tile (T and the finished flag carried
    between rounds) give the brute-force image."""
    monkeypatch.setattr(composite_module, "PIXEL_PAIR_BUDGET", 16 * 16 * 8)
    monkeypatch.setattr(composite_module, "ROUND_GAUSSIANS", 5)
    g = _with_opaque_stack(random_gaussians(n=60, degree=0, seed=7, log_scale=-1.8))
    camera = make_camera(36, 20)
    out = render(g, camera, outputs=("rgb", "alpha"), backend="torch")
    ref = brute_force_render(g, camera)
    for name in ("rgb", "alpha"):
        np.testing.assert_allclose(out[name].numpy(), ref[name], atol=1e-5, err_msg=name)


def test_saturated_tiles_drop_out_without_changing_the_image(monkeypatch):
    """An opaque wall in front of many small Gaussians: every pixel reaches the stop rule in
    the first rounds, tiles drop out, and the result still equals the brute force (which
    never sees the hidden Gaussians either)."""
    monkeypatch.setattr(composite_module, "ROUND_GAUSSIANS", 4)
    camera = make_camera(32, 32)
    wall = Gaussians(
        means=torch.tensor([[0.0, 0.0, -1.8 + 0.05 * i] for i in range(4)], dtype=torch.float64),
        log_scales=torch.full((4, 3), 1.5, dtype=torch.float64),
        quats=torch.tensor([[1.0, 0, 0, 0]] * 4, dtype=torch.float64),
        opacity_logits=torch.full((4,), 10.0, dtype=torch.float64),
        sh=0.3 * torch.ones(4, 1, 3, dtype=torch.float64),
    )
    hidden = random_gaussians(n=40, degree=0, seed=15, log_scale=-1.5)
    g = Gaussians(**{k: torch.cat([getattr(wall, k), getattr(hidden, k)]) for k in wall.tensors()})
    out = render(g, camera, outputs=("rgb", "alpha", "depth"), backend="torch")
    ref = brute_force_render(g, camera)
    for name in ("rgb", "alpha", "depth"):
        np.testing.assert_allclose(out[name].numpy(), ref[name], atol=1e-5, err_msg=name)
    # Every pixel stopped inside the wall: the hidden Gaussians add nothing anywhere.
    wall_only = render(wall, camera, outputs=("rgb", "alpha"), backend="torch")
    for name in ("rgb", "alpha"):
        np.testing.assert_allclose(out[name].numpy(), wall_only[name].numpy(), atol=1e-12, err_msg=name)


def test_checkpointed_steps_give_the_same_gradients(monkeypatch):
    """Large images recompute steps in the backward pass; gradients must not change."""
    g = _with_opaque_stack(random_gaussians(n=30, degree=1, seed=8))
    camera = make_camera(40, 30)

    def gradients():
        params = {k: v.clone().requires_grad_(True) for k, v in g.tensors().items()}
        out = render(Gaussians(**params), camera, outputs=("rgb", "depth", "alpha"), backend="torch")
        (out["rgb"].sum() + out["depth"].sum() + out["alpha"].square().sum()).backward()
        return {k: p.grad for k, p in params.items()}

    monkeypatch.setattr(composite_module, "PIXEL_PAIR_BUDGET", 16 * 16 * 16)
    monkeypatch.setattr(composite_module, "CHECKPOINT_ABOVE", 1 << 40)
    plain = gradients()
    monkeypatch.setattr(composite_module, "CHECKPOINT_ABOVE", 0)
    checkpointed = gradients()
    for name in plain:
        assert float(plain[name].abs().max()) > 0, name
        np.testing.assert_allclose(checkpointed[name].numpy(), plain[name].numpy(), atol=1e-12, err_msg=name)


def test_equal_depths_blend_in_index_order():
    """Two Gaussians at the same depth: the lower index is in front (stable order)."""
    dtype = torch.float64
    g = Gaussians(
        means=torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=dtype),
        log_scales=torch.full((2, 3), -1.0, dtype=dtype),
        quats=torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0]], dtype=dtype),
        opacity_logits=torch.tensor([2.0, 2.0], dtype=dtype),
        sh=torch.tensor([[[1.0, -1.0, -1.0]], [[-1.0, 1.0, -1.0]]], dtype=dtype),
    )
    camera = make_camera(16, 16)
    out = render(g, camera, backend="torch")["rgb"]
    ref = brute_force_render(g, camera)["rgb"]
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-12)
    centre = out[8, 8]
    assert centre[0] > centre[1]  # red (index 0) in front of green


def _plane_of_flat_gaussians(normal_world: np.ndarray, point: np.ndarray, dtype=torch.float64) -> Gaussians:
    """A 9x9 grid of flat, overlapping, opaque Gaussians on the plane through ``point``."""
    normal_world = normal_world / np.linalg.norm(normal_world)
    helper = np.array([1.0, 0, 0]) if abs(normal_world[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(normal_world, helper)
    u /= np.linalg.norm(u)
    v = np.cross(normal_world, u)
    rotation = np.stack([u, v, normal_world], 1)  # local z = normal = smallest scale axis
    from inceptiongs.camera import rotation_to_quat
    q = rotation_to_quat(rotation)
    grid = np.linspace(-1.2, 1.2, 9)
    means = np.array([point + a * u + b * v for a in grid for b in grid])
    n = len(means)
    return Gaussians(
        means=torch.tensor(means, dtype=dtype),
        log_scales=torch.tensor([[np.log(0.25), np.log(0.25), np.log(1e-4)]] * n, dtype=dtype),
        quats=torch.tensor(np.tile(q, (n, 1)), dtype=dtype),
        opacity_logits=torch.full((n,), 5.0, dtype=dtype),
        sh=torch.zeros(n, 1, 3, dtype=dtype),
    )


@pytest.mark.parametrize("normal_world", [(0.0, 0.0, 1.0), (0.4, -0.3, 1.0)])
def test_plane_depth_on_a_plane_of_flat_gaussians(normal_world):
    """Plane depth is the exact ray-plane intersection depth (for a fronto-parallel plane that
    is also the rendered expected depth), and the normal faces the camera."""
    camera = make_camera(32, 24, eye=(0.0, 0.0, -3.0))
    point = np.array([0.0, 0.0, 0.0])
    normal_world = np.array(normal_world)
    g = _plane_of_flat_gaussians(normal_world, point)
    out = render(g, camera, outputs=("alpha", "depth", "plane_depth", "normal"), backend="torch")
    covered = out["alpha"][..., 0].numpy() > 0.9
    assert covered.mean() > 0.5
    # Analytic: ray x = z K^-1 [u, v, 1] in camera space meets n_c . x = n_c . p_c.
    rot, trans = camera.world_to_camera[:3, :3], camera.world_to_camera[:3, 3]
    n_c = rot @ (normal_world / np.linalg.norm(normal_world))
    p_c = rot @ point + trans
    cols, rows = np.meshgrid(np.arange(32) + 0.5, np.arange(24) + 0.5)
    rays = np.stack([(cols - camera.cx) / camera.fx, (rows - camera.cy) / camera.fy, np.ones_like(cols)], -1)
    expected = (n_c @ p_c) / (rays @ n_c)
    plane_depth = out["plane_depth"][..., 0].numpy()
    np.testing.assert_allclose(plane_depth[covered], expected[covered], rtol=1e-9)
    blended_normal = out["normal"].numpy()[covered]
    facing = n_c if n_c @ p_c < 0 else -n_c
    unit = blended_normal / np.linalg.norm(blended_normal, axis=-1, keepdims=True)
    np.testing.assert_allclose(unit, np.broadcast_to(facing, unit.shape), atol=1e-9)
    if normal_world[0] == 0:
        # Every Gaussian centre lies at the plane's depth, so the expected depth is exact too.
        np.testing.assert_allclose(out["depth"][..., 0].numpy()[covered], expected[covered], rtol=1e-9)


def test_pose_override_matches_camera_pose():
    g = random_gaussians(n=20)
    camera = make_camera()
    other = look_at(np.array([0.5, 0.2, -2.5]), np.zeros(3))
    moved = Camera(camera.name, camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, other)
    via_tensor = render(g, camera, world_to_camera=torch.tensor(other), backend="torch")["rgb"]
    np.testing.assert_allclose(via_tensor.numpy(), render(g, moved, backend="torch")["rgb"].numpy(), atol=1e-12)


def test_auto_backend_agrees_with_torch():
    pytest.importorskip("inceptiongs.rasterizer.composite_numba", reason="numba fast path not present")
    g = _with_opaque_stack(random_gaussians(n=40, degree=1, seed=4)).to(dtype=torch.float32)
    camera = make_camera(48, 32)
    fast = render(g, camera, outputs=("rgb", "alpha", "depth"), backend="auto")
    ref = render(g, camera, outputs=("rgb", "alpha", "depth"), backend="torch")
    for name in ("rgb", "alpha", "depth"):
        np.testing.assert_allclose(fast[name].numpy(), ref[name].numpy(), atol=1e-4, err_msg=name)


def test_composite_rejects_unknown_backend():
    from inceptiongs.rasterizer.composite import composite
    z = torch.zeros(0, 2)
    with pytest.raises(ValueError):
        composite(z, torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3), torch.zeros(0), z, 4, 4, backend="cuda")
    image, alpha = composite(z, torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3), torch.zeros(0), z, 5, 3,
                             backend="torch")
    assert image.shape == (3, 5, 3) and alpha.shape == (3, 5, 1)
    assert torch.all(image == 0) and torch.all(alpha == 0)


def test_fast_paths_give_the_torch_reference_gradients():
    """render() with every numba fast path (projection, SH colour, composite) against the torch
    reference, gradients of every parameter included (float64, degree 3, the stop rule and the
    Jacobian clamp exercised)."""
    pytest.importorskip("numba")
    g = _with_offscreen_giants(_with_opaque_stack(random_gaussians(n=40, degree=3, seed=6)))
    camera = make_camera(48, 32)
    weights = torch.randn(32, 48, 5, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    grads = {}
    for backend in ("torch", "numba"):
        leaves = {k: v.clone().requires_grad_(True) for k, v in g.tensors().items()}
        out = render(Gaussians(**leaves), camera, outputs=("rgb", "alpha", "depth"), backend=backend)
        stacked = torch.cat([out["rgb"], out["alpha"], out["depth"]], -1)
        (stacked * weights).sum().backward()
        grads[backend] = {k: v.grad for k, v in leaves.items()}
    for name, ref in grads["torch"].items():
        scale = float(ref.abs().max())
        assert scale > 0, name
        np.testing.assert_allclose(grads["numba"][name].numpy(), ref.numpy(), rtol=1e-6, atol=1e-9 * scale,
                                   err_msg=name)
