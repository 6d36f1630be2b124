"""Photos the model cannot fit are named: per-view MSE kept from the training renders, reported
when a view lies far below the median training-view PSNR."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
import torch

import train_cases as tc
from inceptiongs.rasterizer.rasterize import render
from inceptiongs.train.view_fit import (PSNR_CAP_DB, VIEW_FIT_FILE, poorly_fit, summary_line, view_fit_report,
                                        view_psnr)


def test_psnr_of_a_perfect_render_is_capped_and_finite():
    psnr = view_psnr({0: 0.0, 1: 1e-2, 2: 1.0})
    assert psnr[0] == PSNR_CAP_DB and math.isclose(psnr[1], 20.0) and psnr[2] == 0.0
    json.dumps(view_fit_report({0: 0.0, 1: 1e-2, 2: 1e-2}, {0: "a", 1: "b", 2: "c"}))  # no inf in the JSON


def test_only_views_far_below_the_median_are_reported_worst_first():
    psnr = {0: 25.0, 1: 26.0, 2: 24.5, 3: 19.9, 4: 25.5, 5: 12.0, 6: 20.6}
    assert poorly_fit(psnr, margin_db=5.0) == [5]          # median 24.5: 19.9 is 4.6 below
    assert poorly_fit(psnr, margin_db=4.0) == [5, 3]       # 20.6 is only 3.9 below
    assert poorly_fit(psnr, margin_db=3.0) == [5, 3, 6]
    assert poorly_fit({0: 30.0, 1: 30.0, 2: 30.0}) == []
    assert poorly_fit({0: 30.0, 1: 5.0}) == []            # two views: no median to speak of


def test_summary_names_the_worst_views_and_is_silent_without_any():
    names = {i: f"IMG_{i:03d}.JPG" for i in range(20)}
    mse = {i: 10 ** (-2.5) for i in range(20)}           # 25 dB everywhere
    assert summary_line(view_fit_report(mse, names), "run/view_fit.json") is None
    for bad, db in ((3, 12.0), (7, 15.0), (9, 10.0), (0, 11.0), (1, 13.0), (2, 14.0), (4, 16.0)):
        mse[bad] = 10 ** (-db / 10)
    report = view_fit_report(mse, names)
    assert [v["index"] for v in report["views"]] == list(range(20))
    assert sum(v["poorly_fit"] for v in report["views"]) == 7
    line = summary_line(report, "run/view_fit.json")
    assert line.startswith("poorly fit photos: 7 of 20 training views")
    assert "IMG_009.JPG 10.0 dB, IMG_000.JPG 11.0 dB" in line and "and 2 more" in line and "run/view_fit.json" in line


@pytest.mark.slow
def test_a_photo_that_disagrees_with_the_others_is_reported_after_training():
    """Eight ring photos of a ball; in one, the ball stands 0.8 units higher (an object moved
    between photos). Training keeps each view's last MSE; only that photo ends far below the
    median. (A colour change alone is not a test: view-dependent colour can fit one view.)"""
    cameras = tc.ring_cameras(8)
    truth = tc.ball(300)
    images = tc.photos(truth, cameras)
    moved = dataclasses.replace(truth, means=truth.means + torch.tensor([0.0, 0.0, 0.8]))
    with torch.no_grad():
        images[5] = render(moved, cameras[5])["rgb"].clamp(0, 1)
    cfg = tc.config(iterations=120, free_space={"enabled": False})
    data, state = tc.setup(tc.ball(300, seed=1), cameras, images, cfg, truth.means.numpy())
    tc.run_steps(state, data, cfg, 120)
    assert sorted(state.view_mse) == list(range(8))       # every view rendered at least once
    psnr = view_psnr(state.view_mse)
    assert poorly_fit(psnr) == [5], psnr


def test_exclude_photos_takes_names_a_list_file_or_a_runs_report(tmp_path):
    from inceptiongs.commands.train import photos_to_exclude
    from inceptiongs.errors import InputError

    assert photos_to_exclude(None) == [] and photos_to_exclude("a.jpg, b.jpg") == ["a.jpg", "b.jpg"]
    many = ",".join(f"DSCF{5605 + i}.JPG" for i in range(108))   # longer than a file name may be
    assert len(photos_to_exclude(many)) == 108
    (tmp_path / "list.txt").write_text("a.jpg\nb.jpg\n\n")
    assert photos_to_exclude(str(tmp_path / "list.txt")) == ["a.jpg", "b.jpg"]
    run = tmp_path / "run"
    run.mkdir()
    with pytest.raises(InputError, match="no view_fit.json"):
        photos_to_exclude(str(run))
    report = view_fit_report({0: 1e-3, 1: 1e-3, 2: 0.5, 3: 1e-3, 4: 0.2}, {i: f"p{i}.jpg" for i in range(5)})
    (run / VIEW_FIT_FILE).write_text(json.dumps(report))
    assert photos_to_exclude(str(run)) == ["p2.jpg", "p4.jpg"]   # the poorly fit ones, worst first
