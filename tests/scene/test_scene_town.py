"""The town: a loadable COLMAP capture whose photos, sparse points and camera groups agree with
the geometry it was ray-cast from, checked against a brute-force ray-box test that uses no grid."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from inceptiongs.cli import main
from inceptiongs.scene import town as town_mod
from inceptiongs.scene.loader import load_scene, read_raw_scene
from inceptiongs.scene.town_layout import blocks_for_views, make_town
from inceptiongs.scene.town_trace import GROUND, SKY, scene_tuple

VIEWS, WIDTH, HEIGHT, SEED = 40, 96, 72, 3


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return town_mod.write_town_scene(tmp_path_factory.mktemp("town") / "scene", views=VIEWS, width=WIDTH,
                                     height=HEIGHT, seed=SEED, progress=False)


@pytest.fixture(scope="module")
def town():
    return make_town(blocks_for_views(VIEWS), SEED)


def brute_force_hits(boxes: np.ndarray, origins: np.ndarray, dirs: np.ndarray):
    """Nearest hit of each ray over every box and the ground plane, no acceleration:
    origins, dirs [R, 3] -> (t [R], inf for the sky; hit [R]: box index, GROUND or SKY)."""
    safe = np.where(np.abs(dirs) > 1e-12, dirs, 1e-12)
    lo = (boxes[None, :, :3] - origins[:, None]) / safe[:, None]      # [R, K, 3]
    hi = (boxes[None, :, 3:] - origins[:, None]) / safe[:, None]
    enter = np.minimum(lo, hi).max(axis=2)
    leave = np.maximum(lo, hi).min(axis=2)
    t_box = np.where((enter <= leave) & (enter > 1e-9), enter, np.inf)
    nearest = np.argmin(t_box, axis=1)
    t = t_box[np.arange(len(origins)), nearest]
    hit = np.where(np.isfinite(t), nearest, SKY)
    falling = dirs[:, 2] < -1e-12
    t_ground = np.where(falling, -origins[:, 2] / np.where(falling, dirs[:, 2], -1.0), np.inf)
    ground = t_ground < t
    return np.where(ground, t_ground, t), np.where(ground, GROUND, hit)


def test_town_loads_with_its_camera_groups(root):
    scene = load_scene(root)
    meta = json.loads((root / "demo_scene.json").read_text())
    assert scene.format == "colmap-binary" and scene.warnings == [] and meta["scene"] == "town"
    assert len(scene.cameras) == VIEWS and {(c.width, c.height) for c in scene.cameras} == {(WIDTH, HEIGHT)}
    assert set(scene.camera_models) == {"PINHOLE"}
    names = {c.name for c in scene.cameras}
    assert set(meta["dense_cameras"]) | set(meta["scarce_cameras"]) == names
    assert not set(meta["dense_cameras"]) & set(meta["scarce_cameras"])
    assert len(meta["scarce_cameras"]) >= 3 and set(meta["aerial_cameras"]) <= set(meta["dense_cameras"])
    assert all(p.suffix == ".jpg" and p.read_bytes()[:2] == b"\xff\xd8" for p in scene.image_paths)
    assert 300 < len(scene.points) < 100 * VIEWS
    photo = scene.load_image(0)
    assert photo.shape == (HEIGHT, WIDTH, 3) and float(np.std(photo)) > 0.05   # textured, not flat


def test_grid_ray_caster_matches_brute_force(town):
    cameras, *_ = town_mod.town_cameras(town, VIEWS, WIDTH, HEIGHT, SEED)
    rng = np.random.default_rng(0)
    origins, dirs = [], []
    for camera in cameras:
        o, d = town_mod.camera_rays(camera, rng.uniform(0, 1, (150, 2)) * (WIDTH, HEIGHT))
        origins.append(o)
        dirs.append(d)
    origins, dirs = np.concatenate(origins), np.concatenate(dirs)
    t, hit, _, _ = town_mod.trace_rays(scene_tuple(town), origins, dirs)
    t_ref, hit_ref = brute_force_hits(town.boxes, origins, dirs)
    assert {GROUND, SKY} < set(hit.tolist()) and (hit >= 0).mean() > 0.3      # all three kinds occur
    finite = np.isfinite(t_ref)
    assert np.array_equal(np.isfinite(t), finite)
    assert np.allclose(t[finite], t_ref[finite], rtol=1e-9, atol=1e-9)
    # The hit surface agrees wherever the nearest hit is not a tie between touching boxes.
    assert (hit == hit_ref).mean() > 0.99


def test_scarce_views_see_the_yard_close_and_dense_views_only_from_afar(root, town):
    meta = json.loads((root / "demo_scene.json").read_text())
    assert [tuple(c["yard"]) for c in meta["courtyards"]] == [c.yard for c in town.courtyards]
    cameras, dense, scarce, _ = town_mod.town_cameras(town, VIEWS, WIDTH, HEIGHT, SEED)
    assert (dense, scarce) == (meta["dense_cameras"], meta["scarce_cameras"])
    j, i = np.mgrid[0:HEIGHT, 0:WIDTH]
    pixels = np.stack([i.ravel() + 0.5, j.ravel() + 0.5], axis=1)
    close, nearest = {}, {}
    for camera in cameras:
        origins, dirs = town_mod.camera_rays(camera, pixels)
        t, hit, _, _ = town_mod.trace_rays(scene_tuple(town), origins, dirs)
        points = origins + dirs * np.where(np.isfinite(t), t, 0.0)[:, None]
        in_yard = np.zeros(len(points), bool)
        for yard in town.courtyards:
            in_yard |= yard.contains(points) & (hit != SKY)
        close[camera.name] = float(np.mean(in_yard & (t < 12.0)))
        nearest[camera.name] = float(t[in_yard].min()) if in_yard.any() else np.inf
    # Each scarce view is filled with the yard within 12 m; no dense view has a single pixel of
    # it nearer than 15 m, though some dense views do see it (from afar: a thin region, not a
    # hidden one).
    assert min(close[n] for n in scarce) > 0.9
    assert min(nearest[n] for n in dense) > 15.0
    assert any(np.isfinite(nearest[n]) for n in dense)


def test_sparse_points_show_in_the_photos_that_see_them(root, town):
    raw = read_raw_scene(root)
    points, colours = raw.points, raw.point_colors.astype(float) / 255
    rng = np.random.default_rng(1)
    pick = rng.choice(len(points), size=min(300, len(points)), replace=False)
    seen_by = np.zeros(len(pick), int)
    errors, depth_errors = [], []
    for camera, path in zip(raw.cameras, raw.image_paths):
        photo = cv2.imread(str(path))[:, :, ::-1].astype(float) / 255
        local = points[pick] @ camera.rotation.T + camera.world_to_camera[:3, 3]
        in_front = local[:, 2] > 0.05
        u = camera.fx * local[:, 0] / np.where(in_front, local[:, 2], 1.0) + camera.cx
        v = camera.fy * local[:, 1] / np.where(in_front, local[:, 2], 1.0) + camera.cy
        inside = in_front & (u >= 0) & (v >= 0) & (u < camera.width) & (v < camera.height)
        if not inside.any():
            continue
        # Unoccluded by the brute-force test: the ray to the point stops at the point.
        offsets = points[pick][inside] - camera.center
        distance = np.linalg.norm(offsets, axis=1)
        t_ref, _ = brute_force_hits(town.boxes, np.broadcast_to(camera.center, offsets.shape), offsets / distance[:, None])
        visible = t_ref >= distance * (1 - 1e-6) - 1e-4
        index = np.flatnonzero(inside)[visible]
        seen_by[index] += 1
        # The ray-caster's depth through the point's exact image position is the point's depth.
        origins, dirs = town_mod.camera_rays(camera, np.stack([u[index], v[index]], axis=1))
        t, _, _, _ = town_mod.trace_rays(scene_tuple(town), origins, dirs)
        depth_errors.append(np.abs(t - distance[visible]) / distance[visible])
        # The photo there has the point's colour (up to supersampling, JPEG and texture detail).
        errors.append(np.abs(photo[v[index].astype(int), u[index].astype(int)] - colours[pick][index]).mean(axis=1))
    assert np.concatenate(depth_errors).max() < 1e-6
    errors = np.concatenate(errors)
    assert np.median(errors) < 0.06 and np.mean(errors < 0.15) > 0.8
    # Every point is seen by the view it was sampled from and at least two others.
    assert np.mean(seen_by >= 3) > 0.97


def test_same_seed_same_bytes(root, tmp_path):
    again = town_mod.write_town_scene(tmp_path / "again", views=VIEWS, width=WIDTH, height=HEIGHT, seed=SEED,
                                      progress=False)
    files = sorted(p.relative_to(root) for p in root.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    assert all((root / f).read_bytes() == (again / f).read_bytes() for f in files)
    other = town_mod.write_town_scene(tmp_path / "other", views=VIEWS, width=WIDTH, height=HEIGHT, seed=SEED + 1,
                                      progress=False)
    assert (other / "images" / "00000.jpg").read_bytes() != (root / "images" / "00000.jpg").read_bytes()


def test_interrupted_write_leaves_nothing(tmp_path, monkeypatch):
    calls = []
    render = town_mod.render_town_photo

    def failing(scene, camera):
        calls.append(camera.name)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return render(scene, camera)

    monkeypatch.setattr(town_mod, "render_town_photo", failing)
    with pytest.raises(KeyboardInterrupt):
        town_mod.write_town_scene(tmp_path / "town", views=VIEWS, width=WIDTH, height=HEIGHT, progress=False)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, message", [
    (["--views", "5"], "--views 5: the town needs"),
    (["--views", "10000000"], "--views 10000000: the town needs"),
    (["--size", "20x10000"], "--size 20x10000: each side must be"),
    (["--size", "huge"], "--size huge: expected WIDTHxHEIGHT"),
])
def test_bad_town_requests_are_one_line(tmp_path, capsys, argv, message):
    assert main(["demo-scene", str(tmp_path / "out"), "--scene", "town", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "out").exists()


def test_views_belong_to_the_town_only(tmp_path, capsys):
    assert main(["demo-scene", str(tmp_path / "out"), "--views", "100"]) == 2
    assert "only the town takes a number of views" in capsys.readouterr().err


def test_town_grows_with_the_views():
    small, large = make_town(blocks_for_views(40)), make_town(blocks_for_views(3000))
    assert large.blocks >= 3 * small.blocks and len(large.boxes) > 6 * len(small.boxes)
    assert len(large.courtyards) > len(small.courtyards) >= 1
    # Box heights vary (several storeys, towers) and each box sits in the grid cells it covers.
    heights = large.boxes[:, 5] - large.boxes[:, 2]
    assert heights.min() < 8.0 and heights.max() > 30.0
    for k in (0, len(large.boxes) // 2, len(large.boxes) - 1):
        x, y = (large.boxes[k, 0] + large.boxes[k, 3]) / 2, (large.boxes[k, 1] + large.boxes[k, 4]) / 2
        c = int((y - large.grid_y0) // 6.0) * large.grid_n + int((x - large.grid_x0) // 6.0)
        assert k in large.cell_items[large.cell_start[c]:large.cell_start[c + 1]]
