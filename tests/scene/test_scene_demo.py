"""The procedural demo scene: a loadable COLMAP model whose photos, cameras and sparse points
agree, an uneven camera path, determinism, and safe writing."""

from __future__ import annotations

import json

import numpy as np
import pytest

import inceptiongs.scene.demo as demo
from inceptiongs.camera import pose_distance
from inceptiongs.errors import InputError
from inceptiongs.scene.loader import load_scene


@pytest.fixture(scope="module")
def demo_root(tmp_path_factory):
    return demo.write_demo_scene(tmp_path_factory.mktemp("demo") / "scene", progress=False)


def test_demo_scene_loads_with_named_camera_groups(demo_root):
    scene = load_scene(demo_root)
    width, height, n_dense, n_scarce = demo.SIZES["small"]
    assert scene.format == "colmap-binary" and scene.warnings == []
    assert len(scene.cameras) == n_dense + n_scarce
    assert {(c.width, c.height) for c in scene.cameras} == {(width, height)}
    meta = json.loads((demo_root / "demo_scene.json").read_text())
    names = {c.name for c in scene.cameras}
    assert len(meta["dense_cameras"]) == n_dense and len(meta["scarce_cameras"]) == n_scarce
    assert set(meta["dense_cameras"]) | set(meta["scarce_cameras"]) == names
    assert len(scene.points) > 1000 and scene.point_colors.dtype == np.uint8

    # Uneven path: every scarce camera is further from the dense arc than dense neighbours
    # are from each other.
    dense = [scene.camera_by_name(n).world_to_camera for n in meta["dense_cameras"]]
    scarce = [scene.camera_by_name(n).world_to_camera for n in meta["scarce_cameras"]]
    dense_spacing = max(min(pose_distance(a, b) for j, b in enumerate(dense) if j != i)
                        for i, a in enumerate(dense))
    for pose in scarce:
        assert min(pose_distance(pose, d) for d in dense) > 2 * dense_spacing


def test_sparse_points_have_the_colour_of_the_photos_where_they_project(demo_root):
    scene = load_scene(demo_root)

    def best_colour_error(shift: float) -> np.ndarray:
        best = np.full(len(scene.points), np.inf)
        for index, camera in enumerate(scene.cameras):
            image = scene.load_image(index)
            p = scene.points @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
            u = camera.fx * p[:, 0] / np.maximum(p[:, 2], 1e-9) + camera.cx + shift
            v = camera.fy * p[:, 1] / np.maximum(p[:, 2], 1e-9) + camera.cy
            inside = (p[:, 2] > 0) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
            pixels = image[v[inside].astype(int), u[inside].astype(int)]
            error = np.abs(pixels - scene.point_colors[inside] / 255.0).max(axis=1)
            best[inside] = np.minimum(best[inside], error)
        return best

    best = best_colour_error(0.0)
    assert np.isfinite(best).all()  # every point is seen by some camera
    assert np.mean(best < 0.06) > 0.97 and np.median(best) < 1e-3
    assert np.median(best_colour_error(3.0)) > 1e-3  # the check notices misplaced points


def test_photos_are_textured_and_deterministic(demo_root):
    scene = load_scene(demo_root)
    image = scene.load_image(0)
    # Detail everywhere: strong local gradients, not flat colours.
    gradient = np.abs(np.diff(image, axis=1)).mean()
    assert gradient > 0.02
    cameras, _, _ = demo.demo_cameras("small", seed=0)
    tex = demo.Textures(noise=np.random.default_rng(0).random((64, 64)))
    again = demo.render_photo(cameras[0], tex)
    assert np.abs(again - image).max() <= 0.5 / 255 + 1e-6  # only PNG quantisation
    other, _, _ = demo.demo_cameras("small", seed=1)
    assert not np.allclose(other[0].world_to_camera, cameras[0].world_to_camera)


@pytest.fixture
def tiny_sizes(monkeypatch):
    monkeypatch.setitem(demo.SIZES, "small", (32, 24, 3, 1))


def test_refuses_foreign_folder_and_replaces_previous_demo(tmp_path, tiny_sizes):
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep")
    with pytest.raises(InputError, match="not an empty folder or a previous demo scene"):
        demo.write_demo_scene(foreign, progress=False)
    assert (foreign / "notes.txt").read_text() == "keep"

    out = tmp_path / "demo"
    demo.write_demo_scene(out, seed=1, progress=False)
    first = (out / "images" / "000.png").read_bytes()
    demo.write_demo_scene(out, seed=2, progress=False)
    assert (out / "images" / "000.png").read_bytes() != first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo", "mine"]  # no staging left


def test_interrupted_write_leaves_nothing(tmp_path, tiny_sizes, monkeypatch):
    calls = []

    def failing(camera, tex):
        calls.append(camera.name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return np.zeros((camera.height, camera.width, 3))

    monkeypatch.setattr(demo, "render_photo", failing)
    with pytest.raises(KeyboardInterrupt):
        demo.write_demo_scene(tmp_path / "demo", progress=False)
    assert list(tmp_path.iterdir()) == []
