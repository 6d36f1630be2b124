"""Stiff and extreme cases for the torch rasterizer.

Each case either matches the brute-force float64 reference (tests/rasterize_cases.py) or
is removed by a named culling rule, and outputs plus gradients stay finite. The rules:

- NEAR/FAR rule: camera z outside [NEAR_PLANE, FAR_PLANE] -> culled (behind, at the camera
  centre, or centre in front of the near plane even if the body straddles it).
- OPACITY rule: sigmoid(clamp(logit, +-OPACITY_LOGIT_ABS_MAX)) < ALPHA_MIN -> culled.
- QUATERNION rule: |q| < QUAT_NORM_MIN (zero, denormal) -> identity rotation.
- SCALE rule: log-scales clamped to [LOG_SCALE_MIN, LOG_SCALE_MAX] before exp.
- FOOTPRINT rule: footprint box entirely outside the image -> culled.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from inceptiongs import constants as K
from inceptiongs.camera import Camera
from inceptiongs.gaussians import Gaussians
from inceptiongs.rasterizer.rasterize import render

from rasterize_cases import brute_force_render, make_camera, random_gaussians

OUTPUTS = ("rgb", "alpha", "depth", "normal", "plane_depth")


def _gaussians(means, log_scales, quats=None, logits=None, dtype=torch.float64, degree=1, seed=0) -> Gaussians:
    means = torch.as_tensor(np.asarray(means, np.float64), dtype=dtype)
    n = means.shape[0]
    gen = torch.Generator().manual_seed(seed)
    log_scales = torch.as_tensor(np.broadcast_to(np.asarray(log_scales, np.float64), (n, 3)).copy(), dtype=dtype)
    quats = torch.tensor([[1.0, 0.2, -0.1, 0.3]] * n, dtype=dtype) if quats is None else torch.as_tensor(quats, dtype=dtype)
    logits = torch.full((n,), 1.0, dtype=dtype) if logits is None else torch.as_tensor(logits, dtype=dtype)
    sh = (0.4 * torch.randn(n, (degree + 1) ** 2, 3, generator=gen, dtype=torch.float64)).to(dtype)
    return Gaussians(means, log_scales, quats, logits, sh)


def _render_and_backprop(g: Gaussians, camera: Camera, outputs=OUTPUTS):
    """Render with gradients on every parameter; check outputs and gradients are finite."""
    params = {k: v.detach().clone().requires_grad_(True) for k, v in g.tensors().items()}
    out = render(Gaussians(**params), camera, outputs=outputs, backend="torch")
    for name in outputs:
        assert torch.isfinite(out[name]).all(), f"{name} not finite"
    loss = sum(out[name].sum() for name in outputs)
    if loss.requires_grad:
        loss.backward()
    for name, p in params.items():
        assert p.grad is None or torch.isfinite(p.grad).all(), f"gradient of {name} not finite"
    return out, params


def _assert_matches_reference(out, g, camera, atol=1e-5, outputs=OUTPUTS):
    """Absolute tolerance, plus for float32 a relative 1e-4: plane depth of an edge-on disc is
    a ratio of two small blended numbers and can be large (~1e2) with float32 rounding."""
    ref = brute_force_render(g, camera)
    rtol = 1e-4 if out["alpha"].dtype == torch.float32 else 0.0
    for name in outputs:
        np.testing.assert_allclose(out[name].detach().to(torch.float64).numpy(), ref[name], atol=atol,
                                   rtol=rtol, err_msg=name)


@pytest.mark.parametrize("dtype,atol", [(torch.float64, 1e-5), (torch.float32, 2e-4)])
def test_log_scales_from_minus_20_to_plus_12(dtype, atol):
    """Tiny (dilation-dominated) to enormous (covers the image) Gaussians match the reference."""
    camera = make_camera()
    log_scales = [[-20.0] * 3, [-8.0] * 3, [-2.0, -3.0, -1.0], [3.0, 2.0, 1.0], [12.0] * 3, [12.0, -20.0, 0.0]]
    means = [[0.1, 0.0, 0.0], [-0.3, 0.2, 0.1], [0.2, -0.2, 0.3], [0.0, 0.1, 1.0], [0.0, 0.0, 2.0], [0.3, 0.3, 0.5]]
    g = _gaussians(means, log_scales, logits=[3.0, 3.0, 0.5, -1.0, -3.0, -2.0], dtype=dtype)
    out, params = _render_and_backprop(g, camera)
    _assert_matches_reference(out, g, camera, atol=atol)
    assert float(out["alpha"].detach().min()) > 0.04  # the log-scale 12 Gaussian really covers every pixel


@pytest.mark.parametrize("dtype,atol", [(torch.float64, 1e-5), (torch.float32, 2e-4)])
def test_anisotropy_one_million_to_one(dtype, atol):
    """Discs (one axis 1e6 x thinner) seen face-on and edge-on, and needles."""
    camera = make_camera()
    means = [[0.0, 0.0, 0.0], [0.4, 0.1, 0.2], [-0.4, -0.2, 0.1], [0.2, -0.4, -0.2]]
    thin = np.log(0.3e-6)
    log_scales = [[np.log(0.3), np.log(0.3), thin], [np.log(0.3), thin, np.log(0.3)],
                  [np.log(0.5), thin + np.log(2), thin], [thin, np.log(0.4), thin]]
    quats = [[1.0, 0, 0, 0], [1.0, 0, 0, 0], [0.9, 0.1, 0.3, 0.2], [0.7, -0.3, 0.0, 0.6]]
    g = _gaussians(means, log_scales, quats=quats, dtype=dtype)
    out, _ = _render_and_backprop(g, camera)
    _assert_matches_reference(out, g, camera, atol=atol)


@pytest.mark.parametrize("dtype,tiny", [(torch.float64, 1e-310), (torch.float32, 1e-40)])
def test_zero_and_denormal_quaternions_are_identity(dtype, tiny):
    """QUATERNION rule: the render equals the identity-rotation render; gradients finite."""
    camera = make_camera()
    means = [[0.0, 0.0, 0.0], [0.3, 0.1, 0.1], [-0.2, 0.2, -0.1]]
    log_scales = [[-1.5, -2.0, -3.0]] * 3
    degenerate = [[0.0, 0.0, 0.0, 0.0], [tiny, 0.0, 0.0, 0.0], [tiny, -tiny, tiny, 0.0]]
    g = _gaussians(means, log_scales, quats=degenerate, dtype=dtype)
    out, params = _render_and_backprop(g, camera)
    identity = _gaussians(means, log_scales, quats=[[1.0, 0, 0, 0]] * 3, dtype=dtype)
    ref = render(identity, camera, outputs=OUTPUTS, backend="torch")
    for name in OUTPUTS:
        assert torch.equal(out[name].detach(), ref[name]), name
    assert torch.all(params["quats"].grad == 0)  # no rotation to differentiate


def test_opacity_logits_plus_minus_50():
    """+50: clamped to the ALPHA_MAX cap, matches the reference; -50: OPACITY rule culls it."""
    camera = make_camera()
    g = _gaussians([[0.0, 0.0, 0.0], [0.2, 0.1, -0.5], [-0.3, 0.0, 0.3]], [[-1.0] * 3] * 3,
                   logits=[50.0, -50.0, 50.0])
    out, params = _render_and_backprop(g, camera)
    _assert_matches_reference(out, g, camera)
    assert out["radii"].tolist()[1] == 0 and out["radii"][0] > 0 and out["radii"][2] > 0
    assert torch.all(params["opacity_logits"].grad == 0)  # beyond the clamp: flat


def test_near_plane_cases():
    """Camera at the origin looking down +z. Kept: centre exactly at NEAR_PLANE and a large
    Gaussian straddling the near plane with its centre in front (projected at its centre, as
    the reference does). Culled by the NEAR/FAR rule: behind, at the camera centre, centre
    just in front of the camera but nearer than NEAR_PLANE, and beyond FAR_PLANE."""
    camera = Camera("origin", 32, 24, 30.0, 30.0, 16.0, 12.0, np.eye(4))
    z_at = K.NEAR_PLANE
    means = [[0.0, 0.0, z_at], [0.01, 0.0, 0.05], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0],
             [0.0, 0.0, 0.5 * K.NEAR_PLANE], [0.0, 0.0, 2 * K.FAR_PLANE], [0.1, 0.1, 1.0]]
    log_scales = [[-6.0] * 3, [np.log(0.2)] * 3, [0.0] * 3, [0.0] * 3, [-1.0] * 3, [5.0] * 3, [-2.0] * 3]
    g = _gaussians(means, log_scales, logits=[1.0, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0], degree=2)
    out, params = _render_and_backprop(g, camera)
    _assert_matches_reference(out, g, camera)
    radii = out["radii"].tolist()
    assert radii[0] > 0 and radii[1] > 0 and radii[6] > 0
    assert radii[2] == radii[3] == radii[4] == radii[5] == 0
    assert torch.all(params["means"].grad[[2, 3, 4, 5]] == 0)


@pytest.mark.parametrize("normalise", [False, True])
def test_scene_translated_one_million_units(normalise):
    """The same scene and camera shifted by 1e6 units.

    float64 model: matches the untranslated render within 1e-6 (the renderer works in float64
    camera space). float32 model, no normalisation: storing a mean near 1e6 in float32
    quantises it to a 1/16-unit grid, which changes the scene itself; the renderer adds
    nothing on top, so it matches the untranslated float64 render of the *quantised* scene
    within 2e-4. float32 after normalisation (recentring in float64 as the scene loader
    does): matches the untranslated float32 render within 2e-4.
    """
    offset = np.array([1e6, -1e6, 1e6])
    camera = make_camera()
    shifted_pose = camera.world_to_camera.copy()
    shifted_pose[:3, 3] -= camera.world_to_camera[:3, :3] @ offset  # same camera, moved by offset
    shifted_camera = camera.with_pose(shifted_pose)
    g = random_gaussians(n=30, degree=2, seed=9)
    far = g.map(lambda t: t.clone())
    far.means = g.means + torch.as_tensor(offset)

    out64 = render(far, shifted_camera, outputs=OUTPUTS, backend="torch")
    near64 = render(g, camera, outputs=OUTPUTS, backend="torch")
    for name in OUTPUTS:
        np.testing.assert_allclose(out64[name].numpy(), near64[name].numpy(), atol=1e-6, err_msg=name)

    if normalise:
        recentred = far.map(lambda t: t.clone())
        recentred.means = far.means - torch.as_tensor(offset)  # float64 recentring, then float32
        out32 = render(recentred.to(dtype=torch.float32), camera, outputs=OUTPUTS, backend="torch")
        reference = render(g.to(dtype=torch.float32), camera, outputs=OUTPUTS, backend="torch")
    else:
        far32 = far.to(dtype=torch.float32)
        assert float((far32.means.double() - far.means).abs().max()) > 1e-3  # storage really quantised
        _, params = _render_and_backprop(far32, shifted_camera)
        out32 = render(far32, shifted_camera, outputs=OUTPUTS, backend="torch")
        quantised = far32.to(dtype=torch.float64)
        quantised.means = quantised.means - torch.as_tensor(offset)
        reference = render(quantised, camera, outputs=OUTPUTS, backend="torch")
    for name in OUTPUTS:
        np.testing.assert_allclose(out32[name].double().numpy(), reference[name].double().numpy(), atol=2e-4,
                                   err_msg=name)


def test_one_by_one_image():
    camera = Camera("px", 1, 1, 2.0, 2.0, 0.5, 0.5, make_camera().world_to_camera)
    g = random_gaussians(n=12, degree=1, seed=12, log_scale=-1.0)
    out, _ = _render_and_backprop(g, camera)
    _assert_matches_reference(out, g, camera)
    assert float(out["alpha"].detach()) > 0.1


def test_one_gaussian():
    camera = make_camera()
    g = random_gaussians(n=1, degree=3, seed=13, spread=0.1, log_scale=-1.0)
    out, _ = _render_and_backprop(g, camera)
    _assert_matches_reference(out, g, camera)
    assert out["radii"].tolist()[0] > 0


@pytest.mark.slow
def test_4096_square_image_with_few_gaussians():
    """4096x4096: finite everywhere, pixels outside every footprint are exactly empty, and a
    window around the Gaussians equals the brute force on that window's cropped camera
    (all centres are inside the window's frustum, so the Jacobian clamp is inactive in both)."""
    size = 4096
    pose = make_camera().world_to_camera
    camera = Camera("big", size, size, 3000.0, 3000.0, size / 2, size / 2, pose)
    g = _gaussians([[0.0, 0.0, 0.0], [0.003, 0.002, 0.1], [-0.002, 0.003, -0.1]], [[-5.5] * 3] * 3,
                   dtype=torch.float32, logits=[2.0, 1.0, 0.0])
    out = render(g, camera, outputs=("rgb", "alpha"), backend="torch")
    assert out["rgb"].shape == (size, size, 3)
    assert torch.isfinite(out["rgb"]).all() and torch.isfinite(out["alpha"]).all()
    x0, y0, w = size // 2 - 24, size // 2 - 24, 48
    window = camera.cropped(x0, y0, w, w)
    ref = brute_force_render(g, window)
    for name in ("rgb", "alpha"):
        np.testing.assert_allclose(out[name][y0:y0 + w, x0:x0 + w].double().numpy(), ref[name], atol=2e-4)
    outside = out["alpha"].clone()
    outside[y0:y0 + w, x0:x0 + w] = 0
    assert float(outside.abs().max()) == 0.0
    assert float(out["alpha"][y0:y0 + w, x0:x0 + w].max()) > 0.5


def test_all_gaussians_at_one_point():
    """100 Gaussians sharing one centre: equal depths, blended in index order, stop rule hit."""
    camera = make_camera(20, 16)
    gen = torch.Generator().manual_seed(14)
    n = 100
    g = _gaussians(np.zeros((n, 3)), (-1.5 + 0.5 * torch.randn(n, 3, generator=gen)).numpy(),
                   quats=torch.randn(n, 4, generator=gen), logits=torch.randn(n, generator=gen) + 1.0, degree=1)
    ref = brute_force_render(g, camera)
    for dtype, atol in ((torch.float64, 1e-5), (torch.float32, 2e-4)):
        out, _ = _render_and_backprop(g.to(dtype=dtype), camera)
        for name in OUTPUTS:
            np.testing.assert_allclose(out[name].detach().double().numpy(), ref[name], atol=atol,
                                       rtol=1e-4 if dtype == torch.float32 else 0.0, err_msg=name)
        assert float(out["alpha"].detach().max()) > 1 - 2 * K.TRANSMITTANCE_MIN


@pytest.mark.slow
def test_one_million_gaussians_forward_memory_bounded():
    """1e6 random Gaussians around a camera (most culled by the NEAR/FAR or FOOTPRINT rule,
    the rest tiny): forward finishes with finite outputs and the process's peak RSS stays
    under 3 GB. Run in a fresh interpreter so ru_maxrss measures this render alone."""
    script = textwrap.dedent("""
        import resource, torch
        from inceptiongs.camera import Camera
        from inceptiongs.gaussians import Gaussians
        from inceptiongs.rasterizer.rasterize import render
        torch.set_num_threads(2)
        gen = torch.Generator().manual_seed(0)
        n = 1_000_000
        g = Gaussians((torch.rand(n, 3, generator=gen) - 0.5) * 40, torch.randn(n, 3, generator=gen) - 5.0,
                      torch.randn(n, 4, generator=gen), torch.randn(n, generator=gen),
                      0.3 * torch.randn(n, 1, 3, generator=gen))
        camera = Camera("c", 256, 192, 200.0, 200.0, 128.0, 96.0, torch.eye(4, dtype=torch.float64).numpy())
        with torch.no_grad():
            out = render(g, camera, outputs=("rgb", "alpha", "depth"), backend="torch")
        finite = all(bool(torch.isfinite(out[k]).all()) for k in ("rgb", "alpha", "depth"))
        visible = int((out["radii"] > 0).sum())
        print(finite, visible, float(out["alpha"].mean()), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    """)
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    finite, visible, mean_alpha, max_rss_kb = result.stdout.split()
    assert finite == "True"
    assert 1000 < int(visible) < 1_000_000  # some survive, most are culled
    assert float(mean_alpha) > 0.01
    assert int(max_rss_kb) < 3 * 1024 * 1024
