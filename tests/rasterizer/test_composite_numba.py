"""The numba compositing fast path against an independent brute-force float64 reference.

The reference below evaluates every Gaussian at every pixel (fine for the tiny images used
here) in plain torch, so torch.autograd gives its gradients; it shares no code with the
numba kernels. Tolerances: 1e-5 relative in float64 (the kernels compute in float64 too, so
this only absorbs summation order) and 1e-4 for float32 inputs (rounding of the inputs and
outputs to float32)."""

from __future__ import annotations

import math

import numba
import pytest
import torch

from inceptiongs.rasterizer.composite_numba import composite_numba
from inceptiongs.constants import ALPHA_MAX, ALPHA_MIN, RECURRENCE_CONIC_MAX, TRANSMITTANCE_MIN


# --------------------------------------------------------------------------------------
# independent reference and scene generator


def brute_force_composite(means2d, conics, opacities, values, depths, width, height):
    """The composite contract evaluated densely: every Gaussian at every pixel.

    Returns image [H, W, C], alpha [H, W, 1] and stopped [H, W] (pixels where the stop rule
    fired, so tests can prove they exercise it)."""
    dtype = values.dtype
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=dtype) + 0.5, torch.arange(width, dtype=dtype) + 0.5, indexing="ij"
    )
    trans = torch.ones(height, width, dtype=dtype)
    image = torch.zeros(height, width, values.shape[1], dtype=dtype)
    stopped = torch.zeros(height, width, dtype=torch.bool)
    order = torch.argsort(depths, stable=True)
    for i in order.tolist():
        dx = xs - means2d[i, 0]
        dy = ys - means2d[i, 1]
        a, b, c = conics[i, 0], conics[i, 1], conics[i, 2]
        power = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = torch.clamp(opacities[i] * torch.exp(-power), max=ALPHA_MAX)
        valid = (power >= 0) & (alpha >= ALPHA_MIN) & ~stopped
        after = trans * (1 - alpha)
        stop = valid & (after < TRANSMITTANCE_MIN)
        stopped = stopped | stop
        add = valid & ~stop
        weight = torch.where(add, trans * alpha, torch.zeros_like(trans))
        image = image + weight[..., None] * values[i]
        trans = torch.where(add, after, trans)
    return image, (1 - trans)[..., None], stopped


def footprint_extents(cov2d: torch.Tensor, opacities: torch.Tensor) -> torch.Tensor:
    """[M, 2] half-sizes from the contract's footprint rule (pixels)."""
    level = torch.clamp(torch.log(opacities / ALPHA_MIN), min=0.0)
    return torch.sqrt(2 * level[:, None] * torch.stack([cov2d[:, 0, 0], cov2d[:, 1, 1]], dim=1))


def random_gaussians(m, width, height, seed, dtype=torch.float64, opacity=(0.05, 0.95),
                     radius_px=(1.0, 6.0), channels=3, margin=4.0):
    """Random projected Gaussians, some hanging over the image border. Returns a dict with
    means2d, conics, opacities, values, depths, extents."""
    gen = torch.Generator().manual_seed(seed)

    def uniform(shape, lo, hi):
        return lo + (hi - lo) * torch.rand(shape, generator=gen, dtype=torch.float64)

    means = torch.stack([uniform(m, -margin, width + margin), uniform(m, -margin, height + margin)], dim=1)
    sigmas = uniform((m, 2), *radius_px)
    angle = uniform(m, 0.0, math.pi)
    rot = torch.stack([torch.cos(angle), -torch.sin(angle), torch.sin(angle), torch.cos(angle)], 1).view(m, 2, 2)
    cov = rot @ torch.diag_embed(sigmas**2) @ rot.transpose(1, 2)
    inv = torch.linalg.inv(cov)
    conics = torch.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], dim=1)
    opac = uniform(m, *opacity)
    scene = {
        "means2d": means,
        "conics": conics,
        "opacities": opac,
        "values": uniform((m, channels), -0.5, 1.5),
        "depths": uniform(m, 0.5, 5.0),
        "extents": footprint_extents(cov, opac),
    }
    return {k: v.to(dtype) for k, v in scene.items()}


DIFFERENTIABLE = ("means2d", "conics", "opacities", "values")


def run_numba(scene, width, height):
    return composite_numba(scene["means2d"], scene["conics"], scene["opacities"], scene["values"],
                           scene["depths"], scene["extents"], width, height)


def run_reference(scene, width, height):
    return brute_force_composite(scene["means2d"], scene["conics"], scene["opacities"], scene["values"],
                                 scene["depths"], width, height)


