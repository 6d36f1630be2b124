"""Stage I in blocks (inceptiongs.train.partition, .blocks, .distributed): the cells, the photos
that see them, one process and torchrun writing the same merged model, a killed run continued
with only its unfinished blocks, and one line for every bad value."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from inceptiongs.camera import Camera, look_at
from inceptiongs.cli import main
from inceptiongs.evaluation.protocols import make_split
from inceptiongs.io.ply import read_ply
from demo_cases import copy_of_demo_scene
from inceptiongs.scene.loader import load_scene
from inceptiongs.train.blocks import BLOCK_DONE, PLAN_FILE, block_dir, read_plan
from inceptiongs.train.distributed import assign, ranks_from_environment
from inceptiongs.train.partition import (Cell, balanced_cells, ground_plane, photos_seeing, visible_points)

ITERATIONS = 30
# One thread everywhere: a block's bytes depend on the thread count of its numba reductions, and
# torchrun gives each of two ranks one thread on these two cores.
ONE_THREAD = {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


def street_cameras(xs, y: float = 0.0, look=(0.0, 1.0, 0.0)) -> list[Camera]:
    """Cameras at eye height (z up) along x, looking along ``look``."""
    cameras = []
    for i, x in enumerate(xs):
        eye = np.array([x, y, 1.6])
        w2c = look_at(eye, eye + np.asarray(look, float), up=np.array([0.0, 0.0, 1.0]))
        cameras.append(Camera(f"{i:03d}.png", 64, 48, 50.0, 50.0, 32.0, 24.0, w2c))
    return cameras


def sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def test_the_ground_plane_is_the_one_street_cameras_stand_on():
    plane = ground_plane(street_cameras(np.linspace(-5, 5, 11)))
    assert abs(abs(plane.up[2]) - 1.0) < 1e-6
    # The first axis follows the street (x), the cameras' principal direction.
    assert abs(abs(plane.u[0]) - 1.0) < 1e-6
    coords = plane.coordinates(np.array([[2.0, 3.0, 7.0]]))
    assert np.allclose(np.abs(coords[0]), [2.0, 3.0], atol=1e-9)


def test_cells_partition_the_plane_and_balance_cameras_and_points():
    rng = np.random.default_rng(0)
    cameras = rng.uniform(-10, 10, (400, 2))
    points = rng.uniform(-10, 10, (4000, 2))
    cells = balanced_cells(cameras, points, 5)
    assert len(cells) == 5
    held = np.stack([cell.contains(points) for cell in cells])
    assert (held.sum(axis=0) == 1).all()            # every point in exactly one cell
    counts = np.stack([cell.contains(cameras) for cell in cells]).sum(axis=1)
    assert counts.min() >= 0.5 * counts.max() and counts.sum() == 400
    # Outer cells reach to infinity: a point far outside the capture still has its cell.
    assert sum(bool(cell.contains(np.array([[1e6, -1e6]]))[0]) for cell in cells) == 1


def test_a_point_behind_a_nearer_one_is_not_visible():
    camera = street_cameras([0.0])[0]
    near, far, aside = [0.0, 2.0, 1.6], [0.0, 8.0, 1.6], [3.5, 8.0, 1.6]
    visible = visible_points(camera, np.array([near, far, aside, [0.0, -3.0, 1.6]]))
    assert visible.tolist() == [True, False, True, False]   # occluded, visible, behind the camera


def test_photos_see_the_cells_their_points_lie_in():
    # Points in two cells: x < 0 and x >= 0; one camera looks at each from the street (y = -5).
    points = np.array([[x, 0.0, z] for x in np.linspace(-6, -1, 20) for z in (0.5, 1.5, 2.5)]
                      + [[x, 0.0, z] for x in np.linspace(1, 6, 20) for z in (0.5, 1.5, 2.5)])
    cams = [street_cameras([-3.5], y=-4.0)[0], street_cameras([3.5], y=-4.0)[0]]
    cams = [c.with_pose(c.world_to_camera, name=n) for c, n in zip(cams, ("west", "east"))]
    plane = ground_plane(street_cameras(np.linspace(-5, 5, 5)))
    west_u = plane.coordinates(np.array([[-3.0, 0.0, 0.0]]))[0, 0]
    sign = 1.0 if west_u < 0 else -1.0
    cells = [Cell(-1e9, 0.0, -1e9, 1e9), Cell(0.0, 1e9, -1e9, 1e9)] if sign > 0 else \
        [Cell(0.0, 1e9, -1e9, 1e9), Cell(-1e9, 0.0, -1e9, 1e9)]
    seen = photos_seeing(cells, [0.0, 0.0], plane, cams, [0, 1], points)
    assert seen == [[0], [1]]


def test_blocks_go_to_ranks_largest_first_and_the_same_on_every_rank():
    assert assign([5, 9, 1, 7], 2) == [[1, 2], [3, 0]]
    assert assign([3, 3, 3], 3) == [[0], [1], [2]]
    assert ranks_from_environment({}).world == 1
    ranks = ranks_from_environment({"RANK": "1", "WORLD_SIZE": "2", "LOCAL_RANK": "1", "LOCAL_WORLD_SIZE": "2"})
    assert (ranks.rank, ranks.world, ranks.distributed) == (1, 2, True)


def test_a_restricted_split_keeps_the_whole_runs_held_out_views(tmp_path):
    scene = load_scene(copy_of_demo_scene(tmp_path / "scene", size="small"))
    split = make_split(scene, "unstructured", 0)
    keep = split.train[::2] + split.test[::2]
    part = split.restricted(keep)
    assert part.problem() is None
    assert set(part.test) == set(split.test[::2]) and set(part.train) == set(split.train[::2])
    assert part.num_views == split.num_views


def test_a_block_starts_from_every_point_its_photos_see_not_only_its_cells(tmp_path):
    """Content of the block's photos outside its cell must start as Gaussians outside the cell:
    otherwise it is fitted by Gaussians densified inside the cell, which the merge keeps."""
    from inceptiongs.runs.config import Block
    from inceptiongs.train.partition import as_block

    scene = load_scene(copy_of_demo_scene(tmp_path / "scene", size="small"))
    split = make_split(scene, "unstructured", 0)
    plane = ground_plane(scene.cameras)
    points = np.asarray(scene.points, np.float64)
    coords = plane.coordinates(points)
    median = float(np.median(coords[:, 0]))
    cell = Cell(-1e9, median, -1e9, 1e9)
    photos = [scene.cameras[i].name for i in split.train[:4]]
    block = Block(count=2, index=0, photos=photos, origin=list(plane.origin), u=list(plane.u), v=list(plane.v),
                  cell=[cell.u0, cell.u1, cell.v0, cell.v1], margin=0.0)
    block_scene, block_split = as_block(scene, split, block)
    seen = np.zeros(len(points), bool)
    for view in block_split.train:
        seen |= visible_points(scene.cameras[view], points)
    expected = seen | cell.contains(coords)
    assert (seen & ~cell.contains(coords)).any(), "the case needs photos that see past the cell"
    assert len(block_scene.points) == int(expected.sum())


@pytest.fixture(scope="module")
def blocks_run(tmp_path_factory):
    """A tiny town (48 views of 96x72) trained in 2 blocks, one thread (ONE_THREAD), in one process."""
    root = tmp_path_factory.mktemp("blocks")
    scene = root / "town"
    assert main(["demo-scene", str(scene), "--scene", "town", "--views", "48", "--size", "tiny"]) == 0
    run = root / "run"
    command = [sys.executable, "-m", "inceptiongs", "train", str(scene), "--out", str(run), "--iterations",
               str(ITERATIONS), "--protocol", "unstructured", "--blocks", "2"]
    subprocess.run(command, env={**os.environ, **ONE_THREAD}, check=True, capture_output=True, timeout=600)
    return scene, run, command


def test_a_blocks_run_is_an_ordinary_run_merged_from_its_cells(blocks_run, capsys):
    scene, run, _ = blocks_run
    plan = read_plan(run)
    assert len(plan.cells) == 2 and all(plan.train_counts)
    merged = read_ply(run / "model.ply")
    kept = json.loads((run / PLAN_FILE).read_text())["kept_gaussians"]
    assert sum(kept) == len(merged) and all(kept)
    # Each block gave exactly its Gaussians inside its own cell, rows as the block wrote them.
    normalization = load_scene(scene).normalization
    first = read_ply(block_dir(run, 0) / "model.ply")
    inside = plan.cells[0].contains(plan.plane.coordinates(normalization.to_normalized(first.means.double().numpy())))
    assert np.array_equal(merged.means[:kept[0]].numpy(), first.means[inside].numpy())
    # The merged run opens as any run does.
    assert main(["eval", str(run), "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["groups"]["all"]["views"] == len(make_split(load_scene(scene), "unstructured").test)
    assert main(["render", str(run), "--view", load_scene(scene).cameras[0].name, "--out",
                 str(run.parent / "r.png")]) == 0


def test_the_same_command_again_writes_nothing(blocks_run):
    _, run, command = blocks_run
    before = {path: (sha(path), path.stat().st_mtime_ns) for path in run.rglob("*.ply")}
    out = subprocess.run(command, env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and "nothing to do" in out.stderr
    assert {path: (sha(path), path.stat().st_mtime_ns) for path in run.rglob("*.ply")} == before


def test_torchrun_on_two_ranks_writes_the_same_model_as_one_process(blocks_run, tmp_path):
    scene, run, command = blocks_run
    out = tmp_path / "run"
    launch = [sys.executable, "-m", "torch.distributed.run", "--nproc-per-node", "2", "--master-port", "29517",
              "-m", "inceptiongs", *command[3:]]
    launch[launch.index("--out") + 1] = str(out)
    result = subprocess.run(launch, env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "[rank 0] merged 2 blocks" in result.stderr and "[rank 1] block" in result.stderr
    assert sha(out / "model.ply") == sha(run / "model.ply")


def test_a_killed_run_trains_only_its_unfinished_blocks_again(blocks_run, tmp_path):
    scene, run, command = blocks_run
    out = tmp_path / "run"
    command = [*command]
    command[command.index("--out") + 1] = str(out)
    plan_order = assign(read_plan(run).train_counts, 1)[0]     # the order one process trains them in
    first, second = plan_order
    process = subprocess.Popen(command, env={**os.environ, **ONE_THREAD}, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while not (block_dir(out, first) / BLOCK_DONE).exists():
            assert process.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        process.send_signal(signal.SIGKILL)
    finally:
        process.wait(timeout=60)
    assert not (block_dir(out, second) / BLOCK_DONE).exists() and not (out / "model.ply").exists()
    kept = sha(block_dir(out, first) / "model.ply")
    again = subprocess.run(command, env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-2000:]
    assert f"block {first + 1} of 2: finished earlier" in again.stderr
    assert f"block {second + 1} of 2:" in again.stderr
    assert sha(block_dir(out, first) / "model.ply") == kept
    # The continued run ends where an uninterrupted one does.
    assert sha(out / "model.ply") == sha(run / "model.ply")


@pytest.mark.parametrize("blocks, words", [("0", "must be 'auto' or >= 1"), ("999", "more blocks than training"),
                                           ("many", "'auto' or a number")])
def test_bad_block_counts_are_one_line(blocks_run, tmp_path, capsys, blocks, words):
    scene, _, _ = blocks_run
    assert main(["train", str(scene), "--out", str(tmp_path / "r"), "--blocks", blocks, "--iterations", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]
    assert not (tmp_path / "r").exists()


def test_more_ranks_than_blocks_and_ranks_without_blocks_are_one_line(blocks_run, tmp_path, capsys, monkeypatch):
    scene, _, _ = blocks_run
    for name, value in {"RANK": "0", "WORLD_SIZE": "3", "LOCAL_RANK": "0", "LOCAL_WORLD_SIZE": "3"}.items():
        monkeypatch.setenv(name, value)
    assert main(["train", str(scene), "--out", str(tmp_path / "r"), "--blocks", "2", "--iterations", "5"]) == 2
    assert "3 ranks for 2 blocks" in capsys.readouterr().err
    assert main(["train", str(scene), "--out", str(tmp_path / "r"), "--iterations", "5"]) == 2
    assert "only `train --blocks` spreads over ranks" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_a_plan_with_a_block_no_photo_sees_is_one_line(blocks_run, tmp_path, capsys):
    scene, run, command = blocks_run
    out = tmp_path / "run"
    out.mkdir()
    plan = json.loads((run / PLAN_FILE).read_text())
    plan["blocks"][1]["photos"] = []
    (out / PLAN_FILE).write_text(json.dumps(plan))
    (out / "config.json").write_bytes((run / "config.json").read_bytes())
    assert main(["train", str(scene), "--out", str(out), "--blocks", "2", "--iterations", str(ITERATIONS)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "block.photos names no photo" in err[0]


def test_a_bootstrap_refines_only_the_blocks_the_flag_sees(blocks_run, tmp_path):
    from inceptiongs.bootstrap.blocks import blocks_holding
    from inceptiongs.bootstrap.targets import Target

    scene_dir, run, _ = blocks_run
    scene = load_scene(scene_dir)
    plan = read_plan(run)
    # A view that sees one block's cell only (most views of this small scene see both).
    flagged = next(camera for camera in scene.cameras
                   if len(blocks_holding([Target(camera.name, camera, "view")], plan, scene.points)) == 1)
    out = tmp_path / "boot"
    settings = tmp_path / "virtual.json"
    settings.write_text(json.dumps({"follow_outlook": False}))
    result = subprocess.run([sys.executable, "-m", "inceptiongs", "bootstrap", str(run), "--out", str(out),
                             "--iterations", "8", "--config", str(settings), "--target-view", flagged.name],
                            env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    plan = json.loads((out / PLAN_FILE).read_text())
    refined = plan["refined"]
    assert len(refined) == 1
    before, after = read_ply(run / "model.ply"), read_ply(out / "model.ply")
    kept_before = json.loads((run / PLAN_FILE).read_text())["kept_gaussians"]
    start_before = start_after = 0
    for index, (count_before, count_after) in enumerate(zip(kept_before, plan["kept_gaussians"])):
        rows_before = slice(start_before, start_before + count_before)
        rows_after = slice(start_after, start_after + count_after)
        if index not in refined:      # the blocks nobody flagged: the same rows, bit for bit
            for name in ("means", "log_scales", "quats", "opacity_logits"):
                assert np.array_equal(getattr(before, name)[rows_before].numpy(),
                                      getattr(after, name)[rows_after].numpy())
            # SH bit for bit; zeros above when the refined block reached a higher degree.
            bands = before.sh.shape[1]
            assert np.array_equal(before.sh[rows_before].numpy(), after.sh[rows_after, :bands].numpy())
            assert not after.sh[rows_after, bands:].any()
        else:                         # the refined block changed
            assert not np.array_equal(before.sh[rows_before].numpy()[:10], after.sh[rows_after].numpy()[:10])
        start_before, start_after = start_before + count_before, start_after + count_after
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    assert summary["blocks_refined"] == refined and summary["virtual_steps"] > 0
