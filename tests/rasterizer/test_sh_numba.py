"""The numba SH colour (rasterizer/sh_numba.py) against the torch reference (rasterizer/sh.py)
at every degree: colours, coefficient gradients and direction gradients (the analytic basis
derivatives), including colours clamped at 0 (no gradient there) and coefficients beyond the
degree (no gradient). float64: 1e-12; float32 inputs are read in place and accumulated in
float64, so they differ from torch's float32 sums by float32 rounding (1e-5)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("numba")

from inceptiongs.rasterizer.sh import sh_to_color  # noqa: E402


def colour_and_grads(sh, directions, degree, backend, weights):
    sh = sh.clone().requires_grad_(True)
    directions = directions.clone().requires_grad_(True)
    colour = sh_to_color(sh, directions, degree, backend=backend)
    (colour * weights).sum().backward()
    return colour.detach(), sh.grad, directions.grad


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("dtype, atol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_numba_sh_matches_torch(degree, dtype, atol):
    gen = torch.Generator().manual_seed(degree)
    n = 500
    sh = 0.5 * torch.randn(n, 16, 3, generator=gen, dtype=torch.float64)
    sh[:, 0] *= 6.0  # wide enough that some colours fall below 0 at every degree
    sh = sh.to(dtype)
    directions = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen, dtype=torch.float64), dim=-1).to(dtype)
    weights = torch.randn(n, 3, generator=gen, dtype=torch.float64).to(dtype)
    ref = colour_and_grads(sh, directions, degree, "torch", weights)
    fast = colour_and_grads(sh, directions, degree, "numba", weights)
    clamped = ref[0] == 0
    assert 0 < int(clamped.sum()) < clamped.numel()  # both sides of the clamp are exercised
    for name, a, b in zip(("colour", "sh grad", "direction grad"), ref, fast):
        if a is None:  # degree 0: the colour does not depend on the direction
            assert b is None or float(b.abs().max()) == 0.0, name
            continue
        assert b.dtype == dtype, name
        np.testing.assert_allclose(b.numpy(), a.numpy(), atol=atol * max(1.0, float(a.abs().max())), err_msg=name)
    count = (degree + 1) ** 2
    assert torch.all(fast[1][:, count:] == 0)


def test_numba_sh_direction_gradient_matches_finite_differences():
    gen = torch.Generator().manual_seed(7)
    sh = 0.5 * torch.randn(8, 16, 3, generator=gen, dtype=torch.float64)
    sh[:, 0] = 2.0  # keep colours above the clamp so the derivative is smooth
    d = torch.nn.functional.normalize(torch.randn(8, 3, generator=gen, dtype=torch.float64), dim=-1)
    w = torch.randn(8, 3, generator=gen, dtype=torch.float64)
    _, _, grad = colour_and_grads(sh, d, 3, "numba", w)
    eps = 1e-6
    for row in range(8):
        for col in range(3):
            plus, minus = d.clone(), d.clone()
            plus[row, col] += eps
            minus[row, col] -= eps
            numeric = float(((sh_to_color(sh, plus, 3, backend="numba") - sh_to_color(sh, minus, 3, backend="numba"))
                             * w).sum()) / (2 * eps)
            assert abs(numeric - float(grad[row, col])) < 1e-6 * max(1.0, abs(numeric))
