"""The verdict tells the truth about time: a bootstrap is compared only with a baseline of the same
stage-I run, start and wall time (summary_file.same_time_mismatch), in the viewer, `eval` and
`report` alike; a baseline of another length is refused and named, and the sentence says when the
bootstrap made no step, no virtual step, or scored below stage I."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from inceptiongs.bootstrap.summary_file import SAME_TIME_MIN_S, SAME_TIME_TOLERANCE, same_time_mismatch
from inceptiongs.cli import main
from inceptiongs.evaluation.verdict import BootstrapVerdict, read_bootstrap_verdict, verdict_line


def _summary(run="/runs/run", baseline=False, start=536, end=900, seconds=68.1, **extra) -> dict:
    return {"run": run, "baseline": baseline, "start_iteration": start, "iteration": end, "wall_s": seconds, **extra}


def _scores(scarce: float, covered: float) -> dict:
    return {"scarce_psnr": scarce, "covered_psnr": covered, "all_psnr": 0.5 * (scarce + covered)}


def write_summary(folder: Path, run: Path, baseline: bool, seconds: float, start: int = 536, end: int = 900,
                  before=(15.12, 22.0), after=(15.50, 22.1), virtual_steps: int = 20) -> Path:
    (folder / "bootstrap").mkdir(parents=True, exist_ok=True)
    steps = {"real": end - start, "l1_ssim": 0 if baseline else virtual_steps}
    data = {**_summary(str(run), baseline, start, end, seconds), "steps": steps,
            "initial_eval": _scores(*before), "last_eval": _scores(*after)}
    (folder / "bootstrap" / "summary.json").write_text(json.dumps(data), encoding="utf-8")
    return folder


def test_same_time_means_same_stage_i_same_start_and_the_same_wall_time_within_the_tolerance():
    boot = _summary()
    assert same_time_mismatch(boot, _summary(baseline=True, seconds=68.8)) is None          # the demo's pair
    assert same_time_mismatch(boot, _summary(baseline=True, seconds=68.1 * (1 + SAME_TIME_TOLERANCE) + 0.1)) \
        == "it ran 72 s, the bootstrap 68 s"
    short = _summary(seconds=5.0, end=536)                                                  # a 0-step bootstrap
    assert same_time_mismatch(short, _summary(baseline=True, seconds=66.0)) == "it ran 66 s, the bootstrap 5 s"
    assert same_time_mismatch(short, _summary(baseline=True, seconds=5.0 + SAME_TIME_MIN_S)) is None
    assert "another stage-I run" in same_time_mismatch(boot, _summary(run="/runs/other", baseline=True))
    assert same_time_mismatch(boot, _summary(baseline=True, start=300)) == \
        "it started at iteration 300, the bootstrap at 536"
    assert "not recorded" in same_time_mismatch(boot, {**_summary(baseline=True), "wall_s": None})
    assert "not a baseline" in same_time_mismatch(boot, _summary())


def test_the_sentence_says_no_step_no_virtual_step_and_below_stage_i():
    flat = _scores(15.12, 22.0)
    nothing = BootstrapVerdict(Path("boot"), None, flat, _scores(15.26, 22.0), seconds=4.0, iterations=(536, 536),
                               refused=((Path("run_baseline"), "it ran 66 s, the bootstrap 4 s"),))
    line = verdict_line(nothing)
    assert line.startswith("held-out scarce views: better by 0.14 dB than stage I; no same-time baseline (stage I continued on "
                           "the photos alone for 4 s) was run; run_baseline is not one: it ran 66 s, the bootstrap 4 s")
    assert line.endswith("the bootstrap made no step (iterations 536..536)")
    photos = BootstrapVerdict(Path("boot"), None, flat, _scores(15.29, 22.0), baseline=_scores(15.25, 22.0),
                              virtual_steps=0, iterations=(536, 700))
    assert verdict_line(photos) == ("held-out scarce views: about the same as the same-time baseline (+0.04 dB); no virtual "
                                    "step ran (the loop followed the outlook, or every view was left out), so this "
                                    "is stage I trained longer")
    below = BootstrapVerdict(Path("boot"), None, flat, _scores(15.08, 22.0), baseline=_scores(14.99, 22.0),
                             virtual_steps=30, iterations=(536, 800))
    assert verdict_line(below) == ("held-out scarce views: better by 0.09 dB than the same-time baseline; it scored below "
                                   "stage I (15.12 -> 15.08 dB)")


def test_a_baseline_of_another_length_is_refused_and_the_same_time_one_is_found(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    boot = write_summary(tmp_path / "run_bootstrap", run, False, 60.0, end=800, after=(15.08, 22.1))
    write_summary(tmp_path / "run_baseline", run, True, 66.0, after=(14.99, 22.4))
    write_summary(tmp_path / "other_baseline", tmp_path / "elsewhere", True, 60.0)   # another stage I: not named
    verdict = read_bootstrap_verdict(boot)
    assert verdict.baseline is None and verdict.seconds == 60.0
    assert verdict.refused == ((tmp_path / "run_baseline", "it ran 66 s, the bootstrap 60 s"),)
    write_summary(tmp_path / "run_baseline_2", run, True, 61.5, after=(15.02, 22.3))
    verdict = read_bootstrap_verdict(boot)
    assert verdict.baseline_dir == tmp_path / "run_baseline_2" and verdict.baseline["scarce_psnr"] == 15.02


def test_report_compares_a_bootstrap_only_with_its_same_time_baseline(tmp_path, capsys):
    from test_report import write_log

    run = tmp_path / "run"
    run.mkdir()
    boot = write_summary(tmp_path / "boot", run, False, 4.0, end=536, after=(15.26, 22.0))
    base = write_summary(tmp_path / "base", run, True, 66.0, after=(15.0, 22.4))
    for folder in (boot, base):
        write_log(folder, [{"wall_s": 1.0, "iteration": 536, "scarce_psnr": 15.1, "covered_psnr": 22.0}])
    assert main(["report", str(boot), str(base)]) == 0
    printed = capsys.readouterr().out
    assert "boot: held-out scarce views: better by 0.14 dB than stage I; no same-time baseline" in printed
    assert "base is not one: it ran 66 s, the bootstrap 4 s" in printed
    assert "made no step (iterations 536..536)" in printed and "than the same-time baseline" not in printed


@pytest.mark.slow
def test_eval_of_a_bootstrap_prints_its_verdict_against_the_same_time_baseline_only(tmp_path, capsys):
    from test_evaluate import known_gaussians, ring_cameras, write_run, write_scene

    scene_root = tmp_path / "scene"
    scene_root.mkdir()
    write_scene(scene_root, known_gaussians(), ring_cameras())
    write_run(tmp_path / "run", scene_root, known_gaussians())
    boot = tmp_path / "run_bootstrap"
    write_run(boot, scene_root, known_gaussians())
    write_summary(boot, tmp_path / "run", False, 60.0, end=800, after=(15.08, 22.1))
    write_summary(tmp_path / "run_baseline", tmp_path / "run", True, 66.0, after=(14.99, 22.4))
    assert main(["eval", str(boot)]) == 0
    printed = capsys.readouterr().out
    assert "repair verdict (the bootstrap's own evaluations): held-out scarce views: about the same as stage I" in printed
    assert "run_baseline is not one: it ran 66 s, the bootstrap 60 s" in printed
    assert "than the same-time baseline" not in printed
    write_summary(tmp_path / "run_baseline_2", tmp_path / "run", True, 61.0, after=(15.02, 22.3))
    assert main(["eval", str(boot), "--json"]) == 0
    verdict = json.loads(capsys.readouterr().out)["verdict"]
    assert verdict["same_time_baseline"] == str(tmp_path / "run_baseline_2")
    assert verdict["line"].startswith("held-out scarce views: better by 0.06 dB than the same-time baseline; it scored below "
                                      "stage I (15.12 -> 15.08 dB)")
    assert verdict["refused"] == [{"folder": str(tmp_path / "run_baseline"), "why": "it ran 66 s, the bootstrap 60 s"}]


def test_the_sentence_says_why_no_virtual_step_ran_as_the_summary_records_it(tmp_path):
    """A bootstrap of the statuette's flags said "no virtual step ran (the loop followed the
    outlook, or every view was left out)" when its summary said which: the outlook's "nothing to
    repair" had kept every step on the photos. The agreement gate leaving out every view is named
    too; a summary without rounds keeps the general words."""
    run = tmp_path / "run"
    outlook = {"outlook": {"verdict": "nothing to repair"},
               "rounds": [{"round": 1, "views": [], "deferred": "every step on the photos"}]}
    gated = {"rounds": [{"round": 1, "views": [{"supervised": False}, {"supervised": False}]}]}
    lines = {}
    for name, extra in (("outlook", outlook), ("gated", gated), ("plain", {})):
        folder = write_summary(tmp_path / name, run, False, 60.0, virtual_steps=0)
        data = json.loads((folder / "bootstrap" / "summary.json").read_text())
        (folder / "bootstrap" / "summary.json").write_text(json.dumps({**data, **extra}), encoding="utf-8")
        lines[name] = verdict_line(read_bootstrap_verdict(folder, folders=[]))
    assert ('no virtual step ran (the outlook said "nothing to repair", so every step went to the photos), so this '
            'is stage I trained longer') in lines["outlook"], lines["outlook"]
    assert ("no virtual step ran (the agreement gate left out all 2 virtual views: their warped photos agreed worse "
            "with each other than with the render)") in lines["gated"], lines["gated"]
    assert "(the loop followed the outlook, or every view was left out)" in lines["plain"], lines["plain"]
