"""`inceptiongs report` on the prior's logs: generated quality against training time and DDIM steps."""

from __future__ import annotations

import json

import cv2

from inceptiongs.cli import main
from inceptiongs.evaluation.report_prior import generated_by_steps, prior_evaluations, prior_figure_path


def write_prior_logs(run, with_stage1=True):
    (run / "prior").mkdir(parents=True)
    (run / "eval").mkdir()
    scores = lambda p, s: {"scarce": {"psnr": p, "ssim": s}, "covered": {"psnr": p + 5, "ssim": s + 0.1}}  # noqa: E731
    records = [{"step": 40, "train_s": 120.0, "loss": 0.2, "generated": scores(14.0, 0.41), "render": scores(12.0, 0.35)},
               {"step": 20, "train_s": 60.0, "loss": 0.3},
               {"step": 0, "train_s": 0.0, "generated": scores(6.0, 0.05), "render": scores(12.0, 0.35)}]
    (run / "prior" / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records) + '{"torn')
    by_steps = [{"ddim_steps": 20, "seconds_per_image": 9.0,
                 "groups": {g: {"views": 2, "render": v, "generated": {"psnr": v["psnr"] + 1, "ssim": 0.5}}
                            for g, v in scores(12.0, 0.35).items()}},
                {"ddim_steps": 5, "seconds_per_image": 2.5,
                 "groups": {g: {"views": 2, "render": v, "generated": {"psnr": v["psnr"] - 1, "ssim": 0.3}}
                            for g, v in scores(12.0, 0.35).items()}}]
    (run / "eval" / "generated.json").write_text(json.dumps({"by_steps": by_steps}))
    if with_stage1:
        (run / "metrics.jsonl").write_text(json.dumps({"iteration": 0, "wall_s": 0.0, "all_psnr": 10.0}) + "\n")


def test_readers_sort_and_skip_non_evaluations(tmp_path):
    write_prior_logs(tmp_path / "run")
    assert [r["step"] for r in prior_evaluations(tmp_path / "run")] == [0, 40]
    assert [e["ddim_steps"] for e in generated_by_steps(tmp_path / "run")] == [5, 20]


def test_report_adds_the_prior_figure_and_table(tmp_path, capsys):
    run = tmp_path / "run"
    write_prior_logs(run)
    out = tmp_path / "fig.png"
    assert main(["report", str(run), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "14.00/0.410 (12.00/0.350)" in text        # generated (render) at 120 s, scarce
    assert "13.00/0.500 (12.00/0.350)" in text        # 20 DDIM steps, scarce
    assert cv2.imread(str(out)) is not None
    figure = cv2.imread(str(prior_figure_path(out)))
    assert figure is not None and figure.shape[0] > 400

    only = tmp_path / "only_prior.png"
    assert main(["report", str(run), "--prior", "--out", str(only)]) == 0
    assert cv2.imread(str(only)) is not None


def test_prior_report_errors(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["report", str(tmp_path / "empty"), "--prior"]) == 2
    run = tmp_path / "bad"
    (run / "prior").mkdir(parents=True)
    (run / "prior" / "metrics.jsonl").write_text(json.dumps({"step": 1, "generated": {}}) + "\n" + "{}\n")
    assert main(["report", str(run), "--prior"]) == 2
    assert "train_s" in capsys.readouterr().err