def grads_of(fn, scene, width, height, seed):
    """Gradients of a random linear loss of (image, alpha) w.r.t. the differentiable inputs."""
    leaves = {k: (v.detach().clone().requires_grad_(k in DIFFERENTIABLE)) for k, v in scene.items()}
    image, alpha = fn(leaves, width, height)[:2]
    gen = torch.Generator().manual_seed(seed)
    w_image = torch.randn(image.shape, generator=gen, dtype=torch.float64).to(image.dtype)
    w_alpha = torch.randn(alpha.shape, generator=gen, dtype=torch.float64).to(alpha.dtype)
    ((image * w_image).sum() + (alpha * w_alpha).sum()).backward()
    return {k: leaves[k].grad for k in DIFFERENTIABLE}


def assert_matches(actual, expected, rtol, atol=1e-9):
    torch.testing.assert_close(actual.to(torch.float64), expected.to(torch.float64), rtol=rtol, atol=atol)


# --------------------------------------------------------------------------------------
# forward


@pytest.mark.parametrize("seed, m, opacity", [(0, 40, (0.05, 0.95)), (1, 80, (0.5, 0.99)), (2, 120, (0.9, 0.999))])
def test_forward_matches_reference_float64(seed, m, opacity):
    width, height = 37, 29  # not multiples of the tile size: partial edge tiles
    scene = random_gaussians(m, width, height, seed, opacity=opacity, radius_px=(1.0, 8.0))
    image, alpha = run_numba(scene, width, height)
    ref_image, ref_alpha, _ = run_reference(scene, width, height)
    assert image.shape == (height, width, 3) and alpha.shape == (height, width, 1)
    assert image.dtype == torch.float64
    assert_matches(image, ref_image, rtol=1e-5)
    assert_matches(alpha, ref_alpha, rtol=1e-5)
    assert alpha.max() > 0.5  # the scene is not trivially empty


def test_stop_rule_is_exercised_and_respected():
    width, height = 33, 20
    scene = random_gaussians(150, width, height, seed=3, opacity=(0.95, 0.999), radius_px=(4.0, 10.0))
    image, alpha = run_numba(scene, width, height)
    ref_image, ref_alpha, stopped = run_reference(scene, width, height)
    assert stopped.float().mean() > 0.5, "the scene must trigger the stop rule on most pixels"
    assert_matches(image, ref_image, rtol=1e-5)
    assert_matches(alpha, ref_alpha, rtol=1e-5)
    # The stop rule keeps the final transmittance at or above TRANSMITTANCE_MIN.
    assert float((1 - alpha).min()) >= TRANSMITTANCE_MIN


def test_wide_footprints_stepped_exp_matches_reference_tightly():
    # sigma 12-40 px: conic a well below RECURRENCE_CONIC_MAX, so every row span is stepped by
    # the exp() recurrence (forward and backward); an opaque stack exercises the stop rule,
    # where the backward must take exactly the forward's decisions.
    width, height = 45, 38
    scene = random_gaussians(60, width, height, seed=7, opacity=(0.6, 0.99), radius_px=(12.0, 40.0))
    assert float(scene["conics"][:, 0].max()) < RECURRENCE_CONIC_MAX
    image, alpha = run_numba(scene, width, height)
    ref_image, ref_alpha, stopped = run_reference(scene, width, height)
    assert stopped.float().mean() > 0.3
    assert_matches(image, ref_image, rtol=1e-10, atol=1e-12)
    assert_matches(alpha, ref_alpha, rtol=1e-10, atol=1e-12)
    got = grads_of(run_numba, scene, width, height, seed=7)
    want = grads_of(run_reference, scene, width, height, seed=7)
    for key in DIFFERENTIABLE:
        assert_matches(got[key], want[key], rtol=1e-8, atol=1e-10)


