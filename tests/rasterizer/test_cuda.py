"""The torch rasterizer on a CUDA device against the same code on the CPU: outputs and the
gradients of every parameter. Skipped where torch sees no CUDA device (CI never has one; the
figures of the last run on a GPU machine are in docs/rendering.md, "On a GPU")."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inceptiongs.gaussians import Gaussians
from inceptiongs.rasterizer.rasterize import render

from rasterize_cases import make_camera, random_gaussians

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device (torch.cuda.is_available() is False)")

OUTPUTS = ("rgb", "alpha", "depth", "normal", "plane_depth")


def _render_with_grads(g: Gaussians, device: str) -> tuple[dict, dict]:
    """float32 render of ``g`` on ``device`` -> (outputs on the CPU, gradients on the CPU) of a
    fixed random weighting of every output."""
    camera = make_camera(64, 48)
    leaves = {k: v.to(device=device, dtype=torch.float32).clone().requires_grad_(True) for k, v in g.tensors().items()}
    out = render(Gaussians(**leaves), camera, outputs=OUTPUTS, background=(0.1, 0.2, 0.3), backend="torch")
    stacked = torch.cat([out[name] for name in OUTPUTS], -1)
    weights = torch.randn(stacked.shape, generator=torch.Generator().manual_seed(3)).to(device)
    (stacked * weights).sum().backward()
    return ({name: out[name].detach().cpu() for name in OUTPUTS},
            {k: v.grad.detach().cpu() for k, v in leaves.items()})


def test_cuda_render_matches_cpu():
    g = random_gaussians(n=60, degree=3, seed=11)
    cpu_out, cpu_grads = _render_with_grads(g, "cpu")
    gpu_out, gpu_grads = _render_with_grads(g, "cuda")
    assert float(cpu_out["alpha"].max()) > 0.1  # the scene is in view: the comparison compares something
    for name in OUTPUTS:
        # float32 on two devices: summation order differs, so agreement to float32 rounding
        # of values of order 1 (depth of order 3).
        np.testing.assert_allclose(gpu_out[name].numpy(), cpu_out[name].numpy(), atol=2e-5, rtol=1e-5, err_msg=name)
    for name, ref in cpu_grads.items():
        scale = float(ref.abs().max())
        assert scale > 0, name
        np.testing.assert_allclose(gpu_grads[name].numpy(), ref.numpy(), rtol=1e-3, atol=1e-4 * scale, err_msg=name)


def test_cuda_render_of_nothing_in_view_is_the_background():
    g = random_gaussians(n=20, degree=0, seed=2)
    # The camera sits at z = -3 looking along +z: these are all behind it.
    behind = Gaussians(**{**g.tensors(), "means": g.means + torch.tensor([0.0, 0.0, -10.0], dtype=g.dtype)})
    out = render(behind.to(torch.device("cuda")), make_camera(32, 24), outputs=("rgb", "alpha"),
                 background=(0.25, 0.5, 0.75), backend="auto")
    assert out["rgb"].device.type == "cuda"
    assert float(out["alpha"].abs().max()) == 0.0
    np.testing.assert_allclose(out["rgb"].cpu().numpy().reshape(-1, 3)[0], [0.25, 0.5, 0.75], atol=1e-6)
