"""The numba projection (rasterizer/projection_numba.py) against the torch reference
(rasterizer/projection.py), values and gradients, on ordinary and extreme Gaussians: zero and
denormal quaternions, log-scales past both clamps, centres on and behind the near plane, far
outside the field of view (the Jacobian clamp), non-finite means, opacities below ALPHA_MIN and
needles. Both compute in float64; tolerances absorb summation order only (1e-9 relative in
float64; float32 outputs are the same float64 values rounded, so 1 ulp)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("numba")

from inceptiongs.rasterizer.projection import project  # noqa: E402

from rasterize_cases import make_camera  # noqa: E402

FIELDS = ("camera_means", "means2d", "conics", "cov2d", "extents")
DIFFERENTIABLE = ("camera_means", "means2d", "conics", "opacities")


def extreme_params(n: int = 600, seed: int = 0, dtype=torch.float64) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=gen, dtype=torch.float64) - 0.5) * 4.0
    log_scales = -3.0 + 1.5 * torch.randn(n, 3, generator=gen, dtype=torch.float64)
    quats = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    logits = 3.0 * torch.randn(n, generator=gen, dtype=torch.float64)
    quats[0:4] = 0.0                                   # zero quaternion -> identity
    quats[4] = torch.tensor([1e-300, 0.0, 0.0, 0.0])   # denormal norm -> identity
    log_scales[5:10, 0] = 40.0                         # above LOG_SCALE_MAX (no gradient)
    log_scales[10:15, 1] = -40.0                       # below LOG_SCALE_MIN
    means[15:20, 2] = -3.0                             # on the camera's plane (z = 0): culled
    means[20:25, 2] = -3.0 + 0.009999999776482582      # exactly at the near plane
    means[25:30] = torch.tensor([6.0, 0.5, -1.0])      # far outside the view: clamped Jacobian
    means[30, 0] = float("nan")
    logits[31:36] = -8.0                               # opacity below ALPHA_MIN: culled
    log_scales[36:40] = torch.tensor([0.0, -12.0, -12.0])  # needles
    return {"means": means.to(dtype), "log_scales": log_scales.to(dtype), "quats": quats.to(dtype),
            "opacity_logits": logits.to(dtype)}


def project_with_grads(params, camera, backend, weights):
    leaves = {k: v.clone().requires_grad_(True) for k, v in params.items()}
    pose = torch.as_tensor(camera.world_to_camera, dtype=torch.float64)
    proj = project(leaves["means"], leaves["log_scales"], leaves["quats"], leaves["opacity_logits"], pose, camera,
                   backend=backend)
    v = proj.visible
    loss = sum((getattr(proj, name) * weights[name].to(params["means"].dtype))[v].sum() for name in DIFFERENTIABLE)
    loss.backward()
    return proj, {k: leaf.grad for k, leaf in leaves.items()}


def random_weights(n, seed=1):
    gen = torch.Generator().manual_seed(seed)
    shapes = {"camera_means": (n, 3), "means2d": (n, 2), "conics": (n, 3), "opacities": (n,)}
    return {name: torch.randn(*shape, generator=gen, dtype=torch.float64) for name, shape in shapes.items()}


@pytest.mark.parametrize("dtype, rtol", [(torch.float64, 1e-9), (torch.float32, 1e-6)])
def test_numba_projection_matches_torch_values_and_gradients(dtype, rtol):
    params = extreme_params(dtype=dtype)
    camera = make_camera(64, 48)
    weights = random_weights(params["means"].shape[0])
    ref, ref_grads = project_with_grads(params, camera, "torch", weights)
    fast, fast_grads = project_with_grads(params, camera, "numba", weights)

    assert torch.equal(ref.visible, fast.visible)
    assert torch.equal(ref.radii, fast.radii)
    visible = ref.visible
    # The cases above must be exercised: some culled, some visible, some clamped.
    assert 50 < int(visible.sum()) < params["means"].shape[0] - 20
    for name in FIELDS:
        a, b = getattr(ref, name).detach(), getattr(fast, name).detach()
        assert a.dtype == b.dtype == dtype, name
        # Culled rows may hold anything finite or not; both must agree on visible ones exactly
        # in kind, and on every finite value within tolerance.
        assert torch.equal(torch.isfinite(a), torch.isfinite(b)), name
        finite = torch.isfinite(a)
        np.testing.assert_allclose(b[finite].numpy(), a[finite].numpy(), rtol=rtol, atol=1e-12, err_msg=name)
    for name in params:
        a, b = ref_grads[name], fast_grads[name]
        # Both give finite gradients, the NaN mean's row included (the reference feeds a
        # non-finite centre through its arithmetic as the origin); the fast path gives culled
        # rows exactly zero.
        assert torch.isfinite(a).all() and torch.isfinite(b).all(), name
        assert torch.all(b[~visible] == 0), name
        scale = float(a.abs().max())
        np.testing.assert_allclose(b.numpy(), a.numpy(), rtol=rtol, atol=rtol * scale, err_msg=name)
    # The clamped log-scales and degenerate quaternions pass no gradient, as in torch.
    assert torch.all(fast_grads["log_scales"][5:10, 0] == 0) and torch.all(fast_grads["log_scales"][10:15, 1] == 0)
    assert torch.all(fast_grads["quats"][0:5] == 0)


def test_numba_gradient_matches_finite_differences():
    """Independent of the torch reference: central differences of a weighted sum of the
    differentiable outputs, on a few visible Gaussians (float64)."""
    params = extreme_params(n=40, seed=3)
    camera = make_camera(64, 48)
    weights = random_weights(40, seed=5)
    proj, grads = project_with_grads(params, camera, "numba", weights)
    visible = proj.visible

    def loss_of(p):
        pose = torch.as_tensor(camera.world_to_camera, dtype=torch.float64)
        out = project(p["means"], p["log_scales"], p["quats"], p["opacity_logits"], pose, camera, backend="numba")
        return float(sum((getattr(out, name) * weights[name])[visible].sum() for name in DIFFERENTIABLE))

    rows = [int(i) for i in torch.nonzero(visible).squeeze(-1)[:4]]
    assert len(rows) == 4
    eps = 1e-6
    for name in ("means", "log_scales", "quats"):
        for row in rows:
            for col in range(params[name].shape[1]):
                plus = {k: v.clone() for k, v in params.items()}
                minus = {k: v.clone() for k, v in params.items()}
                plus[name][row, col] += eps
                minus[name][row, col] -= eps
                numeric = (loss_of(plus) - loss_of(minus)) / (2 * eps)
                analytic = float(grads[name][row, col])
                assert abs(numeric - analytic) <= 1e-5 * max(1.0, abs(numeric)), (name, row, col, numeric, analytic)


def test_a_non_finite_centre_leaves_the_pose_gradient_finite_and_unchanged():
    """Langevin view sampling differentiates the pose through the torch projection: one NaN or
    infinite centre among the Gaussians (culled) must not make that gradient NaN, nor change it."""
    params = {k: v[:30] for k, v in extreme_params().items()}  # finite centres only
    camera = make_camera(64, 48)

    def pose_grad(p):
        pose = torch.as_tensor(camera.world_to_camera, dtype=torch.float64).requires_grad_(True)
        proj = project(p["means"], p["log_scales"], p["quats"], p["opacity_logits"], pose, camera)
        (proj.means2d[proj.visible].sum() + proj.conics[proj.visible].sum()).backward()
        return pose.grad, proj

    clean, _ = pose_grad(params)
    for bad in (float("nan"), float("inf")):
        poisoned = {k: torch.cat([v, v[:1]]) for k, v in params.items()}
        poisoned["means"][-1, 1] = bad
        grad, proj = pose_grad(poisoned)
        assert not bool(proj.visible[-1]) and not bool(torch.isfinite(proj.means2d[-1]).any())
        assert torch.isfinite(grad).all(), bad
        torch.testing.assert_close(grad, clean, rtol=1e-12, atol=1e-12)


def test_auto_uses_torch_when_the_pose_needs_a_gradient():
    params = {k: v[:30] for k, v in extreme_params().items()}  # without the NaN mean (row 30)
    camera = make_camera(64, 48)
    pose = torch.as_tensor(camera.world_to_camera, dtype=torch.float64).requires_grad_(True)
    proj = project(params["means"], params["log_scales"], params["quats"], params["opacity_logits"], pose, camera)
    proj.means2d[proj.visible].sum().backward()
    assert pose.grad is not None and float(pose.grad.abs().sum()) > 0
    with pytest.raises(ValueError, match="pose"):
        project(params["means"], params["log_scales"], params["quats"], params["opacity_logits"], pose, camera,
                backend="numba")
    with pytest.raises(ValueError, match="backend"):
        project(params["means"], params["log_scales"], params["quats"], params["opacity_logits"], pose.detach(),
                camera, backend="cuda")
