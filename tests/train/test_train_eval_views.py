"""Training scores at most ``output.eval_views`` held-out views per group on its cadence: a
capture that holds out hundreds of views does not render them all before its first step."""

from __future__ import annotations

import json

from demo_cases import copy_of_demo_scene
from inceptiongs.evaluation import scoring
from inceptiongs.evaluation.protocols import Split
from inceptiongs.runs.config import Output, TrainConfig
from inceptiongs.train.trainer import train


def test_training_scores_at_most_eval_views_per_group(tmp_path, monkeypatch):
    scene = copy_of_demo_scene(tmp_path / "scene")
    scored = []
    real = scoring.evaluate_views

    def counting(gaussians, scene_, split, **kwargs):
        scored.append((len(split.scarce_test), len(split.covered_test)))
        return real(gaussians, scene_, split, **kwargs)

    monkeypatch.setattr(scoring, "evaluate_views", counting)
    config = TrainConfig(scene=str(scene), downscale=8, protocol="llff", seed=0, iterations=2,
                         output=Output(log_every=1, eval_every=1, eval_views=2))
    train(config, tmp_path / "run", progress=False)
    split = Split.load(tmp_path / "run" / "split.json")
    assert len(split.covered_test) > 2                                  # more held out than scored
    assert scored and all(scarce <= 2 and covered == 2 for scarce, covered in scored)
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in records if "covered_psnr" in r] == [0, 1, 2]
