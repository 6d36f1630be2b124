"""`inceptiongs info` on the real captures, a PLY and a scene the test writes."""

from __future__ import annotations

import json

import numpy as np
import pycolmap

from conftest import require_data
from inceptiongs.cli import main
from inceptiongs.scene.colmap import write_colmap_binary
from scene_cases import known_cameras, known_points, write_images


def _info_json(path, capsys) -> dict:
    assert main(["info", str(path), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_info_statuette(capsys):
    root = require_data("statuette")
    summary = _info_json(root, capsys)
    recon = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    assert summary["format"] == "colmap-binary" and summary["cameras"] == 23
    assert summary["camera_models"] == {"PINHOLE": 23} and summary["sparse_points"] == 1443
    assert sum(summary["resolutions"].values()) == 23 and "1000x657" in summary["resolutions"]
    centers = np.array([im.projection_center() for im in recon.images.values()])
    extent = np.linalg.norm(centers - centers.mean(axis=0), axis=1).max()
    assert abs(summary["camera_extent"] - extent) < 1e-9  # original units
    assert summary["warnings"] == []
    assert main(["info", str(root)]) == 0
    text = capsys.readouterr().out
    assert "colmap-binary" in text and "PINHOLE (23)" in text


def test_info_fern(capsys):
    summary = _info_json(require_data("fern"), capsys)
    assert summary["format"] == "llff" and summary["cameras"] == 20
    assert summary["resolutions"] == {"504x378": 20} and summary["sparse_points"] == 0


def test_info_ply(capsys):
    path = require_data("splats/donut.ply")
    summary = _info_json(path, capsys)
    assert summary["gaussians"] == 45624 and summary["sh_degree"] == 0
    assert np.all(np.array(summary["bounds"][0]) < np.array(summary["bounds"][1]))


def test_info_lists_missing_images_as_warnings_with_point_bounds(tmp_path, capsys):
    cameras = known_cameras(count=3)
    write_images(tmp_path / "images", cameras, [None] * 3)
    (tmp_path / "images" / cameras[2].name).unlink()
    (tmp_path / "sparse" / "0").mkdir(parents=True)
    write_colmap_binary(tmp_path / "sparse" / "0",
                        [(c, "PINHOLE", [c.fx, c.fy, c.cx, c.cy]) for c in cameras], known_points())
    summary = _info_json(tmp_path, capsys)
    assert summary["cameras"] == 3 and summary["sparse_points"] == len(known_points())
    assert len(summary["warnings"]) == 1 and cameras[2].name in summary["warnings"][0]
    bounds = np.array(summary["points_bounds"])
    assert np.allclose(bounds[0], known_points().min(axis=0)) and np.allclose(bounds[1], known_points().max(axis=0))
    # Coverage: all three cameras see every point (a missing image does not change the geometry).
    coverage = summary["coverage"]
    assert coverage["available"] and coverage["views_per_point"]["median"] == 3 and coverage["views"] == 3


def test_info_warns_about_duplicate_image_names(tmp_path, capsys):
    from inceptiongs.camera import rigid_inverse

    cameras = known_cameras(count=2)
    write_images(tmp_path / "images", cameras, [None] * 2)
    frames = []
    for camera in [cameras[0], cameras[1], cameras[1]]:
        c2w = rigid_inverse(camera.world_to_camera) @ np.diag([1.0, -1.0, -1.0, 1.0])
        frames.append({"file_path": f"images/{camera.name}", "transform_matrix": c2w.tolist()})
    (tmp_path / "transforms.json").write_text(json.dumps({"fl_x": 60, "w": 120, "h": 90, "frames": frames}))
    summary = _info_json(tmp_path, capsys)
    assert summary["cameras"] == 3
    image = tmp_path / "images" / cameras[1].name
    assert summary["warnings"] == [f"{image}: duplicate image name images/{cameras[1].name} "
                                   "(more than one camera uses it)"]
    assert main(["info", str(tmp_path), "--strict"]) == 2
    assert capsys.readouterr().err.startswith(f"error: {image}: duplicate image name")
