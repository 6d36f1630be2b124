"""The rasterizer contract: every registered rasterizer (RASTERIZERS) that can run here gives
the torch reference's outputs and gradients, within the tolerances stated per backend.

Every case renders float32 Gaussians (gsplat computes in float32) and compares with the torch
reference in float64 on the same values. torch and numba run on any machine; gsplat runs
where a CUDA GPU, gsplat and a CUDA compiler are all present, and skips saying which is missing.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inceptiongs.gaussians import Gaussians
from inceptiongs.rasterizer.backend import numba_installed
from inceptiongs.rasterizer.interface import RASTERIZERS, RenderResult, cuda_missing, get_rasterizer
from inceptiongs.rasterizer.rasterize import render

from rasterize_cases import make_camera, random_gaussians

OUTPUTS = ("rgb", "alpha", "depth", "plane_depth", "normal", "features")
PARAMETERS = ("means", "log_scales", "quats", "opacity_logits", "sh")

# Outputs: |a - b| <= atol + rtol |b| (rtol: plane depth is a ratio of two blended numbers, large
# on edge-on discs). Gradients: |a - b| <= grad_rtol * max |b| per parameter. float32 against the
# float64 reference; gsplat's (sort by tile, footprint of 3 sigma, its own float32 arithmetic)
# gets ten times the room.
TOLERANCES = {
    "torch": {"atol": 2e-4, "rtol": 1e-4, "grad_rtol": 1e-3},
    "numba": {"atol": 2e-4, "rtol": 1e-4, "grad_rtol": 1e-3},
    "gsplat": {"atol": 2e-3, "rtol": 1e-3, "grad_rtol": 1e-2},
}


def unavailable(name: str) -> str | None:
    """Why rasterizer ``name`` cannot run here (a skip reason), or None."""
    if name == "numba" and not numba_installed():
        return "numba is not installed"
    if name == "gsplat":
        missing = cuda_missing()
        return None if missing is None else f"gsplat needs CUDA: {missing[0]} ({missing[1]})"
    return None


def stiff_discs(seed: int = 3) -> Gaussians:
    """Discs one million times thinner than wide, face-on and edge-on, and needles (the
    stability suite's anisotropy case), with a saturated and a vanishing opacity."""
    means = torch.tensor([[0.0, 0.0, 0.0], [0.4, 0.1, 0.2], [-0.4, -0.2, 0.1], [0.2, -0.4, -0.2],
                          [-0.1, 0.3, 0.3]], dtype=torch.float64)
    thin, wide = np.log(0.3e-6), np.log(0.3)
    log_scales = torch.tensor([[wide, wide, thin], [wide, thin, wide], [np.log(0.5), thin + np.log(2), thin],
                               [thin, np.log(0.4), thin], [wide, wide - 1.0, thin]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0], [0.9, 0.1, 0.3, 0.2], [0.7, -0.3, 0.0, 0.6],
                          [0.5, 0.5, -0.5, 0.5]], dtype=torch.float64)
    logits = torch.tensor([1.0, 2.0, 0.5, 50.0, -50.0], dtype=torch.float64)
    sh = 0.4 * torch.randn(5, 4, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    return Gaussians(means, log_scales, quats, logits, sh)


CASES = {
    "random degree 3": lambda: random_gaussians(n=40, degree=3, seed=6),
    "random degree 0": lambda: random_gaussians(n=24, degree=0, seed=1),
    "stiff discs": stiff_discs,
}


def render_with_gradients(rasterizer, g: Gaussians, features: torch.Tensor, camera, weights: dict, background):
    """Render every output with gradients on every parameter and the features; backpropagate a
    fixed weighted sum -> (result, {parameter: grad}, means2d grad)."""
    leaves = {k: v.detach().clone().requires_grad_(True) for k, v in g.tensors().items()}
    feats = features.detach().clone().requires_grad_(True)
    out = rasterizer(Gaussians(**leaves), camera, outputs=OUTPUTS, features=feats, background=background)
    loss = sum((out[name] * weights[name]).sum() for name in OUTPUTS)
    loss.backward()
    grads = {name: leaves[name].grad for name in PARAMETERS}
    grads["features"] = feats.grad
    return out, grads, out["means2d"].grad


def reference(g: Gaussians, features, camera, weights, background):
    as64 = Gaussians(**{k: v.to(torch.float64) for k, v in g.tensors().items()})

    def torch64(gaussians, camera, **kwargs):
        return render(gaussians, camera, backend="torch", **kwargs)

    return render_with_gradients(torch64, as64, features.to(torch.float64), camera, weights, background)


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("name", list(RASTERIZERS))
def test_rasterizer_matches_the_torch_reference(name, case):
    reason = unavailable(name)
    if reason is not None:
        pytest.skip(reason)
    tol = TOLERANCES[name]
    g32 = Gaussians(**{k: v.to(torch.float32) for k, v in CASES[case]().tensors().items()})
    camera = make_camera(48, 32)
    gen = torch.Generator().manual_seed(11)
    features = torch.randn(len(g32), 5, generator=gen)
    channels = {"rgb": 3, "alpha": 1, "depth": 1, "plane_depth": 1, "normal": 3, "features": 5}
    weights = {k: torch.randn(32, 48, c, generator=gen, dtype=torch.float64) for k, c in channels.items()}
    background = torch.tensor([0.2, 0.5, 0.9])

    out, grads, means2d_grad = render_with_gradients(
        get_rasterizer(name), g32, features, camera, {k: w.float() for k, w in weights.items()}, background)
    ref, ref_grads, ref_means2d_grad = reference(g32, features, camera, weights, background)

    assert isinstance(out, RenderResult)
    for output in OUTPUTS:
        np.testing.assert_allclose(out[output].detach().double().numpy(), ref[output].detach().numpy(),
                                   atol=tol["atol"], rtol=tol["rtol"], err_msg=f"{name} {output}")
    drawn = ref["radii"] > 0
    assert torch.equal(out["radii"] > 0, drawn), f"{name}: which Gaussians are drawn"
    np.testing.assert_allclose(out["means2d"].detach().double()[drawn].numpy(), ref["means2d"].detach()[drawn].numpy(),
                               atol=tol["atol"] * 10, err_msg=f"{name} means2d")
    ref_grads["means2d"], grads["means2d"] = ref_means2d_grad, means2d_grad
    for param, expected in ref_grads.items():
        assert grads[param] is not None, f"{name}: no gradient for {param}"
        scale = float(expected.abs().max())
        np.testing.assert_allclose(grads[param].double().numpy(), expected.numpy(), rtol=0,
                                   atol=tol["grad_rtol"] * max(scale, 1e-12), err_msg=f"{name} d/d{param}")


@pytest.mark.parametrize("name", list(RASTERIZERS))
def test_outputs_nobody_asked_for_are_none(name):
    reason = unavailable(name)
    if reason is not None:
        pytest.skip(reason)
    g = Gaussians(**{k: v.float() for k, v in random_gaussians(n=8, seed=2).tensors().items()})
    out = get_rasterizer(name)(g, make_camera(16, 12), outputs=("alpha",))
    assert out.alpha is not None and out.alpha.shape == (12, 16, 1)
    assert out.rgb is None and out.depth is None and out.features is None
    assert "rgb" not in out and "alpha" in out and set(out.keys()) == {"means2d", "radii", "alpha"}


def test_gsplat_arguments_follow_gsplat_conventions_on_the_cpu():
    """The gsplat backend's scene and camera arguments, fed to gsplat's own pure-torch projection
    (which runs without a GPU), give the reference's pixel centres and conics: quaternion order,
    post-activation scales, world-to-camera and K agree with what gsplat expects."""
    pytest.importorskip("gsplat", reason="gsplat is not installed (pip install 'inceptiongs[cuda]')")
    from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci

    from inceptiongs import constants
    from inceptiongs.rasterizer.gsplat_backend import gsplat_inputs
    from inceptiongs.rasterizer.projection import project

    g = random_gaussians(n=40, degree=1, seed=4)
    camera = make_camera(48, 32)
    pose = torch.as_tensor(camera.world_to_camera, dtype=torch.float64)
    args = gsplat_inputs(g, pose, camera)
    covars, _ = _quat_scale_to_covar_preci(args["quats"], args["scales"], compute_preci=False)
    radii, means2d, depths, conics, _ = _fully_fused_projection(
        args["means"], covars, args["viewmats"], args["Ks"], camera.width, camera.height,
        eps2d=constants.DILATION_PX, near_plane=constants.NEAR_PLANE, far_plane=constants.FAR_PLANE)
    ref = project(g.means, g.log_scales, g.quats, g.opacity_logits, pose, camera, backend="torch")
    drawn = ref.visible & (radii[0] > 0).all(-1)
    assert drawn.sum() >= 20
    np.testing.assert_allclose(means2d[0][drawn].double().numpy(), ref.means2d[drawn].detach().numpy(), atol=1e-3)
    np.testing.assert_allclose(conics[0][drawn].double().numpy(), ref.conics[drawn].detach().numpy(),
                               rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(depths[0].double().numpy(), ref.camera_means[:, 2].detach().numpy(), rtol=1e-5)


def fake_rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, render_mode,
                       near_plane, far_plane, eps2d, packed):
    """gsplat.rasterization's call and return shapes (unpacked, one camera) computed by the torch
    reference stages: stands in for the CUDA kernels so the backend's glue runs on the CPU."""
    from inceptiongs.camera import Camera
    from inceptiongs.rasterizer.composite import composite
    from inceptiongs.rasterizer.projection import project

    assert render_mode == "RGB" and not packed and eps2d == 0.3 and near_plane > 0 and far_plane > near_plane
    k = Ks[0].double()
    camera = Camera("fake", width, height, float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
                    viewmats[0].double().detach().numpy())
    proj = project(means, torch.log(scales), quats, torch.logit(opacities), viewmats[0].double(), camera,
                   backend="torch")
    means2d = proj.means2d[None]          # the tensor gsplat returns, on the path to the image
    keep = torch.nonzero(proj.visible).squeeze(-1)
    image, alpha = composite(means2d[0][keep], proj.conics[keep], proj.opacities[keep], colors[keep],
                             proj.camera_means[keep, 2].detach(), proj.extents[keep].detach(), width, height,
                             backend="torch")
    radii = torch.stack([proj.radii, proj.radii], -1).to(torch.int32)[None]
    return image[None], alpha[None], {"means2d": means2d, "radii": radii}


def test_gsplat_backend_glue_on_the_cpu(monkeypatch):
    """The gsplat backend around a stand-in for gsplat's kernels: every output, the means2d
    gradient and the parameter gradients come back as the reference's (the kernels themselves
    are checked by the contract test on a GPU machine)."""
    pytest.importorskip("gsplat", reason="gsplat is not installed (pip install 'inceptiongs[cuda]')")
    from inceptiongs.rasterizer import gsplat_backend

    monkeypatch.setattr(gsplat_backend, "rasterization", fake_rasterization)
    g32 = Gaussians(**{k: v.to(torch.float32) for k, v in random_gaussians(n=30, degree=2, seed=8).tensors().items()})
    camera = make_camera(40, 28)
    gen = torch.Generator().manual_seed(5)
    features = torch.randn(len(g32), 4, generator=gen)
    channels = {"rgb": 3, "alpha": 1, "depth": 1, "plane_depth": 1, "normal": 3, "features": 4}
    weights = {k: torch.randn(28, 40, c, generator=gen) for k, c in channels.items()}
    background = torch.tensor([0.3, 0.1, 0.7])
    out, grads, means2d_grad = render_with_gradients(gsplat_backend.GsplatRasterizer(device="cpu"), g32, features,
                                                     camera, weights, background)
    ref, ref_grads, ref_means2d_grad = render_with_gradients(get_rasterizer("torch"), g32, features, camera,
                                                             weights, background)
    for output in OUTPUTS:
        np.testing.assert_allclose(out[output].detach().numpy(), ref[output].detach().numpy(), atol=1e-5,
                                   rtol=1e-5, err_msg=output)
    assert torch.equal(out["radii"], ref["radii"])
    ref_grads["means2d"], grads["means2d"] = ref_means2d_grad, means2d_grad
    for param, expected in ref_grads.items():
        np.testing.assert_allclose(grads[param].numpy(), expected.numpy(), rtol=0,
                                   atol=1e-4 * float(expected.abs().max()), err_msg=param)
