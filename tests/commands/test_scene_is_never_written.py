"""A scene folder is the user's input: no command writes into it, whatever --out says."""

from __future__ import annotations

from pathlib import Path

import pytest

from demo_cases import copy_of_demo_scene
from inceptiongs.cli import main


@pytest.fixture(scope="module")
def scene_and_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("never_written")
    scene = copy_of_demo_scene(root / "scene")
    run = root / "run"
    assert main(["train", str(scene), "--out", str(run), "--iterations", "2", "--downscale", "4"]) == 0
    return scene, run


def listing(folder: Path) -> dict:
    return {path.relative_to(folder): path.stat().st_size for path in folder.rglob("*")}


@pytest.mark.parametrize("argv", [
    ["train", "{scene}", "--out", "{scene}/run", "--iterations", "2"],
    ["train", "{scene}", "--out", "{scene}/run", "--iterations", "2", "--blocks", "1"],
    ["render", "{run}", "--view", "{view}", "--out", "{scene}/frame.png"],
    ["render", "{run}", "--orbit", "--out", "{scene}/sub/orbit.mp4"],
    ["coverage", "{scene}", "--out", "{scene}/coverage.png"],
    ["coverage", "{run}", "--out", "{scene}/coverage.png"],
    ["bootstrap", "{run}", "--out", "{scene}", "--iterations", "2"],
])
def test_an_out_inside_the_scene_folder_is_one_line_and_nothing_is_written(scene_and_run, capsys, argv):
    scene, run = scene_and_run
    view = sorted((scene / "images").iterdir())[0].name
    before = listing(scene)
    capsys.readouterr()
    assert main([part.format(scene=scene, run=run, view=view) for part in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "inside the scene folder" in err[0], err
    assert listing(scene) == before
