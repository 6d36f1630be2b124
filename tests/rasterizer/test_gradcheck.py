"""torch.autograd.gradcheck (float64) of render() for every differentiable input.

Small configurations (a 32x24 image, ~14 Gaussians). fast_mode checks random directional
derivatives (v^T J u) instead of building the full Jacobian, which keeps each check well under
a second. Opacities stay far from the ALPHA_MAX cap and the scene far from the stop rule so
the finite differences (eps 1e-6) do not straddle the renderer's few discontinuities.
"""

from __future__ import annotations

import pytest
import torch
from torch.autograd import gradcheck

from inceptiongs.gaussians import Gaussians
from inceptiongs.rasterizer.rasterize import render

from rasterize_cases import make_camera, random_gaussians

OUTPUTS = ("rgb", "alpha", "depth", "normal", "plane_depth")


def _check(function, *inputs):
    assert gradcheck(function, inputs, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=True)


def _scene(degree=1, seed=0):
    g = random_gaussians(n=14, degree=degree, seed=seed, spread=0.8, log_scale=-1.6)
    g.opacity_logits.clamp_(-2.0, 1.5)
    return g


def _replace(g: Gaussians, **changes) -> Gaussians:
    fields = g.tensors()
    fields.update(changes)
    return Gaussians(**fields)


def _outputs(out: dict) -> tuple:
    return tuple(out[name] for name in OUTPUTS if name in out)


@pytest.mark.parametrize("name", ["means", "log_scales", "quats", "opacity_logits"])
def test_gradcheck_geometry(name):
    g = _scene(seed=1)
    camera = make_camera()

    def f(x):
        return _outputs(render(_replace(g, **{name: x}), camera, outputs=OUTPUTS, backend="torch"))

    _check(f, getattr(g, name).clone().requires_grad_(True))


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_gradcheck_sh(degree):
    g = _scene(degree=degree, seed=2 + degree)
    camera = make_camera()

    def f(sh, means):
        return render(_replace(g, sh=sh, means=means), camera, outputs=("rgb",), backend="torch")["rgb"]

    # Means too: for degree >= 1 the colour depends on the view direction.
    _check(f, g.sh.clone().requires_grad_(True), g.means.clone().requires_grad_(True))


def test_gradcheck_features():
    g = _scene(seed=6)
    camera = make_camera()
    features = torch.randn(len(g), 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))

    def f(x):
        return render(g, camera, outputs=("features", "alpha"), features=x, backend="torch")["features"]

    _check(f, features.requires_grad_(True))


def test_gradcheck_pose():
    g = _scene(degree=2, seed=7)
    camera = make_camera()

    def f(pose):
        out = render(g, camera, outputs=OUTPUTS, world_to_camera=pose, backend="torch")
        return _outputs(out)

    _check(f, torch.tensor(camera.world_to_camera, dtype=torch.float64, requires_grad=True))


def test_gradcheck_composite_inputs_directly():
    """The composite alone w.r.t. its four differentiable inputs, with a background blend."""
    from inceptiongs.rasterizer.composite import composite_torch
    gen = torch.Generator().manual_seed(3)
    m = 12
    means2d = torch.rand(m, 2, generator=gen, dtype=torch.float64) * torch.tensor([32.0, 24.0])
    xx, yy = 6 + 10 * torch.rand(m, generator=gen, dtype=torch.float64), 6 + 10 * torch.rand(m, generator=gen, dtype=torch.float64)
    xy = 2 * (torch.rand(m, generator=gen, dtype=torch.float64) - 0.5)
    det = xx * yy - xy * xy
    conics = torch.stack([yy / det, -xy / det, xx / det], -1)
    opacities = 0.1 + 0.7 * torch.rand(m, generator=gen, dtype=torch.float64)
    values = torch.rand(m, 4, generator=gen, dtype=torch.float64)
    depths = torch.rand(m, generator=gen, dtype=torch.float64)
    extents = 3.4 * torch.sqrt(torch.stack([xx, yy], -1))

    def f(means2d, conics, opacities, values):
        return composite_torch(means2d, conics, opacities, values, depths, extents, 32, 24)

    _check(f, *(t.requires_grad_(True) for t in (means2d, conics, opacities, values)))
