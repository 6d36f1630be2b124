"""Run-folder plumbing: config validation, checkpoint files, frames, metrics log, CLI guards."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from inceptiongs.cli import main
from inceptiongs.errors import InputError
from inceptiongs.gaussians import Gaussians
from inceptiongs.runs.checkpoint import list_checkpoints, load_checkpoint, save_checkpoint
from inceptiongs.runs.config import LearningRates, TrainConfig, short_run_schedule
from inceptiongs.train.init_gaussians import gaussians_from_points, mean_neighbour_distance
from inceptiongs.train.optim import position_learning_rate
from inceptiongs.runs.metrics import append_metrics, truncate_metrics
from inceptiongs.runs.frames import to_normalized_frame, to_original_frame
from inceptiongs.train.step import supported_sh_degree


def test_config_round_trip_and_bad_files(tmp_path):
    config = TrainConfig(scene="/x", iterations=123, protocol="llff")
    config.save(tmp_path / "config.json")
    assert TrainConfig.load(tmp_path / "config.json") == config
    (tmp_path / "bad.json").write_text(json.dumps({"iterations": 5, "bogus": 1}))
    with pytest.raises(InputError, match="bad.json: unknown key 'bogus'"):
        TrainConfig.load(tmp_path / "bad.json")
    (tmp_path / "proto.json").write_text(json.dumps({"protocol": "random"}))
    with pytest.raises(InputError, match="proto.json: protocol must be one of"):
        TrainConfig.load(tmp_path / "proto.json")


def test_short_schedule_keeps_milestone_fractions():
    config = short_run_schedule(TrainConfig(iterations=3000))
    window = config.densification
    assert window.densify_until == 1500 and config.pgsr_terms.normal_from == 700
    assert window.densify_from == 100 and window.densify_every == 25
    assert config.pgsr_terms.multiview_from == 700 and config.sh.increase_every == 100
    assert window.prune_large_from == 800        # half-way through the densification window
    # No opacity reset within a run this short; a Gaussian budget that shrinks with the run.
    assert window.opacity_reset_every > config.iterations
    assert window.max_gaussians == 200_000
    assert short_run_schedule(TrainConfig(iterations=500)).densification.max_gaussians == 100_000
    longer = short_run_schedule(TrainConfig(iterations=12_000)).densification
    assert longer.opacity_reset_every == 3000 and longer.max_gaussians == 800_000
    assert short_run_schedule(TrainConfig(iterations=30_000)) == TrainConfig(iterations=30_000)


def test_position_lr_decays_log_linearly_and_scales_with_extent():
    config = TrainConfig(iterations=100, learning_rates=LearningRates(means=1e-3, means_final=1e-5))
    assert position_learning_rate(0, config, 2.0) == pytest.approx(2e-3)
    assert position_learning_rate(50, config, 2.0) == pytest.approx(2e-4)
    assert position_learning_rate(100, config, 2.0) == pytest.approx(2e-5)


def test_checkpoints_are_pruned_and_partial_files_ignored(tmp_path):
    for step in (5, 10, 15):
        save_checkpoint(tmp_path, step, {"iteration": step, "params": {}}, keep=2)
    (tmp_path / "checkpoints" / ".step_0000020.pt.abc.tmp").write_bytes(b"partial")
    assert [s for s, _ in list_checkpoints(tmp_path)] == [10, 15]
    newest = list_checkpoints(tmp_path)[-1][1]
    assert torch.load(newest, weights_only=True)["iteration"] == 15
    # Data only, but not all a resume needs: refused in one line (a foreign or crafted file).
    with pytest.raises(InputError, match="step_0000015.pt: not an InceptionGS training checkpoint"):
        load_checkpoint(newest)
    broken = tmp_path / "checkpoints" / "step_0000099.pt"
    broken.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="step_0000099.pt: not a readable checkpoint"):
        load_checkpoint(broken)


def test_frames_round_trip_and_match_the_point_transform():
    class Norm:  # the contract's two fields only: exercises the fallback transform
        center = np.array([1.0, -2.0, 3.0])
        scale = 0.25
    g = Gaussians(torch.randn(4, 3, dtype=torch.float64), torch.randn(4, 3, dtype=torch.float64),
                  torch.randn(4, 4, dtype=torch.float64), torch.randn(4, dtype=torch.float64),
                  torch.randn(4, 1, 3, dtype=torch.float64))
    original = to_original_frame(g, Norm())
    np.testing.assert_allclose(original.means.numpy(), g.means.numpy() / 0.25 + Norm.center)
    np.testing.assert_allclose(original.log_scales.numpy(), g.log_scales.numpy() - math.log(0.25))
    back = to_normalized_frame(original, Norm())
    torch.testing.assert_close(back.means, g.means)
    torch.testing.assert_close(back.log_scales, g.log_scales)


def test_metrics_truncation_drops_later_and_torn_lines(tmp_path):
    for i in range(1, 6):
        append_metrics(tmp_path, {"iteration": i})
    with open(tmp_path / "metrics.jsonl", "a") as handle:
        handle.write('{"iteration": 6, "lo')
    truncate_metrics(tmp_path, 3)
    lines = (tmp_path / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line)["iteration"] for line in lines] == [1, 2, 3]


def test_initial_scales_are_neighbour_distances():
    points = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 2.0, 0], [0, 0, 4.0]])
    expected = torch.tensor([(1 + 2 + 4) / 3, (1 + np.sqrt(5) + np.sqrt(17)) / 3,
                             (2 + np.sqrt(5) + np.sqrt(20)) / 3, (4 + np.sqrt(17) + np.sqrt(20)) / 3])
    torch.testing.assert_close(mean_neighbour_distance(torch.tensor(points)), expected.double())
    g = gaussians_from_points(points, np.full((4, 3), 255, np.uint8), sh_degree=2)
    assert g.sh.shape == (4, 9, 3) and torch.all(g.sh[:, 1:] == 0)
    assert torch.allclose(torch.exp(g.log_scales[:, 0]), expected.float())


def test_sh_degree_follows_the_view_count():
    assert [supported_sh_degree(n, 3) for n in (2, 5, 10, 30)] == [0, 1, 2, 3]
    assert supported_sh_degree(30, 1) == 1


def test_cli_refuses_to_overwrite_a_run_and_reports_missing_scene(tmp_path, capsys):
    assert main(["train", str(tmp_path / "nowhere")]) == 2
    assert "nowhere: scene folder does not exist" in capsys.readouterr().err
    scene = tmp_path / "scene"
    scene.mkdir()
    run = tmp_path / "run"
    TrainConfig(scene=str(scene)).save(run / "config.json")
    assert main(["train", str(scene), "--out", str(run)]) == 2
    assert "already holds a run" in capsys.readouterr().err
