"""`inceptiongs eval RUN --generated`: the prior's generated images scored next to the stage-I
renders on the held-out views, images render | generated | photo; and the prior log that
`inceptiongs report` plots."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from inceptiongs.cli import main
from inceptiongs.rasterizer.interface import render_rgb
from inceptiongs.evaluation.generated import evaluate_generated_run, photo_of, score
from inceptiongs.evaluation.metrics import psnr

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def run_with_prior(tmp_path_factory):
    from prior_cases import make_stand_in_run

    run = make_stand_in_run(tmp_path_factory.mktemp("eval_generated"), protocol="unstructured")
    assert main(["prior", str(run), "--steps", "3", "--patch-size", "16", "--batch-size", "2",
                 "--eval-every-minutes", "1000", "--eval-steps", "1", "--eval-views", "1"]) == 0
    return run


def test_prior_log_has_training_seconds_and_generated_scores(run_with_prior):
    records = [json.loads(line) for line in (run_with_prior / "prior" / "metrics.jsonl").read_text().splitlines()]
    evaluations = [r for r in records if "generated" in r]
    # at step 0 and at the end (the interval of 1000 minutes is never reached in between)
    assert [r["step"] for r in evaluations] == [0, 3]
    assert evaluations[-1]["train_s"] > evaluations[0]["train_s"] == 0.0
    for record in evaluations:
        assert set(record["generated"]) == {"scarce", "covered", "all"}  # one view of each group
        assert 0.0 < record["generated"]["all"]["psnr"] < 100.0
        assert record["render"]["all"] == evaluations[0]["render"]["all"]  # same Gaussians


def test_eval_generated_scores_and_side_by_side_images(run_with_prior, capsys):
    assert main(["eval", str(run_with_prior), "--generated", "--ddim-steps", "1,2", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    summary = json.loads((run_with_prior / "eval" / "generated.json").read_text())
    assert printed["generated"] == summary
    assert [entry["ddim_steps"] for entry in summary["by_steps"]] == [1, 2]
    assert summary["prior"]["backend"] == "tiny" and summary["prior"]["step"] == 3

    from inceptiongs.runs.load import load_run
    gaussians, scene, _ = load_run(run_with_prior)
    views = summary["views"]
    assert {v["group"] for v in views} == {"scarce", "covered"}
    for view in views:
        # the render's scores are recomputed independently here
        camera = scene.cameras[view["index"]]
        photo = photo_of(scene, view["index"])
        rendered = render_rgb(gaussians, camera)
        assert view["render"]["psnr"] == pytest.approx(float(psnr(rendered, photo)), abs=1e-4)
        panels = cv2.imread(str(run_with_prior / view["image"]))[..., ::-1]
        assert panels.shape == (camera.height, 3 * camera.width, 3)
        w = camera.width
        # left panel: the render, right panel: the photo; the middle one scores as recorded
        assert np.abs(panels[:, :w] / 255.0 - rendered.numpy()).max() <= 1 / 255 + 1e-6
        assert np.abs(panels[:, 2 * w:] / 255.0 - photo.numpy()).max() <= 1 / 255 + 1e-6
        generated = torch.as_tensor(panels[:, w:2 * w] / 255.0, dtype=torch.float32)
        assert score(generated, photo)["psnr"] == pytest.approx(view["generated"]["psnr"], abs=0.1)
    groups = summary["by_steps"][0]["groups"]
    scarce = [v for v in views if v["group"] == "scarce"]
    assert groups["scarce"]["views"] == len(scarce)
    assert groups["scarce"]["generated"]["ssim"] == pytest.approx(np.mean([v["generated"]["ssim"] for v in scarce]))

    assert main(["eval", str(run_with_prior), "--generated", "--ddim-steps", "0"]) == 2
    assert main(["eval", str(run_with_prior), "--generated", "--ddim-steps", "x"]) == 2


def test_eval_generated_takes_the_sampling_start(run_with_prior):
    # The default samples as the prior's config says (from its render, noised to 0.3 T); --init
    # and --start score another start with the same weights, and say so in generated.json.
    default = evaluate_generated_run(run_with_prior, (1,), progress=False)
    assert default["sampling"] == {"start": 0.3, "init": "render"}
    hint = evaluate_generated_run(run_with_prior, (1,), progress=False, start=0.5, init="hint")
    assert hint["sampling"] == {"start": 0.5, "init": "hint"}
    assert hint["views"][0]["generated"] != default["views"][0]["generated"]
    assert hint["views"][0]["render"] == default["views"][0]["render"]
    assert main(["eval", str(run_with_prior), "--generated", "--ddim-steps", "1", "--start", "0"]) == 2


def test_eval_generated_without_a_prior_is_an_input_error(run_with_prior, tmp_path):
    import shutil

    from inceptiongs.errors import InputError

    run = tmp_path / "run"
    run.mkdir()
    for name in ("config.json", "split.json", "model.ply"):
        shutil.copy(run_with_prior / name, run / name)
    with pytest.raises(InputError, match="prior.pt"):
        evaluate_generated_run(run, (2,), progress=False)