def test_forward_float32_matches_float64_reference():
    width, height = 37, 29
    scene64 = random_gaussians(80, width, height, seed=4, opacity=(0.1, 0.95))
    scene32 = {k: v.float() for k, v in scene64.items()}
    image, alpha = run_numba(scene32, width, height)
    assert image.dtype == torch.float32 and alpha.dtype == torch.float32
    # The reference sees the same float32-rounded inputs, widened to float64.
    ref_image, ref_alpha, _ = run_reference({k: v.double() for k, v in scene32.items()}, width, height)
    assert_matches(image, ref_image, rtol=1e-4, atol=1e-5)
    assert_matches(alpha, ref_alpha, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("channels", [1, 5])
def test_other_channel_counts(channels):
    width, height = 20, 18
    scene = random_gaussians(30, width, height, seed=5, channels=channels)
    image, _ = run_numba(scene, width, height)
    ref_image, _, _ = run_reference(scene, width, height)
    assert image.shape == (height, width, channels)
    assert_matches(image, ref_image, rtol=1e-5)


def test_result_does_not_depend_on_extents_beyond_the_footprint():
    width, height = 40, 35
    scene = random_gaussians(60, width, height, seed=6)
    tight_image, tight_alpha = run_numba(scene, width, height)
    for huge in (1e6, 1e30, math.inf, math.nan, -1.0):  # invalid ones cover the whole image
        loose = dict(scene, extents=torch.full_like(scene["extents"], huge))
        image, alpha = run_numba(loose, width, height)
        # Same per-tile lists in the same depth order over the covered pixels: bit-identical.
        assert torch.equal(image, tight_image), huge
        assert torch.equal(alpha, tight_alpha), huge


def test_thin_rotated_ellipses():
    # Needle-like footprints (sigma ratios beyond 30:1): their boxes are mostly empty, and the
    # kernels' per-row spans must still keep every pixel of the ellipse.
    width, height = 40, 36
    scene = random_gaussians(60, width, height, seed=15, radius_px=(0.05, 12.0), opacity=(0.2, 0.99))
    ratio = torch.linalg.eigvalsh(torch.stack([
        torch.stack([scene["conics"][:, 0], scene["conics"][:, 1]], 1),
        torch.stack([scene["conics"][:, 1], scene["conics"][:, 2]], 1)], 1))
    assert (ratio[:, 1] / ratio[:, 0]).max() > 1e3
    image, alpha = run_numba(scene, width, height)
    ref_image, ref_alpha, _ = run_reference(scene, width, height)
    assert_matches(image, ref_image, rtol=1e-5)
    assert_matches(alpha, ref_alpha, rtol=1e-5)
    got = grads_of(run_numba, scene, width, height, seed=15)
    want = grads_of(run_reference, scene, width, height, seed=15)
    for key in DIFFERENTIABLE:
        assert_matches(got[key], want[key], rtol=1e-5, atol=1e-8)


def test_gaussians_partly_and_fully_outside_the_image():
    width, height = 24, 20
    scene = random_gaussians(50, width, height, seed=7, radius_px=(2.0, 9.0), margin=25.0)
    image, alpha = run_numba(scene, width, height)
    ref_image, ref_alpha, _ = run_reference(scene, width, height)
    outside = ((scene["means2d"][:, 0] < 0) | (scene["means2d"][:, 0] > width)).sum()
    assert outside > 5
    assert_matches(image, ref_image, rtol=1e-5)
    assert_matches(alpha, ref_alpha, rtol=1e-5)


def test_no_gaussians_gives_zeros_and_empty_gradients():
    scene = random_gaussians(0, 10, 7, seed=8)
    leaves = {k: v.clone().requires_grad_(k in DIFFERENTIABLE) for k, v in scene.items()}
    image, alpha = run_numba(leaves, 10, 7)
    assert image.shape == (7, 10, 3) and alpha.shape == (7, 10, 1)
    assert not image.any() and not alpha.any()
    (image.sum() + alpha.sum()).backward()
    assert leaves["means2d"].grad.shape == (0, 2)
    assert leaves["values"].grad.shape == (0, 3)


def test_one_pixel_image():
    scene = random_gaussians(12, 1, 1, seed=9, radius_px=(0.5, 2.0), margin=1.0)
    image, alpha = run_numba(scene, 1, 1)
    ref_image, ref_alpha, _ = run_reference(scene, 1, 1)
    assert alpha.item() > 0
    assert_matches(image, ref_image, rtol=1e-5)
    assert_matches(alpha, ref_alpha, rtol=1e-5)
    got = grads_of(run_numba, scene, 1, 1, seed=9)
    want = grads_of(run_reference, scene, 1, 1, seed=9)
    for key in DIFFERENTIABLE:
        assert_matches(got[key], want[key], rtol=1e-5)


def one_gaussian(x, y, opacity, conic=(0.5, 0.0, 0.5), extent=10.0):
    t = torch.float64
    return {
        "means2d": torch.tensor([[x, y]], dtype=t),
        "conics": torch.tensor([conic], dtype=t),
        "opacities": torch.tensor([opacity], dtype=t),
        "values": torch.tensor([[1.0, 2.0, -1.0]], dtype=t),
        "depths": torch.tensor([1.0], dtype=t),
        "extents": torch.tensor([[extent, extent]], dtype=t),
    }


def test_alpha_exactly_at_alpha_min_is_kept_and_just_below_is_skipped():
    # The mean sits on pixel (2, 1)'s centre, so power is exactly 0 and alpha == opacity there.
    kept = one_gaussian(2.5, 1.5, ALPHA_MIN)
    image, alpha = run_numba(kept, 5, 4)
    assert alpha[1, 2, 0].item() == pytest.approx(ALPHA_MIN, rel=1e-15)
    assert image[1, 2, 1].item() == pytest.approx(2.0 * ALPHA_MIN, rel=1e-15)
    assert (alpha > 0).sum() == 1  # every other pixel has alpha below ALPHA_MIN

    skipped = one_gaussian(2.5, 1.5, math.nextafter(ALPHA_MIN, 0.0))
    image, alpha = run_numba(skipped, 5, 4)
    assert not alpha.any() and not image.any()


def test_invalid_conic_with_negative_power_is_skipped():
    # a < 0: power < 0 away from the mean, which the contract skips (not an exploding alpha).
    scene = one_gaussian(4.0, 4.0, 0.8, conic=(-0.3, 0.0, 0.2))
    image, alpha = run_numba(scene, 8, 8)
    ref_image, ref_alpha, _ = run_reference(scene, 8, 8)
    assert_matches(image, ref_image, rtol=1e-5)
    assert_matches(alpha, ref_alpha, rtol=1e-5)
    assert alpha.max() <= ALPHA_MAX
    got = grads_of(run_numba, scene, 8, 8, seed=10)
    want = grads_of(run_reference, scene, 8, 8, seed=10)
    for key in DIFFERENTIABLE:
        assert_matches(got[key], want[key], rtol=1e-5)


def test_saturated_alpha_passes_no_opacity_gradient_where_clamped():
    # A wide, nearly opaque Gaussian: alpha = min(ALPHA_MAX, o * exp(-power)) clamps near the
    # centre and not at the rim.
    scene = one_gaussian(6.0, 6.0, 0.9999, conic=(0.02, 0.0, 0.02), extent=40.0)
    image, alpha = run_numba(scene, 12, 12)
    assert alpha.max().item() == pytest.approx(ALPHA_MAX, rel=1e-15)
    got = grads_of(run_numba, scene, 12, 12, seed=11)
    want = grads_of(run_reference, scene, 12, 12, seed=11)
    for key in DIFFERENTIABLE:
        assert_matches(got[key], want[key], rtol=1e-5)
    # Only clamped pixels: the opacity gradient must vanish.
    centre_only = one_gaussian(6.0, 6.0, 0.9999, conic=(1e-6, 0.0, 1e-6), extent=40.0)
    got = grads_of(run_numba, centre_only, 12, 12, seed=12)
    assert got["opacities"].abs().max() == 0 and got["means2d"].abs().max() == 0


def test_non_finite_mean_contributes_nothing():
    scene = random_gaussians(10, 16, 16, seed=13)
    image_before, _ = run_numba(scene, 16, 16)
    with_nan = {k: torch.cat([v, v[:1]]) for k, v in scene.items()}
    with_nan["means2d"][-1] = torch.tensor([math.nan, 3.0])
    image_after, _ = run_numba(with_nan, 16, 16)
    assert torch.equal(image_before, image_after)


def test_result_does_not_depend_on_thread_count():
    width, height = 48, 40
    scene = random_gaussians(200, width, height, seed=14, radius_px=(2.0, 8.0))
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = run_numba(scene, width, height), grads_of(run_numba, scene, width, height, seed=14)
        numba.set_num_threads(threads)
        many = run_numba(scene, width, height), grads_of(run_numba, scene, width, height, seed=14)
    finally:
        numba.set_num_threads(threads)
    assert torch.equal(one[0][0], many[0][0]) and torch.equal(one[0][1], many[0][1])
    for key in DIFFERENTIABLE:
        assert torch.equal(one[1][key], many[1][key])


def test_depth_ties_keep_index_order():
    # Two Gaussians at the same depth and place: the first index is in front.
    scene = one_gaussian(3.0, 3.0, 0.7)
    scene = {k: torch.cat([v, v]) for k, v in scene.items()}
    scene["values"][1] = torch.tensor([5.0, 5.0, 5.0])
    image, _ = run_numba(scene, 6, 6)
    ref_image, _, _ = run_reference(scene, 6, 6)
    assert_matches(image, ref_image, rtol=1e-12)
    swapped = {k: v.flip(0) for k, v in scene.items()}
    assert not torch.allclose(run_numba(swapped, 6, 6)[0], image)


# --------------------------------------------------------------------------------------
# backward


@pytest.mark.parametrize("seed, opacity", [(20, (0.05, 0.95)), (21, (0.9, 0.999))])
def test_backward_matches_reference_autograd(seed, opacity):
    width, height = 35, 23
    scene = random_gaussians(70, width, height, seed=seed, opacity=opacity, radius_px=(1.5, 7.0))
    got = grads_of(run_numba, scene, width, height, seed=seed)
    want = grads_of(run_reference, scene, width, height, seed=seed)
    for key in DIFFERENTIABLE:
        assert got[key].shape == scene[key].shape
        assert_matches(got[key], want[key], rtol=1e-5, atol=1e-8)
    assert got["means2d"].abs().max() > 0


def test_backward_float32_gradients_close_to_float64():
    width, height = 30, 22
    scene = random_gaussians(50, width, height, seed=22)
    scene32 = {k: v.float() for k, v in scene.items()}
    got = grads_of(run_numba, scene32, width, height, seed=22)
    want = grads_of(run_reference, {k: v.double() for k, v in scene32.items()}, width, height, seed=22)
    for key in DIFFERENTIABLE:
        assert got[key].dtype == torch.float32
        scale = want[key].abs().max().clamp(min=1.0)
        assert ((got[key].double() - want[key]).abs().max() / scale) < 1e-4, key


def test_gradcheck_float64_small():
    width, height = 12, 9
    scene = random_gaussians(6, width, height, seed=23, opacity=(0.3, 0.9), radius_px=(1.5, 4.0), margin=1.0)
    inputs = tuple(scene[k].clone().requires_grad_(k in DIFFERENTIABLE) for k in
                   ("means2d", "conics", "opacities", "values", "depths", "extents"))

    def fn(means2d, conics, opacities, values, depths, extents):
        return composite_numba(means2d, conics, opacities, values, depths, extents, width, height)

    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_alpha_only_gradient():
    # grad_image may be unused by the caller: only alpha feeds the loss.
    width, height = 20, 20
    scene = random_gaussians(25, width, height, seed=24)
    leaves = {k: v.clone().requires_grad_(k in DIFFERENTIABLE) for k, v in scene.items()}
    _, alpha = run_numba(leaves, width, height)
    alpha.sum().backward()
    ref = {k: v.clone().requires_grad_(k in DIFFERENTIABLE) for k, v in scene.items()}
    run_reference(ref, width, height)[1].sum().backward()
    for key in ("means2d", "conics", "opacities"):
        assert_matches(leaves[key].grad, ref[key].grad, rtol=1e-5)
    assert leaves["values"].grad.abs().max() == 0


# --------------------------------------------------------------------------------------
# against the project's tile-binned torch reference (inceptiongs.rasterizer.composite.composite_torch)


def run_composite_torch(scene, width, height):
    from inceptiongs.rasterizer.composite import composite_torch

    return composite_torch(scene["means2d"], scene["conics"], scene["opacities"], scene["values"],
                           scene["depths"], scene["extents"], width, height)


@pytest.mark.parametrize("seed, opacity", [(30, (0.05, 0.95)), (31, (0.9, 0.999))])
def test_matches_composite_torch_forward_and_backward(seed, opacity):
    width, height = 45, 38
    scene = random_gaussians(150, width, height, seed=seed, opacity=opacity, radius_px=(1.0, 9.0), margin=10.0)
    image, alpha = run_numba(scene, width, height)
    ref_image, ref_alpha = run_composite_torch(scene, width, height)
    assert_matches(image, ref_image, rtol=1e-5)
    assert_matches(alpha, ref_alpha, rtol=1e-5)
    got = grads_of(run_numba, scene, width, height, seed=seed)
    want = grads_of(run_composite_torch, scene, width, height, seed=seed)
    for key in DIFFERENTIABLE:
        assert_matches(got[key], want[key], rtol=1e-5, atol=1e-8)


def test_matches_composite_torch_float32():
    width, height = 40, 33
    scene = {k: v.float() for k, v in random_gaussians(120, width, height, seed=32).items()}
    image, alpha = run_numba(scene, width, height)
    ref_image, ref_alpha = run_composite_torch(scene, width, height)
    assert image.dtype == ref_image.dtype == torch.float32
    assert_matches(image, ref_image, rtol=1e-4, atol=1e-5)
    assert_matches(alpha, ref_alpha, rtol=1e-4, atol=1e-5)


def test_leaves_numba_chunk_size_as_it_was():
    # The kernels schedule tiles dynamically; the caller's numba setting must survive a call.
    previous = numba.set_parallel_chunksize(7)
    try:
        scene = random_gaussians(20, 20, 20, seed=40)
        grads_of(run_numba, scene, 20, 20, seed=40)
        assert numba.get_parallel_chunksize() == 7
    finally:
        numba.set_parallel_chunksize(previous)
