"""Stiff and extreme inputs for the GL renderer: outputs stay finite and either match the
torch reference (same criteria as the cross-check: RGB PSNR >= 45 dB, alpha within 2e-3 on
99.9% of pixels) or are culled by a stated rule (then GL draws exactly nothing)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.constants import FAR_PLANE, NEAR_PLANE
from inceptiongs.gaussians import Gaussians

moderngl = pytest.importorskip("moderngl")
from conftest import offscreen_context_or_skip  # noqa: E402
from inceptiongs.renderer.crosscheck import agreement  # noqa: E402
from inceptiongs.renderer.splats import SplatRenderer  # noqa: E402


@pytest.fixture(scope="module", params=["cpu", "fetch"])
def renderer(request):
    """Each case runs on both exact compositing paths: "cpu" (the default on software GL)
    and "fetch" (fragment shader with framebuffer fetch, the default on hardware GL)."""
    ctx = offscreen_context_or_skip()
    if request.param == "fetch" and "GL_EXT_shader_framebuffer_fetch" not in ctx.extensions:
        ctx.release()
        pytest.skip("no GL_EXT_shader_framebuffer_fetch in this GL")
    splats = SplatRenderer(ctx, compositing=request.param)
    yield splats
    splats.release()
    ctx.release()


def gaussians(means, log_scales=None, quats=None, logits=None, sh=None, dtype=torch.float32) -> Gaussians:
    means = torch.as_tensor(np.asarray(means, np.float64), dtype=dtype).reshape(-1, 3)
    n = means.shape[0]
    gen = torch.Generator().manual_seed(n)
    def value(x, default):
        return torch.as_tensor(np.asarray(x, np.float64), dtype=dtype) if x is not None else default
    return Gaussians(
        means=means,
        log_scales=value(log_scales, torch.full((n, 3), -2.0, dtype=dtype)).reshape(n, 3),
        quats=value(quats, torch.randn(n, 4, generator=gen, dtype=dtype)).reshape(n, 4),
        opacity_logits=value(logits, torch.full((n,), 1.0, dtype=dtype)).reshape(n),
        sh=value(sh, torch.randn(n, 1, 3, generator=gen, dtype=dtype) * 0.5),
    )


def front_camera(width=96, height=72, eye=(0.0, 0.0, -3.0), target=(0.0, 0.0, 0.0)) -> Camera:
    return Camera("cam", width, height, 0.9 * width, 0.9 * width, width / 2, height / 2,
                  look_at(np.asarray(eye, float), np.asarray(target, float)))


def gl_and_torch(renderer: SplatRenderer, model: Gaussians, cam: Camera, torch_model: Gaussians | None = None):
    from inceptiongs.rasterizer.rasterize import render
    renderer.set_gaussians(model.numpy())
    rgb, alpha = renderer.render(cam, "rgb"), renderer.render(cam, "alpha")
    assert np.isfinite(rgb).all() and np.isfinite(alpha).all()
    with torch.no_grad():
        ref = render(torch_model if torch_model is not None else model, cam, outputs=("rgb", "alpha"))
    return rgb, alpha, ref["rgb"].double().numpy(), ref["alpha"].double().numpy()


def assert_matches(rgb, alpha, ref_rgb, ref_alpha, min_coverage=0.0):
    result = agreement(rgb, alpha, ref_rgb, ref_alpha)
    assert result["ok"], result
    assert np.mean(ref_alpha > 0.01) >= min_coverage  # something was actually drawn


def test_log_scales_from_minus_20_to_plus_12(renderer):
    log_scale = np.linspace(-20.0, 12.0, 33)
    means = np.stack([np.linspace(-0.8, 0.8, 33), np.zeros(33), np.linspace(2.0, 5.0, 33)], -1)
    model = gaussians(means, np.repeat(log_scale[:, None], 3, 1), logits=np.full(33, -1.0))
    assert_matches(*gl_and_torch(renderer, model, front_camera(eye=(0, 0, 0), target=(0, 0, 1))), 0.9)


def test_anisotropy_one_million_to_one(renderer):
    rng = np.random.default_rng(1)
    scales = np.tile([-1.5, -1.5 - math.log(1e6), -1.5], (60, 1))
    model = gaussians(rng.uniform(-1, 1, (60, 3)), scales, logits=rng.normal(0, 1, 60))
    assert_matches(*gl_and_torch(renderer, model, front_camera()), 0.1)


def test_zero_and_denormal_quaternions_become_identity(renderer):
    quats = np.array([[0, 0, 0, 0], [1e-40, 0, 0, 0], [0, 1e-41, 1e-42, 0], [1e-45, 1e-45, 0, 0]], np.float32)
    model = gaussians([[-0.6, 0, 0], [-0.2, 0, 0], [0.2, 0, 0], [0.6, 0, 0]],
                      np.tile([-1.0, -3.0, -2.0], (4, 1)), quats=quats)
    rgb, alpha, ref_rgb, ref_alpha = gl_and_torch(renderer, model, front_camera())
    assert_matches(rgb, alpha, ref_rgb, ref_alpha, 0.05)
    identity = gaussians(model.means, model.log_scales, np.tile([1.0, 0, 0, 0], (4, 1)), sh=model.sh)
    renderer.set_gaussians(identity.numpy())
    assert np.max(np.abs(renderer.render(front_camera(), "alpha") - alpha)) < 1e-6


def test_opacity_logits_plus_minus_50(renderer):
    model = gaussians([[-0.4, 0, 0], [0.4, 0, 0]], logits=[50.0, 50.0])
    assert_matches(*gl_and_torch(renderer, model, front_camera()), 0.01)
    # sigmoid(-30) < ALPHA_MIN: culled by the opacity rule, nothing drawn.
    hidden = gaussians([[-0.4, 0, 0], [0.4, 0, 0]], logits=[-50.0, -50.0])
    rgb, alpha, _, ref_alpha = gl_and_torch(renderer, hidden, front_camera())
    assert alpha.max() == 0.0 and ref_alpha.max() == 0.0


def test_near_plane_behind_and_straddling(renderer):
    cam = front_camera(eye=(0, 0, 0), target=(0, 0, 1))
    culled = gaussians([[0, 0, 0.5 * NEAR_PLANE], [0.1, 0, -1.0], [0, 0, 0.0]], np.full((3, 3), -1.0))
    _, alpha, _, ref_alpha = gl_and_torch(renderer, culled, cam)
    # Rule: camera z < NEAR_PLANE (at the centre, behind, or in front of the near plane) is culled.
    assert alpha.max() == 0.0 and ref_alpha.max() == 0.0
    at_and_straddling = gaussians([[0.0, 0.0, NEAR_PLANE * 1.5], [0.02, 0.01, 0.05], [0.3, -0.1, 0.2]],
                                  [[-7.0, -7.0, -7.0], [-0.7, -0.7, -0.7], [-1.0, -4.0, -1.0]])
    assert_matches(*gl_and_torch(renderer, at_and_straddling, cam), 0.3)


def test_mean_at_the_camera_centre_with_sh(renderer):
    cam = front_camera()
    sh = torch.randn(2, 16, 3, generator=torch.Generator().manual_seed(0)) * 0.3
    model = gaussians([cam.center, cam.center + [0, 0, 1e-7]], np.full((2, 3), 0.0), sh=sh)
    _, alpha, _, ref_alpha = gl_and_torch(renderer, model, cam)
    assert alpha.max() == 0.0 and ref_alpha.max() == 0.0  # both at z < NEAR_PLANE: culled
    near = gaussians([cam.center + [0, 0, 2 * NEAR_PLANE]], [[-5.0, -5.0, -5.0]], sh=sh[:1])
    assert_matches(*gl_and_torch(renderer, near, cam), 0.01)


@pytest.mark.parametrize("offset", [1e6, -1e6])
def test_scene_translated_one_million_units(renderer, offset):
    rng = np.random.default_rng(2)
    shift = np.array([offset, -offset, offset])
    # Float32 spacing at 1e6 is 0.0625: a scene 400 units wide keeps its shape there.
    far_means = torch.as_tensor(rng.uniform(-200, 200, (300, 3)) + shift, dtype=torch.float32)
    far = gaussians(far_means, rng.uniform(1.5, 2.7, (300, 3)), logits=rng.normal(1, 1, 300))
    eye, target = np.array([60.0, -40.0, -600.0]), np.zeros(3)
    far_cam = front_camera(eye=eye + shift, target=target + shift)
    # Without normalisation: GL on the float32 model 1e6 away vs torch on the same values in
    # float64 (the reference's own float32 path keeps t in float64 too).
    rgb, alpha, ref_rgb, ref_alpha = gl_and_torch(renderer, far, far_cam, far.to(dtype=torch.float64))
    assert_matches(rgb, alpha, ref_rgb, ref_alpha, 0.2)
    # With normalisation (the same model moved to the origin, exactly, in float64 first).
    base = gaussians(far.means.double().numpy() - shift, far.log_scales, far.quats, far.opacity_logits, far.sh)
    rgb0, alpha0, ref_rgb0, ref_alpha0 = gl_and_torch(renderer, base, front_camera(eye=eye, target=target))
    assert_matches(rgb0, alpha0, ref_rgb0, ref_alpha0, 0.2)
    assert_matches(rgb, alpha, rgb0, alpha0)


def test_one_by_one_image(renderer):
    model = gaussians(np.random.default_rng(3).uniform(-0.2, 0.2, (20, 3)))
    assert_matches(*gl_and_torch(renderer, model, front_camera(1, 1)), 1.0)


@pytest.mark.slow
def test_4096_squared_image_matches_torch_on_a_window(renderer):
    from inceptiongs.rasterizer.rasterize import render
    rng = np.random.default_rng(4)
    model = gaussians(rng.uniform(-1, 1, (400, 3)), rng.uniform(-3.5, -2, (400, 3)))
    cam = front_camera(4096, 4096)
    renderer.set_gaussians(model.numpy())
    full_rgb, full_alpha = renderer.render(cam, "rgb"), renderer.render(cam, "alpha")
    assert full_rgb.shape == (4096, 4096, 3) and np.isfinite(full_rgb).all()
    for x0, y0 in [(1900, 1950), (0, 0), (3968, 4000)]:
        window = cam.cropped(x0, y0, 96, 96)
        with torch.no_grad():
            ref = render(model, window, outputs=("rgb", "alpha"))
        assert_matches(full_rgb[y0:y0 + 96, x0:x0 + 96], full_alpha[y0:y0 + 96, x0:x0 + 96],
                       ref["rgb"].numpy(), ref["alpha"].numpy())
    assert full_alpha.max() > 0.5


def test_zero_and_one_gaussian(renderer):
    cam = front_camera()
    renderer.set_gaussians(Gaussians.empty(sh_degree=2).numpy())
    assert np.all(renderer.render(cam, "rgb", background=(0.1, 0.2, 0.3)) == np.float32([0.1, 0.2, 0.3]))
    assert renderer.render(cam, "alpha").max() == 0.0
    assert renderer.render(cam, "depth").max() == 0.0
    assert renderer.pick_depth(cam, 10, 10) is None
    assert_matches(*gl_and_torch(renderer, gaussians([[0.1, 0.0, 0.0]], [[-1.0, -1.5, -2.0]]), cam), 0.1)


@pytest.mark.slow
def test_one_million_gaussians(renderer):
    rng = np.random.default_rng(5)
    n = 1_000_000
    model = gaussians(rng.uniform(-1, 1, (n, 3)).astype(np.float32),
                      rng.uniform(-6, -4, (n, 3)).astype(np.float32),
                      rng.normal(size=(n, 4)).astype(np.float32), rng.normal(-1, 1, n).astype(np.float32),
                      rng.normal(0, 0.5, (n, 1, 3)).astype(np.float32))
    assert_matches(*gl_and_torch(renderer, model, front_camera(64, 48)), 0.9)


def test_all_gaussians_at_one_point(renderer):
    """Equal depths everywhere: both renderers order ties by index (stable)."""
    rng = np.random.default_rng(6)
    n = 300
    model = gaussians(np.zeros((n, 3)), rng.uniform(-2.5, -1.0, (n, 3)), logits=rng.normal(0, 1, n))
    assert_matches(*gl_and_torch(renderer, model, front_camera()), 0.2)


def _float32_neighbours(value: float) -> list[float]:
    """[one float32 ulp below, the float32 value itself, one ulp above]."""
    v = np.float32(value)
    return [float(np.nextafter(v, np.float32(-np.inf))), float(v), float(np.nextafter(v, np.float32(np.inf)))]


@pytest.mark.parametrize("plane, log_scale", [(NEAR_PLANE, -7.0), (FAR_PLANE, 11.5)])
def test_near_and_far_plane_one_rule_in_both_renderers(renderer, plane, log_scale):
    """One Gaussian on the optical axis at camera z = the plane and one float32 ulp either side
    (identity pose, so both renderers see exactly this z): torch and GL both draw or both cull,
    and the rule is NEAR_PLANE <= z <= FAR_PLANE."""
    cam = Camera("axis", 96, 72, 86.4, 86.4, 48.0, 36.0, np.eye(4))
    decisions = []
    for z in _float32_neighbours(plane):
        model = gaussians([[0.0, 0.0, z]], [[log_scale] * 3], logits=[3.0])
        _, alpha, _, ref_alpha = gl_and_torch(renderer, model, cam)
        drawn_gl, drawn_torch = bool(alpha.max() > 0), bool(ref_alpha.max() > 0)
        assert drawn_gl == drawn_torch, (plane, z, drawn_gl, drawn_torch)
        decisions.append(drawn_gl)
    expected = [False, True, True] if plane == NEAR_PLANE else [True, True, False]
    assert decisions == expected
