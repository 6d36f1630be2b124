"""``inceptiongs convert IN OUT [--check]``: every format to every other, the measured error
printed, notes for what a format drops, one-line errors for bad names and files; and the other
commands (info, render) opening every format."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from inceptiongs.cli import main
from inceptiongs.io.models import read_model, write_model
from model_cases import random_model

FORMATS = ["ply", "compressed.ply", "splat", "spz"]


@pytest.mark.parametrize("target", FORMATS)
def test_convert_writes_the_format_and_check_prints_the_error(tmp_path, capsys, target):
    source = tmp_path / "in.spz"
    write_model(source, random_model(300, 2))
    out = tmp_path / f"out.{target}"
    assert main(["convert", str(source), str(out), "--check"]) == 0
    captured = capsys.readouterr()
    assert out.is_file()
    first = captured.out.splitlines()[0]
    assert first.startswith(f"{source} (spz, 300 splats, SH degree 2) -> {out} (")
    figures = dict(re.findall(r"^\s+(\w[\w ]*?)\s+max (\S+)", captured.out, re.M))
    assert set(figures) == {"positions", "colour", "opacity", "log scales", "rotations", "SH rest"}
    if target == "ply":  # the .spz's values, written as float32: nothing lost on the way out
        assert all(float(value) == 0 for key, value in figures.items() if key != "rotations")
    elif target == "spz":  # decoded SPZ values are exactly on SPZ's grid: re-encoding keeps them
        assert float(figures["opacity"]) == 0 and float(figures["colour"]) < 0.01
    else:
        assert float(figures["opacity"]) > 0
    if target == "splat":
        assert "SH degree 2 written as degree 0" in captured.err
    back = read_model(out)
    assert len(back) == 300 and back.sh_degree == (0 if target == "splat" else 2)


def test_convert_through_every_format_keeps_the_model_close(tmp_path, capsys):
    """ply -> spz -> compressed.ply -> splat -> ply: the errors add up, no more."""
    model = random_model(257, 0)
    write_model(tmp_path / "a.ply", model)
    chain = ["a.ply", "b.spz", "c.compressed.ply", "d.splat", "e.ply"]
    for here, there in zip(chain, chain[1:]):
        assert main(["convert", str(tmp_path / here), str(tmp_path / there)]) == 0
    end = read_model(tmp_path / "e.ply")
    # Match splats by position (the compressed PLY reordered them).
    a, b = model.means.numpy(), end.means.numpy()
    nearest = ((b[:, None] - a[None]) ** 2).sum(-1).argmin(1)
    assert len(set(nearest.tolist())) == 257
    start = model.subset(torch.as_tensor(nearest))
    assert np.abs(start.means.numpy() - b).max() < 1e-3 * np.ptp(a, axis=0).max()
    opacity = lambda g: torch.sigmoid(g.opacity_logits).numpy()  # noqa: E731
    assert np.abs(opacity(start) - opacity(end)).max() < 3 / 255


@pytest.mark.parametrize("args, message", [
    (["IN", "out.txt"], "out.txt: not a model file name"),
    (["missing.spz", "out.ply"], "missing.spz: model file does not exist"),
    (["garbage.spz", "out.ply"], "garbage.spz: not an SPZ file"),
    (["IN", "no_folder_file/x/out.spz"], None),
])
def test_convert_errors_are_one_line_with_status_2(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    write_model(tmp_path / "in.ply", random_model(10, 0))
    (tmp_path / "garbage.spz").write_bytes(b"not a splat at all" * 10)
    (tmp_path / "no_folder_file").write_text("a file where a folder is needed")
    args = ["in.ply" if a == "IN" else a for a in args]
    assert main(["convert", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: ")
    assert (message or "cannot write") in err
    assert not (tmp_path / "out.ply").exists()


def test_info_and_render_open_every_format(tmp_path, capsys):
    model = random_model(64, 1)
    camera = tmp_path / "cam.json"
    camera.write_text('{"width": 24, "height": 16, "fx": 20, "fy": 20, "cx": 12, "cy": 8, "world_to_camera": '
                      '[[1,0,0,-10],[0,1,0,2],[0,0,1,12],[0,0,0,1]]}')
    for suffix in FORMATS:
        path = tmp_path / f"m.{suffix}"
        write_model(path, model)
        assert main(["info", str(path)]) == 0
        out = capsys.readouterr().out
        assert "64 Gaussians" in out and ("compressed-ply model" in out) == (suffix == "compressed.ply")
        png = tmp_path / f"m_{suffix}.png"
        assert main(["render", str(path), "--camera", str(camera), "--backend", "torch", "--device", "cpu",
                     "--out", str(png)]) == 0
        assert png.stat().st_size > 0
