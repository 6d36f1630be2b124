"""`inceptiongs demo`: the whole pipeline end to end on the tiny courtyard (a few iterations)."""

from __future__ import annotations

import json

import pytest

from inceptiongs.cli import main
from inceptiongs.commands.demo import flagged_view_rows, metrics_table, time_curves, verdict
from inceptiongs.evaluation.protocols import Split


@pytest.mark.slow
def test_demo_runs_stage_one_coverage_bootstrap_baseline_and_report(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", str(out), "--size", "tiny", "--iterations", "4", "--bootstrap-iterations", "4",
                 "--bootstrap-minutes", "0.2", "--prior-steps", "2", "--ddim-steps", "2"]) == 0
    meta = json.loads((out / "scene" / "demo_scene.json").read_text())
    assert meta["scene"] == "courtyard"
    for run in ("run", "run_bootstrap", "run_baseline"):
        for name in ("config.json", "split.json", "model.ply", "metrics.jsonl", "eval/eval.json"):
            assert (out / run / name).is_file(), f"{run}/{name}"
    for name in ("report.png", "target.png", "coverage.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    assert list((out / "run_bootstrap" / "bootstrap" / "views").glob("*.png"))

    split = Split.load(out / "run" / "split.json")
    names = split.view_names
    # The scarce group is the courtyard's designed thin region, j* among it.
    assert split.protocol == "unstructured" and split.target_view in split.scarce_test
    assert {names[i] for i in split.scarce_cluster} == set(meta["scarce_cameras"])
    for run in ("run_bootstrap", "run_baseline"):
        assert Split.load(out / run / "split.json").test == split.test
    evals = [json.loads((out / run / "eval" / "eval.json").read_text())
             for run in ("run", "run_baseline", "run_bootstrap")]
    report = (out / "report.md").read_text()
    # The three-way table's rows are the eval.json numbers of the three runs.
    for group in ("scarce", "covered", "all"):
        a, b, c = (e["groups"][group] for e in evals)
        assert (f"| {group} | {a['views']} | {a['psnr']:.2f} / {a['ssim']:.4f} | {b['psnr']:.2f} / {b['ssim']:.4f} | "
                f"{c['psnr']:.2f} / {c['ssim']:.4f} | {c['psnr'] - b['psnr']:+.2f} | {c['psnr'] - a['psnr']:+.2f} |") in report
    assert verdict(*evals) in report and "same-time baseline" in report
    # j*'s own scores after each run, and what stage I's curve said before the bootstrap started.
    assert "\n".join(flagged_view_rows(split.target_view, *evals)) in report
    outlook = json.loads((out / "run_bootstrap" / "bootstrap" / "summary.json").read_text())["outlook"]
    assert f"Before the bootstrap ran, stage I's curve said: *{outlook['line']}*." in report
    assert "target.png" in report and "coverage.png" in report and "unavailable" in report
    # The baseline ran for (about) the bootstrap's time, starting from stage I's iteration.
    boot_records = [json.loads(line) for line in (out / "run_bootstrap" / "metrics.jsonl").read_text().splitlines()]
    base_records = [json.loads(line) for line in (out / "run_baseline" / "metrics.jsonl").read_text().splitlines()]
    assert base_records[0]["iteration"] == boot_records[0]["iteration"]
    assert base_records[-1]["wall_s"] >= 0.8 * boot_records[-1]["wall_s"]
    printed = capsys.readouterr().out
    assert "[7/7]" in printed and "left)" in printed and "PSNR" in printed
    assert printed.rstrip().splitlines()[-1].strip() == f"inceptiongs-viewer {out / 'run_bootstrap'}"


def _eval(scarce: float, covered: float) -> dict:
    group = lambda psnr: {"views": 2, "psnr": psnr, "ssim": 0.5}  # noqa: E731
    return {"groups": {"scarce": group(scarce), "covered": group(covered), "all": group((scarce + covered) / 2)}}


def test_the_verdict_and_table_compare_the_bootstrap_with_the_baseline():
    stage1, baseline = _eval(14.0, 20.0), _eval(15.0, 21.0)
    assert verdict(stage1, baseline, _eval(15.5, 20.8)).startswith("The bootstrap beat the same-time baseline "
                                                                    "on the scarce views by +0.50 dB")
    lost = verdict(stage1, baseline, _eval(14.5, 21.0))
    assert "did NOT beat" in lost and "-0.50 dB" in lost
    # A baseline of another length is named and the bootstrap is not judged against it.
    refused = verdict(stage1, baseline, _eval(15.5, 20.8), "it ran 66 s, the bootstrap 4 s")
    assert "not the bootstrap's same-time baseline (it ran 66 s, the bootstrap 4 s)" in refused
    assert "beat" not in refused
    rows = metrics_table(stage1, baseline, _eval(14.5, 21.0))
    assert rows[2] == "| scarce | 2 | 14.00 / 0.5000 | 15.00 / 0.5000 | 14.50 / 0.5000 | -0.50 | +0.50 |"


def test_the_flagged_view_row_scores_j_star_after_each_run():
    def with_view(result: dict, psnr: float) -> dict:
        return {**result, "views": [{"index": 3, "name": "003.png", "psnr": psnr, "ssim": 0.25},
                                    {"index": 4, "name": "004.png", "psnr": 99.0, "ssim": 0.9}]}

    runs = with_view(_eval(14.0, 20.0), 12.0), with_view(_eval(15.0, 21.0), 12.5), with_view(_eval(15.5, 20.8), 13.25)
    rows = flagged_view_rows(3, *runs)
    assert rows[2] == "| `003.png` | 12.00 / 0.2500 | 12.50 / 0.2500 | 13.25 / 0.2500 | +0.75 | +1.25 |"
    assert "not a held-out view" in flagged_view_rows(7, *runs)[0]


def test_time_curves_start_the_later_runs_where_stage_one_ended():
    stage1 = [{"iteration": 0, "wall_s": 0.0, "scarce_psnr": 10.0}, {"iteration": 50, "wall_s": 100.0, "scarce_psnr": 12.0}]
    later = [{"iteration": 50, "wall_s": 0.5, "scarce_psnr": 12.0}, {"iteration": 60, "wall_s": 30.0, "scarce_psnr": 13.0}]
    curves = time_curves(stage1, {"bootstrap": later})
    assert curves["stage I"]["scarce"] == [(0.0, 10.0), (100.0, 12.0)]
    assert curves["bootstrap"]["scarce"] == [(100.5, 12.0), (130.0, 13.0)]
