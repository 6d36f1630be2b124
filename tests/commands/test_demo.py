"""`inceptiongs demo`: the whole pipeline end to end on the demo scene (a few iterations)."""

from __future__ import annotations

import json

import pytest

from inceptiongs.cli import main
from inceptiongs.evaluation.protocols import Split


@pytest.mark.slow
def test_demo_runs_stage_one_bootstrap_evaluation_and_report(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", str(out), "--iterations", "4", "--downscale", "4", "--bootstrap-iterations", "4",
                 "--prior-steps", "2", "--ddim-steps", "2"]) == 0
    assert (out / "scene" / "demo_scene.json").is_file()
    for run in ("run", "run_bootstrap"):
        for name in ("config.json", "split.json", "model.ply", "metrics.jsonl", "eval/eval.json"):
            assert (out / run / name).is_file(), f"{run}/{name}"
    for name in ("report.png", "target.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    assert list((out / "run_bootstrap" / "bootstrap" / "views").glob("*.png"))

    split = Split.load(out / "run" / "split.json")
    assert split.protocol == "unstructured" and split.target_view in split.scarce_test
    assert Split.load(out / "run_bootstrap" / "split.json").test == split.test
    stage1 = json.loads((out / "run" / "eval" / "eval.json").read_text())
    boot = json.loads((out / "run_bootstrap" / "eval" / "eval.json").read_text())
    report = (out / "report.md").read_text()
    # The report's table rows are the eval.json numbers of both runs.
    for group in ("scarce", "covered", "all"):
        a, b = stage1["groups"][group], boot["groups"][group]
        assert (f"| {group} | {a['views']} | {a['psnr']:.2f} | {a['ssim']:.4f} | {b['psnr']:.2f} | "
                f"{b['ssim']:.4f} | {b['psnr'] - a['psnr']:+.2f} |") in report
    assert "target.png" in report and "unavailable" in report  # no LPIPS/FID weights were given
    printed = capsys.readouterr().out
    assert "[5/5]" in printed and "PSNR" in printed


def test_demo_rejects_bad_arguments(tmp_path, capsys):
    assert main(["demo", str(tmp_path / "x"), "--minutes", "0"]) == 2
    assert main(["demo", str(tmp_path / "x"), "--bootstrap-iterations", "0"]) == 2
    (tmp_path / "file").write_text("")
    assert main(["demo", str(tmp_path / "file")]) == 2
    assert "file" in capsys.readouterr().err
