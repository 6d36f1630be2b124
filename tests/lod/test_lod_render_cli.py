"""``inceptiongs render --lod / --lod-budget``: the cut before rendering, off by default."""

from __future__ import annotations

import numpy as np
import pytest

from inceptiongs.camera import Camera, look_at, write_camera_json
from inceptiongs.cli import main
from inceptiongs.io.cache import cache_root
from inceptiongs.io.ply import write_ply

from lod_cases import random_gaussians


@pytest.fixture
def model_and_camera(tmp_path):
    g = random_gaussians(800, seed=41, degree=0)
    g.log_scales.sub_(1.0)
    write_ply(g, tmp_path / "model.ply")
    camera = Camera("cli", 64, 48, 60.0, 60.0, 32.0, 24.0, look_at(np.array([0.0, -2.0, -8.0]), np.zeros(3)))
    write_camera_json(camera, tmp_path / "cam.json")
    return tmp_path / "model.ply", tmp_path / "cam.json"


def render(model, camera, out, *extra) -> np.ndarray:
    assert main(["render", str(model), "--camera", str(camera), "--backend", "torch", "--device", "cpu",
                 "--out", str(out), *extra]) == 0
    return np.load(out)


def test_lod_zero_matches_the_exact_render_and_coarse_lod_differs(model_and_camera, tmp_path, capsys):
    model, camera = model_and_camera
    exact = render(model, camera, tmp_path / "exact.npy")
    assert "lod:" not in capsys.readouterr().err          # off by default: no hierarchy
    finest = render(model, camera, tmp_path / "finest.npy", "--lod", "0")
    assert "hierarchy built" in capsys.readouterr().err
    np.testing.assert_allclose(finest, exact, atol=1e-4)
    coarse = render(model, camera, tmp_path / "coarse.npy", "--lod", "1e9")
    note = capsys.readouterr().err
    assert "lod: 1 of 800 splats" in note and "from the cache" in note
    assert np.abs(coarse - exact).max() > 0.05
    assert list((cache_root() / "lod").glob("*.npz")) and not list(model.parent.glob("*.npz"))


def test_lod_budget_draws_at_most_the_budget(model_and_camera, tmp_path, capsys):
    model, camera = model_and_camera
    render(model, camera, tmp_path / "budget.npy", "--lod-budget", "50")
    drawn = int(capsys.readouterr().err.split("lod: ")[1].split(" of ")[0])
    assert 1 <= drawn <= 50


@pytest.mark.parametrize("flags", [["--lod", "-1"], ["--lod", "nan"], ["--lod-budget", "-5"]])
def test_bad_lod_values_are_one_line_errors(model_and_camera, tmp_path, flags, capsys):
    model, camera = model_and_camera
    code = main(["render", str(model), "--camera", str(camera), "--backend", "torch", "--out",
                 str(tmp_path / "x.npy"), *flags])
    assert code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not (tmp_path / "x.npy").exists()


def test_lod_and_lod_budget_exclude_each_other(model_and_camera, tmp_path):
    model, camera = model_and_camera
    # argparse's refusal: one line, status 2
    assert main(["render", str(model), "--camera", str(camera), "--out", str(tmp_path / "x.npy"),
                 "--lod", "2", "--lod-budget", "10"]) == 2
