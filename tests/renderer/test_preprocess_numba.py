"""renderer/preprocess_numba (the CPU compositing's preprocess) against the preprocess shader
it mirrors, on the same packed texels: every mode, SH degrees 0 and 3, stiff Gaussians."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians

moderngl = pytest.importorskip("moderngl")
from inceptiongs.renderer.gl_camera import shader_camera  # noqa: E402
from inceptiongs.renderer.layout import MODES, SPLAT_TEXELS  # noqa: E402
from inceptiongs.renderer.preprocess_numba import preprocess_splats  # noqa: E402
from inceptiongs.renderer.splats import SplatRenderer, pack_gaussians  # noqa: E402


def stiff_model(n: int, seed: int, degree: int) -> Gaussians:
    """Random Gaussians with needles (1e4:1 scales), discs, opacity logits up to +-40, zero and
    huge quaternions, some behind the camera and beside the view."""
    gen = torch.Generator().manual_seed(seed)
    log_scales = torch.rand(n, 3, generator=gen) * 2 - 4.5
    log_scales[: n // 8, 0] += 9.0   # needles
    log_scales[n // 8: n // 4, 2] -= 9.0   # discs
    quats = torch.randn(n, 4, generator=gen)
    quats[: n // 16] = 0.0
    quats[n // 16: n // 8] *= 1e6
    means = torch.rand(n, 3, generator=gen) * 4 - 2
    return Gaussians(means, log_scales, quats, torch.randn(n, generator=gen) * 12.0,
                     torch.randn(n, (degree + 1) ** 2, 3, generator=gen) * 0.4)


def camera(width=96, height=64) -> Camera:
    return Camera("v", width, height, 80.0, 84.0, width / 2 + 3.5, height / 2 - 2.0,
                  look_at(np.array([0.4, -0.3, -3.0]), np.zeros(3)))


def shader_output(ctx, arrays, cam, mode, sh_degree_cap=None) -> np.ndarray:
    """The preprocess shader's output for ``arrays``: the splat buffer after a blended frame."""
    renderer = SplatRenderer(ctx, sort="cpu", compositing="blend")
    try:
        renderer.set_gaussians(arrays)
        renderer.render(cam, mode, sh_degree_cap=sh_degree_cap)
        n = len(arrays["means"])
        return np.frombuffer(renderer._splat_buffer.read(size=n * SPLAT_TEXELS * 16), np.float32).reshape(n, 4, 4)
    finally:
        renderer.release()


@pytest.mark.parametrize("mode", ["rgb", "depth", "normal", "alpha"])
@pytest.mark.parametrize("degree", [0, 3])
def test_the_numba_preprocess_matches_the_shader(gl_context, mode, degree):
    arrays = stiff_model(3000, seed=degree, degree=degree).numpy()
    cam = camera()
    expected = shader_output(gl_context, arrays, cam, mode)
    texels, anchor, _ = pack_gaussians(arrays)
    got = preprocess_splats(texels, degree, shader_camera(cam, anchor), MODES[mode], 1.0)
    kept_gl, kept_cpu = expected[:, 1, 3] > 0, got[:, 1, 3] > 0
    assert 300 < kept_gl.sum() < 3000 - 300   # culled and kept both occur
    # The shader is float32 throughout, the numba pass float64: culling agrees but within
    # rounding of a threshold.
    assert (kept_gl != kept_cpu).sum() <= 3, np.flatnonzero(kept_gl != kept_cpu)
    both = kept_gl & kept_cpu
    np.testing.assert_array_equal(got[~kept_cpu], 0.0)
    np.testing.assert_allclose(got[both, 0, :2], expected[both, 0, :2], rtol=1e-4, atol=1e-3)   # centre, px
    np.testing.assert_allclose(got[both, 1, 3], expected[both, 1, 3], rtol=1e-5)   # opacity
    np.testing.assert_allclose(got[both, 2], expected[both, 2], rtol=1e-3, atol=1e-4)   # value, z
    # Footprint axes and conics, each relative to its own size: a needle's float32 conic and
    # minor axis keep fewer digits.
    for axis, axis_gl in ((got[both, 0, 2:4], expected[both, 0, 2:4]), (got[both, 3, :2], expected[both, 3, :2])):
        size = np.linalg.norm(axis_gl, axis=1, keepdims=True) + 1e-3
        np.testing.assert_allclose(axis / size, axis_gl / size, atol=2e-3)
    conic, conic_gl = got[both, 1, :3].astype(np.float64), expected[both, 1, :3].astype(np.float64)
    scale = np.abs(conic_gl).max(axis=1, keepdims=True)
    np.testing.assert_allclose(conic / scale, conic_gl / scale, atol=2e-3)


def test_the_sh_degree_cap_and_splat_scale_are_honoured(gl_context):
    arrays = stiff_model(500, seed=7, degree=3).numpy()
    cam = camera()
    texels, anchor, _ = pack_gaussians(arrays)
    capped = preprocess_splats(texels, 1, shader_camera(cam, anchor), MODES["rgb"], 1.0)
    expected = shader_output(gl_context, arrays, cam, "rgb", sh_degree_cap=1)
    both = (capped[:, 1, 3] > 0) & (expected[:, 1, 3] > 0)
    np.testing.assert_allclose(capped[both, 2, :3], expected[both, 2, :3], rtol=1e-3, atol=1e-4)
    full = preprocess_splats(texels, 3, shader_camera(cam, anchor), MODES["rgb"], 1.0)
    assert not np.allclose(full[both, 2, :3], capped[both, 2, :3])   # the cap changed colours
    wide = preprocess_splats(texels, 3, shader_camera(cam, anchor), MODES["rgb"], 2.0)
    assert (np.abs(wide[both, 0, 2:4]).sum() > np.abs(full[both, 0, 2:4]).sum() * 1.5)


def test_switching_the_compositing_between_frames_keeps_the_model(gl_context):
    """"cpu" keeps the packed Gaussians on the CPU; a quad path uploads them when it first
    draws, and "cpu" again reads them back from GL: the same frame each time on "cpu"."""
    arrays = stiff_model(800, seed=9, degree=1).numpy()
    cam = camera()
    renderer = SplatRenderer(gl_context, sort="cpu", compositing="cpu")
    try:
        renderer.set_gaussians(arrays)
        first = renderer.render(cam, "rgb")
        renderer.compositing = "blend"
        blended = renderer.render(cam, "rgb")
        renderer.compositing = "cpu"
        again = renderer.render(cam, "rgb")
    finally:
        renderer.release()
    np.testing.assert_array_equal(again, first)
    assert float(np.abs(blended - first).mean()) < 0.05   # the same model drawn by the quads
    assert first.max() > 0.1
