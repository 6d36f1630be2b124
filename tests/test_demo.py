"""`inceptiongs demo`: the main job end to end on the demo scene (a few iterations)."""

from __future__ import annotations

import json

import pytest

from inceptiongs.cli import main
from inceptiongs.protocols import Split


@pytest.mark.slow
def test_demo_writes_scene_run_report_and_summary(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", str(out), "--iterations", "4"]) == 0
    assert (out / "scene" / "demo_scene.json").is_file()
    for name in ("config.json", "split.json", "model.ply", "metrics.jsonl", "eval/eval.json"):
        assert (out / "run" / name).is_file(), name
    for name in ("report.png", "before_target.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"

    split = Split.load(out / "run" / "split.json")
    assert split.protocol == "unstructured" and split.target_view in split.scarce_test
    evaluation = json.loads((out / "run" / "eval" / "eval.json").read_text())
    summary = (out / "summary.md").read_text()
    # The summary's table rows are the eval.json numbers.
    for group in ("scarce", "covered", "all"):
        entry = evaluation["groups"][group]
        assert f"| {group} | {entry['views']} | {entry['psnr']:.2f} | {entry['ssim']:.4f} |" in summary
    target_image = next(v["image"] for v in evaluation["views"] if v["index"] == split.target_view)
    assert (out / "run" / target_image).is_file() and f"run/{target_image}" in summary
    assert "unavailable" in summary  # no LPIPS/FID weights were given
    assert "PSNR" in capsys.readouterr().out


def test_demo_rejects_bad_arguments(tmp_path, capsys):
    assert main(["demo", str(tmp_path / "x"), "--minutes", "0"]) == 2
    (tmp_path / "file").write_text("")
    assert main(["demo", str(tmp_path / "file")]) == 2
    assert "file" in capsys.readouterr().err
