"""Report: scores come from the right log rows; the table and figure are written."""

from __future__ import annotations

import json

import pytest

from inceptiongs.cli import main
from inceptiongs.errors import InputError
from inceptiongs.evaluation.report import eval_series, make_report, read_metrics, score_at, scores_of


def write_log(run_dir, records, torn_tail=False):
    run_dir.mkdir(parents=True, exist_ok=True)
    text = "".join(json.dumps(r) + "\n" for r in records)
    if torn_tail:
        text += '{"wall_s": 9'
    (run_dir / "metrics.jsonl").write_text(text)


def training_records(evals):
    """Loss lines every 10 s plus evaluation lines at the given (wall_s, iteration, scarce, covered)."""
    records = [{"wall_s": float(t), "iteration": t * 3, "loss": 0.5, "ssim": 0.9, "num_gaussians": 100}
               for t in range(0, 1300, 10)]
    for wall, iteration, scarce, covered in evals:
        records.append({"wall_s": wall, "iteration": iteration, "scarce_psnr": scarce, "scarce_ssim": scarce / 100,
                        "covered_psnr": covered, "covered_ssim": covered / 100})
    return sorted(records, key=lambda r: r["wall_s"])


def test_scores_of_reads_flat_and_nested_keys_but_not_losses():
    assert scores_of({"scarce_psnr": 20.0, "covered_ssim": 0.8, "loss_ssim": 0.1, "train_psnr": 30.0,
                      "ssim": 0.5}) == {"scarce": {"psnr": 20.0}, "covered": {"ssim": 0.8}}
    assert scores_of({"eval": {"scarce": {"psnr": 21.0, "ssim": 0.7}}, "test/psnr": 19.0}) == \
        {"scarce": {"psnr": 21.0, "ssim": 0.7}, "test": {"psnr": 19.0}}


def test_table_picks_last_evaluation_at_or_before_each_time(tmp_path):
    evals = [(50.0, 150, 10.0, 20.0), (119.0, 357, 11.0, 21.0), (130.0, 390, 12.0, 22.0),
             (290.0, 870, 13.0, 23.0), (600.0, 1800, 14.0, 24.0)]
    write_log(tmp_path / "runA", training_records(evals), torn_tail=True)
    series = eval_series(read_metrics(tmp_path / "runA" / "metrics.jsonl"))
    assert list(series) == ["scarce", "covered"]
    assert score_at(series["covered"], 120.0).psnr == 21.0       # 119 s row, not the 130 s one
    assert score_at(series["covered"], 600.0).psnr == 24.0       # exactly at 10 min counts
    assert score_at(series["scarce"], 40.0) is None
    table = make_report([tmp_path / "runA"], None)
    rows = {line.split()[1]: line.split()[2:] for line in table.splitlines()[1:] if line.startswith("runA")}
    # the log runs to 1290 s: at 20 min the last evaluation is still the 600 s one
    assert rows["scarce"] == ["10.00/0.100", "11.00/0.110", "13.00/0.130", "14.00/0.140", "14.00/0.140",
                              "14.00/0.140", "(600)"]
    assert rows["covered"] == ["20.00/0.200", "21.00/0.210", "23.00/0.230", "24.00/0.240", "24.00/0.240",
                               "24.00/0.240", "(600)"]


def test_same_iteration_evaluated_twice_is_one_point(tmp_path):
    records = [{"wall_s": 10.0, "iteration": 30, "all_psnr": 12.0},
               {"wall_s": 14.0, "iteration": 30, "all_psnr": 12.0},
               {"wall_s": 20.0, "iteration": 60, "all_psnr": 13.0}]
    series = eval_series(records)
    assert [(p.wall_s, p.iteration) for p in series["all"]] == [(10.0, 30), (20.0, 60)]


def test_table_dashes_where_the_run_never_got(tmp_path):
    records = [r for r in training_records([(50.0, 150, 10.0, 20.0), (200.0, 600, 12.0, 22.0)])
               if r["wall_s"] <= 250.0]
    write_log(tmp_path / "short", records)
    line = [l for l in make_report([tmp_path / "short"], None).splitlines() if " covered " in l][0]
    assert line.split()[2:] == ["20.00/0.200", "20.00/0.200", "-", "-", "-", "22.00/0.220", "(200)"]


def test_cli_writes_figure_for_several_runs(tmp_path, capsys):
    write_log(tmp_path / "a", training_records([(30.0, 90, 15.0, 25.0), (90.0, 270, 16.0, 26.0)]))
    write_log(tmp_path / "b", training_records([(70.0, 210, 17.0, 27.0)]))
    out = tmp_path / "fig" / "report.png"
    assert main(["report", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 5000
    printed = capsys.readouterr().out
    assert "25.00/0.250" in printed and "27.00/0.270" in printed


def test_bad_logs_are_input_errors(tmp_path, capsys):
    run = tmp_path / "bad"
    run.mkdir()
    (run / "metrics.jsonl").write_text('{"wall_s": 1}\nnot json\n{"wall_s": 2}\n')
    with pytest.raises(InputError, match="line 2"):
        read_metrics(run / "metrics.jsonl")
    assert main(["report", str(tmp_path / "missing"), "--out", str(tmp_path / "x.png")]) == 2
    assert "missing" in capsys.readouterr().err
    write_log(tmp_path / "nowall", [{"iteration": 3, "covered_psnr": 20.0}])
    with pytest.raises(InputError, match="wall_s"):
        make_report([tmp_path / "nowall"], None)
