"""The GL renderer's parts: camera matrices, sorting, uploads, picking, window drawing, CLI."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from inceptiongs.camera import Camera, look_at, write_camera_json
from inceptiongs.gaussians import Gaussians

moderngl = pytest.importorskip("moderngl")
from inceptiongs.renderer.context import RendererError, check_context  # noqa: E402
from inceptiongs.renderer.crosscheck import psnr  # noqa: E402
from inceptiongs.renderer.gl_camera import gl_view_projection  # noqa: E402
from inceptiongs.renderer.sorting import depth_order, quad_elements, visible_depth_order  # noqa: E402
from inceptiongs.renderer.splats import SplatRenderer  # noqa: E402


def random_model(n: int, seed: int, degree: int = 1) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    return Gaussians(torch.rand(n, 3, generator=gen) * 2 - 1, torch.rand(n, 3, generator=gen) * 2 - 4.5,
                     torch.randn(n, 4, generator=gen), torch.randn(n, generator=gen) * 1.5,
                     torch.randn(n, (degree + 1) ** 2, 3, generator=gen) * 0.4)


def view(width=80, height=60, eye=(0.4, -0.3, -3.0)) -> Camera:
    return Camera("v", width, height, 70.0, 72.0, width / 2 + 1.5, height / 2 - 2.5,
                  look_at(np.asarray(eye), np.zeros(3)))


def test_gl_view_projection_reproduces_the_pinhole():
    cam = view()
    points = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    view_m, proj = gl_view_projection(cam, 0.1, 100.0)
    clip = (proj.astype(np.float64) @ view_m.astype(np.float64) @ np.c_[points, np.ones(50)].T).T
    ndc = clip[:, :3] / clip[:, 3:]
    t = points @ cam.rotation.T + cam.world_to_camera[:3, 3]
    u = cam.fx * t[:, 0] / t[:, 2] + cam.cx
    v = cam.fy * t[:, 1] / t[:, 2] + cam.cy
    np.testing.assert_allclose((ndc[:, 0] + 1) * cam.width / 2, u, atol=1e-3)
    np.testing.assert_allclose((1 - ndc[:, 1]) * cam.height / 2, v, atol=1e-3)  # NDC +1 = image top
    assert np.all(np.abs(ndc[:, 2]) <= 1)


def test_old_gl_is_refused_with_the_version_found():
    fake = SimpleNamespace(version_code=320, info={"GL_RENDERER": "old card"})
    with pytest.raises(RendererError, match="OpenGL 3.2 found .old card."):
        check_context(fake)
    assert check_context(SimpleNamespace(version_code=330, info={})) is False
    assert check_context(SimpleNamespace(version_code=450, info={})) is True


def test_numpy_order_and_quad_elements():
    means = np.array([[0, 0, 2.0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 3.0]], np.float32)
    rotation, translation = np.eye(3), np.zeros(3)
    assert depth_order(means, rotation, translation, True).tolist() == [1, 0, 2, 3]
    assert depth_order(means, rotation, translation, False).tolist() == [3, 2, 0, 1]
    assert quad_elements(np.array([2, 0], np.uint32)).tolist() == [8, 9, 10, 10, 9, 11, 0, 1, 2, 2, 1, 3]


def test_visible_order_is_float32_z_then_index_without_the_culled():
    rng = np.random.default_rng(0)
    means = rng.uniform(-1, 1, (5000, 3)).astype(np.float32)
    means[100:300] = means[50]  # exact ties
    means[400:410, 2] = np.nextafter(np.float32(0.25), np.float32(1))  # ties only after rounding
    rotation, translation = np.eye(3), np.array([0.0, 0.0, 3.0])
    visible = rng.uniform(size=5000) > 0.2
    order = visible_depth_order(means, visible, rotation, translation)
    z = (means.astype(np.float64) @ rotation[2] + translation[2]).astype(np.float32)
    expected = [i for i in sorted(range(5000), key=lambda i: (z[i], i)) if visible[i]]
    assert order.tolist() == expected
    assert visible_depth_order(means, np.zeros(5000, bool), rotation, translation).size == 0


def test_visible_order_at_scale_and_with_a_foreign_mask():
    """200k splats turned by a random rotation (the numba radix sort's three passes all matter)
    against the plain (float32 z, index) key sort; a mask that lets through depths behind the
    camera gets the stable float sort instead."""
    rng = np.random.default_rng(3)
    means = rng.uniform(-1, 1, (200_000, 3)).astype(np.float32)
    means[1000:1500] = means[7]   # exact ties
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    translation = np.array([0.2, -0.1, 2.5])
    visible = rng.uniform(size=200_000) > 0.3
    order = visible_depth_order(means, visible, rotation, translation)
    candidates = np.flatnonzero(visible)
    z = (means[candidates].astype(np.float64) @ rotation[2] + translation[2]).astype(np.float32)
    expected = candidates[np.lexsort((candidates, z))]
    np.testing.assert_array_equal(order, expected)
    behind = visible_depth_order(means, visible, rotation, np.array([0.0, 0.0, 0.0]))   # z of both signs
    z = (means[candidates].astype(np.float64) @ rotation[2]).astype(np.float32)
    np.testing.assert_array_equal(behind, candidates[np.lexsort((candidates, z))])


@pytest.mark.parametrize("compositing", ["fetch", "blend"])
def test_gpu_bitonic_sort_matches_numpy_sort(gl_context, compositing):
    if gl_context.version_code < 430:
        pytest.skip("GPU sort needs GL 4.3")
    if compositing == "fetch" and "GL_EXT_shader_framebuffer_fetch" not in gl_context.extensions:
        pytest.skip("no framebuffer fetch")
    model = random_model(2500, seed=1)
    # Include exact depth ties (resolved by index in both sorts) and culled Gaussians.
    model.means[:200] = model.means[200:201]
    model.opacity_logits[300:400] = -40.0
    images = []
    for sort in ("gpu", "cpu"):
        renderer = SplatRenderer(gl_context, sort=sort, compositing=compositing)  # the sort orders quads
        renderer.set_gaussians(model.numpy())
        images.append((renderer.render(view(), "rgb"), renderer.render(view(), "alpha")))
        renderer.release()
    np.testing.assert_allclose(images[0][0], images[1][0], atol=1e-5)
    np.testing.assert_allclose(images[0][1], images[1][1], atol=1e-6)


def test_same_version_uploads_nothing_and_new_version_does(gl_context):
    renderer = SplatRenderer(gl_context)
    first, second = random_model(300, seed=2), random_model(500, seed=3)
    renderer.set_gaussians(first.numpy(), version=7)
    image_first = renderer.render(view())
    renderer.set_gaussians(second.numpy(), version=7)  # same version: ignored
    np.testing.assert_array_equal(renderer.render(view()), image_first)
    assert renderer.count == 300
    renderer.set_gaussians(second.numpy(), version=8)
    assert renderer.count == 500
    assert psnr(renderer.render(view()), image_first) < 40
    renderer.release()


def test_pick_depth_is_the_depth_render_at_that_pixel(gl_context):
    renderer = SplatRenderer(gl_context)
    model = random_model(400, seed=4)
    model.opacity_logits += 3.0
    renderer.set_gaussians(model.numpy())
    cam = view()
    depth = renderer.render(cam, "depth")
    alpha = renderer.render(cam, "alpha")
    y, x = np.argwhere(alpha[..., 0] > 0.5)[0]
    # pick_depth renders a 1x1 window of the camera; the EWA Jacobian clamp depends on the
    # image extent, so Gaussians outside the window's widened frustum project slightly
    # differently: close, not bit-equal.
    assert renderer.pick_depth(cam, int(x), int(y)) == pytest.approx(float(depth[y, x, 0]), rel=1e-3)
    assert renderer.pick_depth(cam, -1, 0) is None
    far_away = Camera("away", 80, 60, 70.0, 70.0, 40.0, 30.0, look_at(np.array([0, 0, -3.0]), np.array([0, 0, -6.0])))
    assert renderer.pick_depth(far_away, 40, 30) is None
    assert set(renderer.timings) >= {"sort_ms", "draw_ms"} and min(renderer.timings.values()) >= 0
    renderer.release()


def test_draw_into_a_framebuffer_is_upright_with_background(gl_context):
    renderer = SplatRenderer(gl_context)
    renderer.set_gaussians(random_model(400, seed=5).numpy())
    cam = view()
    target = gl_context.framebuffer(color_attachments=[gl_context.renderbuffer((cam.width, cam.height), 4, dtype="f4")])
    background = (0.3, 0.1, 0.6)
    renderer.draw(cam, "rgb", target, background=background)
    drawn = np.frombuffer(target.read(components=4, dtype="f4"), np.float32).reshape(cam.height, cam.width, 4)
    upright = drawn[::-1, :, :3]  # GL row 0 is the window's bottom
    if renderer.compositing != "cpu":
        renderer.compositing = "blend"  # draw() blends back to front: compare like with like
    reference = renderer.render(cam, "rgb", background=background)
    np.testing.assert_allclose(upright, reference, atol=1e-5)
    target.release()
    renderer.release()


def test_render_cli_gl_matches_torch_and_writes_png(tmp_path):
    from inceptiongs.cli import main
    from inceptiongs.io.ply import write_ply
    model_path = tmp_path / "model.ply"
    write_ply(random_model(600, seed=6, degree=2), model_path)
    write_camera_json(view(96, 64), tmp_path / "cam.json")
    outputs = {}
    for backend in ("gl", "torch"):
        out = tmp_path / f"{backend}.npy"
        assert main(["render", str(model_path), "--camera", str(tmp_path / "cam.json"), "--backend", backend,
                     "--out", str(out), "--background", "0.2,0.2,0.2"]) == 0
        outputs[backend] = np.load(out)
    assert outputs["gl"].shape == (64, 96, 3)
    assert psnr(outputs["gl"], outputs["torch"]) >= 45
    png = tmp_path / "depth.png"
    assert main(["render", str(tmp_path), "--camera", str(tmp_path / "cam.json"), "--mode", "depth",
                 "--out", str(png), "--width", "48"]) == 0  # a run folder holding model.ply
    import cv2
    image = cv2.imread(str(png))
    assert image.shape == (32, 48, 3) and image.max() > 0
    assert main(["render", str(model_path), "--camera", str(tmp_path / "cam.json"), "--out",
                 str(tmp_path / "x.jpg")]) == 2
    assert main(["render", str(model_path), "--view", "anything", "--out", str(png)]) == 2


@pytest.mark.slow
def test_render_cli_view_from_a_scene(tmp_path):
    from inceptiongs.cli import main
    from demo_cases import copy_of_demo_scene
    from inceptiongs.io.ply import write_ply
    from inceptiongs.scene.loader import load_scene
    scene_dir = copy_of_demo_scene(tmp_path / "scene")
    scene = load_scene(scene_dir)
    model = random_model(300, seed=7, degree=0)
    # Model in the scene's original frame, as a trained model.ply is.
    write_ply(scene.normalization.gaussians_to_original(model), tmp_path / "model.ply")
    name = scene.cameras[0].name
    out = tmp_path / "view.npy"
    assert main(["render", str(tmp_path / "model.ply"), "--view", name, "--scene", str(scene_dir),
                 "--backend", "gl", "--mode", "alpha", "--out", str(out)]) == 0
    from inceptiongs.rasterizer.rasterize import render
    with torch.no_grad():
        ref = render(model, scene.camera_by_name(name), outputs=("alpha",))["alpha"].numpy()
    assert np.load(out).shape == ref.shape
    assert np.mean(np.abs(np.load(out) - ref) <= 2e-3) >= 0.999
    assert main(["render", str(tmp_path / "model.ply"), "--view", "no-such-view", "--scene", str(scene_dir),
                 "--out", str(out)]) == 2
    json.loads((scene_dir / "demo_scene.json").read_text())
