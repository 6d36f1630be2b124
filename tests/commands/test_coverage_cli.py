"""`inceptiongs coverage` on a scene with known cameras and points, and its bad input."""

from __future__ import annotations

import json

from inceptiongs.cli import main
from inceptiongs.scene.colmap import write_colmap_binary
from scene_cases import known_cameras, known_points, write_images


def _scene(root, count=3):
    cameras = known_cameras(count=count)
    write_images(root / "images", cameras, [None] * count)
    (root / "sparse" / "0").mkdir(parents=True)
    write_colmap_binary(root / "sparse" / "0", [(c, "PINHOLE", [c.fx, c.fy, c.cx, c.cy]) for c in cameras],
                        known_points())
    return cameras


def test_coverage_of_a_scene_counts_every_camera_and_writes_the_figure(tmp_path, capsys):
    cameras = _scene(tmp_path / "scene", count=3)
    out = tmp_path / "coverage.png"
    assert main(["coverage", str(tmp_path / "scene"), "--out", str(out), "--json", "--suggest", "2"]) == 0
    figures = json.loads(capsys.readouterr().out)
    # Every known point is in front of all three cameras and inside their images.
    assert figures["points"] == len(known_points()) and figures["views_per_point"]["p10"] == 3
    assert figures["thinly_seen_fraction"] == 0.0 and not figures["occlusion_tested"]
    assert len(figures["scarcest_views"]) == 2
    assert {v["name"] for v in figures["scarcest_views"]} <= {c.name for c in cameras}
    assert out.read_bytes()[:4] == b"\x89PNG"

    assert main(["coverage", str(tmp_path / "scene"), "--out", str(tmp_path / "c.png")]) == 0
    printed = capsys.readouterr().out
    assert "views per point: median 3" in printed and "scarcest views" in printed


def test_coverage_rejects_bad_input(tmp_path, capsys):
    assert main(["coverage", str(tmp_path / "missing"), "--out", str(tmp_path / "c.png")]) == 2
    assert "does not exist" in capsys.readouterr().err
    _scene(tmp_path / "scene")
    assert main(["coverage", str(tmp_path / "scene"), "--out", str(tmp_path / "c.jpg")]) == 2
    assert "c.jpg" in capsys.readouterr().err
