"""Stage I in blocks (inceptiongs.train.partition, .blocks, .distributed): the cells, the photos
that see them, one process and torchrun writing the same merged model, a killed run continued
with only its unfinished blocks, and one line for every bad value."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from inceptiongs.camera import Camera, look_at
from inceptiongs.cli import main
from inceptiongs.errors import InputError
from inceptiongs.io.config_json import with_values
from inceptiongs.evaluation.protocols import make_split
from inceptiongs.io.ply import read_ply
from demo_cases import copy_of_demo_scene
from inceptiongs.scene.loader import load_scene
from inceptiongs.train.blocks import (BLOCK_DONE, PLAN_FILE, block_dir, continued_schedule, global_dir, read_plan,
                                     stage_config, stage_steps)
from inceptiongs.train.distributed import assign, ranks_from_environment
from inceptiongs.train.partition import (Cell, balanced_cells, ground_plane, photos_seeing, visible_points)

ITERATIONS = 30     # in all: the global stage's 10 (a third), then 10 for each of the 2 blocks
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


def test_the_global_stage_and_the_blocks_share_the_steps_of_one_run():
    assert stage_steps(3000, 1 / 3, 4) == (1000, [500, 500, 500, 500])
    first, blocks = stage_steps(1001, 0.25, 3)
    assert first == 250 and blocks == [251, 250, 250] and first + sum(blocks) == 1001
    assert stage_steps(10, 0.0, 3) == (0, [4, 3, 3])
    assert stage_steps(3, 0.01, 2) == (1, [1, 1])            # a share > 0 gets at least one step
    with pytest.raises(InputError, match="too few for 2 blocks"):
        stage_steps(2, 0.4, 2)


def test_a_stage_sizes_the_default_milestones_to_its_steps_and_scales_the_given_ones():
    from inceptiongs.runs.config import TrainConfig, short_run_schedule, sized_schedule

    whole = short_run_schedule(TrainConfig(iterations=3000))
    stage = stage_config(whole, 1000)
    one_run = sized_schedule(whole, 1000)      # what `train --iterations 1000` builds
    assert stage.iterations == 1000 and stage.blocks == 0
    assert stage.densification.densify_until == one_run.densification.densify_until != whole.densification.densify_until
    assert stage.sh.increase_every == one_run.sh.increase_every
    # The Gaussian budget is the whole run's.
    assert stage.densification.max_gaussians == whole.densification.max_gaussians
    # A milestone given keeps its fraction of the run.
    given = with_values(whole, {"densification.densify_until": 2400})
    assert stage_config(given, 1000).densification.densify_until == 800


def test_a_continued_block_lives_through_the_rest_of_the_whole_runs_schedule():
    """schedule "continue": block step b has the position step size the whole run has at step
    done + b x rest / steps, and the whole run's milestones land at the same place of the rest."""
    from inceptiongs.runs.config import TrainConfig, short_run_schedule
    from inceptiongs.train.optim import position_learning_rate

    whole = short_run_schedule(TrainConfig(iterations=3000))
    for done, steps in ((1000, 500), (2000, 250)):
        restarted = stage_config(whole, steps)
        block = continued_schedule(restarted, whole, done)
        for b in (0, steps // 3, steps):
            at = done + b * (3000 - done) / steps
            assert position_learning_rate(b, block, 1.0) == pytest.approx(position_learning_rate(at, whole, 1.0),
                                                                            rel=1e-9)
        # A restarted block begins at the full step size: the thing "continue" avoids.
        assert position_learning_rate(0, restarted, 1.0) > 2 * position_learning_rate(0, block, 1.0)
        until = whole.densification.densify_until
        assert block.densification.densify_until == max(0, round((until - done) * steps / (3000 - done)))
        assert block.sh.increase_every == 1
    # The whole run densifies until step 1500: a block after 1000 steps densifies a quarter of its
    # steps, one after 2000 not at all.
    assert whole.densification.densify_until == 1500
    assert continued_schedule(stage_config(whole, 500), whole, 1000).densification.densify_until == 125
    assert continued_schedule(stage_config(whole, 250), whole, 2000).densification.densify_until == 0


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


def test_the_global_stage_is_one_run_of_every_photo_and_the_steps_add_up(blocks_run):
    scene, run, _ = blocks_run
    stage = json.loads((global_dir(run) / "config.json").read_text())
    blocks = [json.loads((block_dir(run, i) / "config.json").read_text()) for i in range(2)]
    assert stage["iterations"] + sum(block["iterations"] for block in blocks) == ITERATIONS
    assert stage["iterations"] == 10 and stage["block"]["count"] == 0 and stage["blocks"] == 0
    # Every training photo, the whole run's held-out views.
    whole = make_split(load_scene(scene), "unstructured")
    assert json.loads((global_dir(run) / "split.json").read_text()) == json.loads((run / "split.json").read_text())
    assert len(json.loads((global_dir(run) / "split.json").read_text())["train"]) == len(whole.train)
    for index, block in enumerate(blocks):
        assert block["block"]["start"] == str(global_dir(run))
        last = json.loads((block_dir(run, index) / "metrics.jsonl").read_text().splitlines()[-1])
        assert last["iteration"] == block["iterations"]


def test_each_block_starts_from_the_global_stages_gaussians(blocks_run):
    """A block's first Gaussians are the global stage's last ones (rows of its checkpoint):
    those in the block's widened cell and those its training photos see."""
    import torch

    from inceptiongs.runs.checkpoint import load_newest_checkpoint
    from inceptiongs.runs.config import TrainConfig
    from inceptiongs.train.block_start import block_start, start_rows
    from inceptiongs.train.partition import as_block
    from inceptiongs.train.sky import in_background

    scene_dir, run, _ = blocks_run
    scene = load_scene(scene_dir)
    _, payload = load_newest_checkpoint(global_dir(run))
    assert payload["iteration"] == 10
    means = payload["params"]["means"].detach().double().numpy()
    background = in_background(payload["params"]["means"].detach(), payload.get("sky")).numpy()
    for index in range(2):
        config = TrainConfig.load(block_dir(run, index) / "config.json")
        _, split = as_block(scene, make_split(scene, "unstructured"), config.block)
        cameras = [scene.cameras[i] for i in split.train]
        rows = start_rows(means, config.block, cameras, background)
        start, sky, _ = block_start(config.block, cameras, 1, lambda line: None)
        assert torch.equal(start.means, payload["params"]["means"].detach()[torch.from_numpy(rows)])
        assert torch.equal(sky, payload["sky"]) and start.sh.shape[1] == 4
        # The block's own log: its run began with exactly these Gaussians.
        first = json.loads((block_dir(run, index) / "metrics.jsonl").read_text().splitlines()[0])
        assert first["iteration"] == 0 and first["num_gaussians"] == len(start)
        # "cell" keeps fewer: the rows the photos see outside the widened cell are left out.
        cell_only = start_rows(means, dataclasses.replace(config.block, start_keep="cell"), cameras, background)
        assert (cell_only <= rows).all() and cell_only.sum() < rows.sum()


def test_the_same_command_again_writes_nothing(blocks_run):
    _, run, command = blocks_run
    before = {path: (sha(path), path.stat().st_mtime_ns) for path in run.rglob("*.ply")}
    assert global_dir(run) / "model.ply" in before
    out = subprocess.run(command, env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and "nothing to do" in out.stderr and "global stage: finished earlier" in out.stderr
    assert {path: (sha(path), path.stat().st_mtime_ns) for path in run.rglob("*.ply")} == before


def test_the_same_folder_with_other_settings_is_one_line_and_writes_nothing(blocks_run, capsys):
    """A finished (or half-finished) run in blocks is continued by the command that started it;
    another --iterations or --seed would otherwise be ignored with "nothing to do"."""
    scene, run, command = blocks_run
    before = {path: sha(path) for path in run.rglob("*") if path.is_file()}
    for flag, value, shown in (("--iterations", str(ITERATIONS + 10), f"iterations {ITERATIONS} (asked {ITERATIONS + 10})"),
                               ("--seed", "3", "seed 0 (asked 3)")):
        asked = [*command[3:]]
        if flag in asked:
            asked[asked.index(flag) + 1] = value
        else:
            asked += [flag, value]
        assert main(asked) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "other settings" in err[0] and shown in err[0], err
    assert {path: sha(path) for path in run.rglob("*") if path.is_file()} == before


def test_torchrun_on_two_ranks_writes_the_same_model_as_one_process(blocks_run, tmp_path):
    scene, run, command = blocks_run
    out = tmp_path / "run"
    launch = [sys.executable, "-m", "torch.distributed.run", "--nproc-per-node", "2", "--master-port", "29517",
              "-m", "inceptiongs", *command[3:]]
    launch[launch.index("--out") + 1] = str(out)
    result = subprocess.run(launch, env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "[rank 0] merged 2 blocks" in result.stderr and "[rank 1] block" in result.stderr
    assert "[rank 0] global stage: 10 steps" in result.stderr and "[rank 1] global stage" not in result.stderr
    assert sha(global_dir(out) / "model.ply") == sha(global_dir(run) / "model.ply")
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
    kept_global = (sha(global_dir(out) / "model.ply"), (global_dir(out) / "model.ply").stat().st_mtime_ns)
    again = subprocess.run(command, env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-2000:]
    assert f"block {first + 1} of 2: finished earlier" in again.stderr
    # The global stage is not trained again.
    assert "global stage: finished earlier" in again.stderr
    assert (sha(global_dir(out) / "model.ply"), (global_dir(out) / "model.ply").stat().st_mtime_ns) == kept_global
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


def test_a_stopped_global_stage_is_continued_from_its_checkpoint_and_trained_once(blocks_run, tmp_path):
    """train_blocks with a stand-in for the trainer: what it is asked to train, and with which resume."""
    from inceptiongs.runs.config import TrainConfig
    from inceptiongs.train.blocks import train_blocks
    from inceptiongs.train.distributed import Ranks
    from inceptiongs.train.trainer import TrainResult

    _, run, _ = blocks_run
    config = TrainConfig.load(run / "config.json")
    out = tmp_path / "run"
    calls = []

    def stand_in(stop_at):
        def train_one(stage, folder, resume):
            name = "global" if folder == global_dir(out) else f"block {stage.block.index}"
            calls.append((name, stage.iterations, resume))
            (folder / "checkpoints").mkdir(parents=True, exist_ok=True)
            (folder / "checkpoints" / "step_0000005.pt").write_bytes(b"")   # what latest_checkpoint finds
            finished = name not in stop_at
            if finished:
                (folder / "model.ply").write_bytes(b"")
            return TrainResult(folder, stage.iterations if finished else 5, finished, 0)
        return train_one

    first = train_blocks(config, out, 2, Ranks(), stand_in({"global"}), lambda line: None)
    assert first.stopped and calls == [("global", 10, False)]
    calls.clear()
    second = train_blocks(config, out, 2, Ranks(), stand_in({"block 0", "block 1"}), lambda line: None)
    assert second.stopped and calls[0] == ("global", 10, True) and calls[1][0].startswith("block")
    assert (global_dir(out) / BLOCK_DONE).is_file()
    calls.clear()
    third = train_blocks(config, out, 2, Ranks(), stand_in({"block 0", "block 1"}), lambda line: None)
    assert third.stopped and [name for name, _, _ in calls] == [calls[0][0]] and calls[0][0] != "global"


def test_a_stop_that_comes_as_a_stage_finishes_starts_no_other_stage(blocks_run, tmp_path):
    """Ctrl+C during a stage's last step: that stage finishes and is kept, the next one does not
    start (it would set up and leave a step-0 checkpoint first), and the run says it stopped."""
    from inceptiongs.runs.config import TrainConfig
    from inceptiongs.train.blocks import train_blocks
    from inceptiongs.train.distributed import Ranks
    from inceptiongs.train.trainer import TrainResult

    _, run, _ = blocks_run
    config = TrainConfig.load(run / "config.json")
    out = tmp_path / "run"
    calls, stop = [], []

    def train_one(stage, folder, resume):   # finishes, with a stop requested during its last step
        calls.append(folder.name)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "model.ply").write_bytes(b"")
        stop.append(True)
        return TrainResult(folder, stage.iterations, True, 0)

    first = train_blocks(config, out, 2, Ranks(), train_one, lambda line: None, stop_requested=lambda: bool(stop))
    assert first.stopped and not first.merged and calls == ["global"]
    assert (global_dir(out) / BLOCK_DONE).is_file()
    assert not block_dir(out, 0).exists() and not block_dir(out, 1).exists()
    stop.clear()
    calls.clear()
    second = train_blocks(config, out, 2, Ranks(), train_one, lambda line: None, stop_requested=lambda: bool(stop))
    assert second.stopped and len(calls) == 1 and calls[0].startswith("block_")
    assert sum(block_dir(out, i).exists() for i in range(2)) == 1


def test_a_stop_during_the_last_blocks_last_step_leaves_a_merged_run_and_says_so(blocks_run, tmp_path, capsys,
                                                                                 monkeypatch):
    """Ctrl+C while the last block takes its last step: the block finishes, the run is merged, and
    the command says so (exit 0), not "stopped ... continue with the same command"."""
    import inceptiongs.train.trainer as trainer

    scene, run, _ = blocks_run
    last = assign(read_plan(run).train_counts, 1)[0][-1]

    def stand_in(config, folder, resume=False, control=None, **_):   # the fixture's models, as trained
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        source = global_dir(run) if folder == global_dir(out) else block_dir(run, config.block.index)
        shutil.copyfile(source / "model.ply", folder / "model.ply")
        if folder == block_dir(out, last):
            control.listening.set()
            os.kill(os.getpid(), signal.SIGINT)    # the handler sets control.stop, as Ctrl+C does
        return trainer.TrainResult(folder, config.iterations, True, 0)

    out = tmp_path / "run"
    monkeypatch.setattr(trainer, "train", stand_in)
    status = main(["train", str(scene), "--out", str(out), "--iterations", str(ITERATIONS), "--protocol",
                   "unstructured", "--blocks", "2"])
    captured = capsys.readouterr()
    assert "SIGINT" in captured.err
    assert status == 0 and "stopped" not in captured.err
    assert "2 blocks merged" in captured.out and (out / "model.ply").is_file()


def test_blocks_auto_trains_a_capture_of_one_blocks_photos_as_one_run(blocks_run, tmp_path, capsys):
    """--blocks auto on fewer training photos than a block holds: one ordinary run (docs: "a smaller
    capture trains as one run"), not a global stage and one block, and the same command again
    continues it."""
    scene, _, _ = blocks_run
    out = tmp_path / "run"
    command = ["train", str(scene), "--out", str(out), "--blocks", "auto", "--iterations", "4"]
    assert main(command) == 0
    err = capsys.readouterr().err
    assert "--blocks auto:" in err and "as one run" in err
    assert not (out / "blocks").exists() and not (out / PLAN_FILE).exists()
    assert json.loads((out / "config.json").read_text())["blocks"] == 0 and (out / "model.ply").is_file()
    assert main(command) == 0
    assert "--blocks auto: continues the one run" in capsys.readouterr().err


def test_a_photo_budget_below_one_photo_is_one_line_and_no_run_folder(blocks_run, tmp_path, capsys):
    scene, _, _ = blocks_run
    out = tmp_path / "r"
    assert main(["train", str(scene), "--out", str(out), "--blocks", "2", "--photo-memory", "1K",
                 "--iterations", str(ITERATIONS)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--photo-memory" in err[0] and "smaller than one photo" in err[0]
    assert not out.exists()


def test_a_time_budget_in_blocks_says_what_it_adds_up_to(blocks_run, tmp_path, capsys):
    """--minutes is each stage's budget (docs): the command says what the whole run may take."""
    scene, _, _ = blocks_run
    assert main(["train", str(scene), "--out", str(tmp_path / "r"), "--blocks", "2", "--minutes", "0.05"]) == 0
    assert "--minutes 0.05 is each stage's own budget: the 3 stages" in capsys.readouterr().err


def test_too_few_steps_and_a_bad_share_are_one_line(blocks_run, tmp_path, capsys):
    scene, _, _ = blocks_run
    assert main(["train", str(scene), "--out", str(tmp_path / "r"), "--blocks", "2", "--iterations", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--iterations 2: too few for 2 blocks" in err[0]
    settings = tmp_path / "share.json"
    settings.write_text(json.dumps({"block": {"global_share": 1.0}}))
    assert main(["train", str(scene), "--out", str(tmp_path / "r"), "--blocks", "2", "--iterations", "30",
                 "--config", str(settings)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "global_share" in err[0]
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
    again = [*command[3:]]   # the command that started the run: only it continues one
    again[again.index("--out") + 1] = str(out)
    assert main(again) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "block.photos names no photo" in err[0]


def one_block_view(scene, plan):
    """A camera of ``scene`` that sees one block's cell only (most views of this small scene see
    both): the flag that makes a bootstrap refine one block."""
    from inceptiongs.bootstrap.blocks import blocks_holding
    from inceptiongs.bootstrap.targets import Target

    return next(camera for camera in scene.cameras
                if len(blocks_holding([Target(camera.name, camera, "view")], plan, scene.points)) == 1)


def test_a_bootstrap_refines_only_the_blocks_the_flag_sees(blocks_run, tmp_path):
    scene_dir, run, _ = blocks_run
    scene = load_scene(scene_dir)
    plan = read_plan(run)
    flagged = one_block_view(scene, plan)
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


def test_the_viewers_bootstrap_job_refines_only_the_blocks_the_flag_sees(blocks_run, tmp_path):
    """The viewer's "Bootstrap flagged views" refined the whole merged model of a run in blocks
    (117,520 Gaussians on a town), where `inceptiongs bootstrap` refines the flagged blocks only."""
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.job import BootstrapJob
    from inceptiongs.io.flags import Flag, save_flags
    from inceptiongs.live import JobControl, SnapshotBox

    scene_dir, run, _ = blocks_run
    scene = load_scene(scene_dir)
    plan = read_plan(run)
    flagged = one_block_view(scene, plan)
    flags = tmp_path / "flags.json"
    save_flags(flags, [Flag("flag 1", flagged, "")])
    out, box = tmp_path / "boot", SnapshotBox()
    BootstrapJob(run, out, flags, BootstrapConfig(iterations=8, follow_outlook=False)).run(box, JobControl())
    written = json.loads((out / PLAN_FILE).read_text())
    assert len(written["refined"]) == 1
    kept = written["kept_gaussians"]
    unrefined = [i for i in range(len(kept)) if i not in written["refined"]][0]
    start = sum(kept[:unrefined])
    before_start = sum(json.loads((run / PLAN_FILE).read_text())["kept_gaussians"][:unrefined])
    before, after = read_ply(run / "model.ply"), read_ply(out / "model.ply")
    assert np.array_equal(before.means[before_start:before_start + kept[unrefined]].numpy(),
                          after.means[start:start + kept[unrefined]].numpy())
    last = box.latest()
    assert last is not None and len(last.gaussians["means"]) == len(after) == sum(kept)
    assert "refined" in last.message and "bootstrap finished" in last.message, last.message
    # Its last word carries the merged result's held-out scores, as an ordinary bootstrap's does.
    assert last.metrics and last.metrics == json.loads((out / "bootstrap" / "summary.json").read_text())["last_eval"]


def flat_eval(run: Path, capsys) -> tuple[dict, dict | None]:
    """`inceptiongs eval RUN --json`'s group scores, flat ("scarce_psnr", ...), and its verdict (None: none)."""
    assert main(["eval", str(run), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    return ({f"{group}_{metric}": entry[metric] for group, entry in printed["groups"].items()
             for metric in ("psnr", "ssim") if entry[metric] is not None}, printed.get("verdict"))


@pytest.fixture(scope="module")
def blocks_bootstrap(blocks_run, tmp_path_factory):
    """`inceptiongs bootstrap` of the blocks run for a view one block sees -> (RUN2, its process)."""
    scene_dir, run, _ = blocks_run
    flagged = one_block_view(load_scene(scene_dir), read_plan(run))
    out = tmp_path_factory.mktemp("blocks_bootstrap") / "boot"
    settings = out.parent / "virtual.json"
    settings.write_text(json.dumps({"follow_outlook": False}))
    result = subprocess.run([sys.executable, "-m", "inceptiongs", "bootstrap", str(run), "--out", str(out),
                             "--iterations", "8", "--config", str(settings), "--target-view", flagged.name],
                            env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    return out, result


def test_a_blocks_bootstraps_summary_scores_the_merged_model_as_eval_does(blocks_run, blocks_bootstrap, capsys):
    """A bootstrap of a run in blocks recorded only its blocks' own scores (each on its block's
    split), so every verdict said there were no held-out scores to judge it by: its summary holds
    the merged input's and the merged result's held-out scores, in an ordinary bootstrap's keys."""
    from inceptiongs.evaluation.verdict import read_bootstrap_verdict, report_verdicts, verdict_line

    _, run, _ = blocks_run
    out, result = blocks_bootstrap
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    before, _ = flat_eval(run, capsys)
    after, verdict_printed = flat_eval(out, capsys)
    assert set(summary["initial_eval"]) == set(before) and set(summary["last_eval"]) == set(after)
    assert {"scarce_psnr", "covered_psnr", "all_psnr"} <= set(before)
    for key in before:
        assert summary["initial_eval"][key] == pytest.approx(before[key], abs=1e-4), key
        assert summary["last_eval"][key] == pytest.approx(after[key], abs=1e-4), key
    assert summary["last_eval"] != summary["initial_eval"]     # the refined block changed the merged model
    assert "scoring the input" in result.stderr and "scoring the result" in result.stderr   # said before each
    # The command prints them as an ordinary bootstrap does.
    assert f"PSNR {before['scarce_psnr']:6.2f} -> {after['scarce_psnr']:6.2f} dB" in result.stdout
    # Every verdict judges it: the viewer's and eval's (read_bootstrap_verdict), report's.
    verdict = read_bootstrap_verdict(out)
    assert verdict is not None and verdict.before == summary["initial_eval"] and verdict.after == summary["last_eval"]
    line = verdict_line(verdict)
    assert "no held-out scores" not in line and line.startswith("held-out scarce views:"), line
    assert verdict.virtual_steps == summary["virtual_steps"] > 0     # the blocks' step counts, added up
    assert verdict.iterations == (summary["start_iteration"], summary["iteration"])
    assert verdict_printed is not None and verdict_printed["line"] == line
    assert verdict_printed["stage1"] == summary["initial_eval"] and verdict_printed["bootstrap"] == summary["last_eval"]
    assert report_verdicts([out]) == [f"{out.name}: {line}"]
    # The outlook the refined block followed, named as that block's.
    block = summary["blocks_refined"][0]
    assert summary["outlook"]["line"] == f"block {block + 1}: {summary['blocks'][0]['summary']['outlook']['line']}"


def test_the_viewers_baseline_of_a_blocks_bootstrap_is_its_same_time_baseline(blocks_run, blocks_bootstrap):
    """The viewer offers the same-time baseline of a result it can judge: of a blocks bootstrap,
    the blocks it refined continued on their photos alone for its time (the whole merged model
    continued would start at another iteration, and the verdict would refuse it)."""
    from app.job_requests import baseline_job_for
    from inceptiongs.evaluation.verdict import read_bootstrap_verdict, verdict_line
    from inceptiongs.live import JobControl, SnapshotBox

    _, run, _ = blocks_run
    out, _ = blocks_bootstrap
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    job = baseline_job_for(read_bootstrap_verdict(out))
    assert job.blocks == tuple(summary["blocks_refined"]) and job.seconds == pytest.approx(summary["wall_s"])
    box = SnapshotBox()
    job.run(box, JobControl())
    baseline = json.loads((job.out_dir / "bootstrap" / "summary.json").read_text())
    assert baseline["baseline"] is True and baseline["blocks_refined"] == summary["blocks_refined"]
    assert baseline["start_iteration"] == summary["start_iteration"] and baseline["last_eval"]
    assert box.latest().metrics == baseline["last_eval"]
    # The blocks nobody refined are the stage-I run's in the baseline too.
    kept = json.loads((job.out_dir / PLAN_FILE).read_text())["kept_gaussians"]
    other = next(i for i in range(len(kept)) if i not in summary["blocks_refined"])
    start = sum(kept[:other])
    before_start = sum(json.loads((run / PLAN_FILE).read_text())["kept_gaussians"][:other])
    assert np.array_equal(read_ply(run / "model.ply").means[before_start:before_start + kept[other]].numpy(),
                          read_ply(job.out_dir / "model.ply").means[start:start + kept[other]].numpy())
    verdict = read_bootstrap_verdict(out)
    assert verdict.baseline_dir == Path(job.out_dir) and verdict.baseline == baseline["last_eval"], verdict.refused
    assert "the same-time baseline" in verdict_line(verdict)


def test_blocks_sharing_a_time_budget_each_get_their_share(blocks_run, tmp_path):
    """A block that ran out of its share of --minutes ended the bootstrap there: the next block was
    never refined and the merge found no model.ply for it."""
    scene_dir, run, _ = blocks_run
    from inceptiongs.bootstrap.blocks import blocks_holding
    from inceptiongs.bootstrap.targets import Target

    scene, plan = load_scene(scene_dir), read_plan(run)
    both = next(camera for camera in scene.cameras
                if len(blocks_holding([Target(camera.name, camera, "view")], plan, scene.points)) == 2)
    out = tmp_path / "boot"
    result = subprocess.run([sys.executable, "-m", "inceptiongs", "bootstrap", str(run), "--out", str(out),
                             "--iterations", "100000", "--minutes", "0.05", "--target-view", both.name],
                            env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    assert summary["blocks_refined"] == [0, 1] and summary["finished"] is False     # out of time, not stopped
    for entry in summary["blocks"]:
        assert entry["summary"]["iteration"] > entry["summary"]["start_iteration"], entry["block"]


def test_a_stop_in_the_first_of_two_blocks_merges_it_with_the_others_as_they_were(blocks_run, tmp_path):
    """A stop ended the blocks' loop, and the merge then looked for the unstarted block's model in
    RUN2 and failed, where the command promises the refined blocks so far are merged."""
    from inceptiongs.bootstrap.blocks import blocks_holding, bootstrap_blocks
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.runner import run_bootstrap
    from inceptiongs.bootstrap.stage1 import load_stage1
    from inceptiongs.bootstrap.targets import Target
    from inceptiongs.live import JobControl

    scene_dir, run, _ = blocks_run
    scene, plan = load_scene(scene_dir), read_plan(run)
    both = next(Target(camera.name, camera, "view") for camera in scene.cameras
                if len(blocks_holding([Target(camera.name, camera, "view")], plan, scene.points)) == 2)
    control = JobControl()
    control.stop.set()      # the user's stop, already given as the first block starts
    out = tmp_path / "boot"
    result = bootstrap_blocks(load_stage1(run), out, [both], BootstrapConfig(iterations=8, follow_outlook=False),
                              lambda block_run, block_out, targets, config: run_bootstrap(
                                  block_run, block_out, targets, config, control=control, progress=False,
                                  log=lambda line: None), lambda line: None, progress=False)
    assert result.refined == [0] and not result.finished and not block_dir(out, 1).exists()
    written = json.loads((out / PLAN_FILE).read_text())
    assert written["refined"] == [0] and written["sources"][1] == str(block_dir(run, 1))
    kept, kept_before = written["kept_gaussians"], json.loads((run / PLAN_FILE).read_text())["kept_gaussians"]
    assert kept[1] == kept_before[1]
    assert np.array_equal(read_ply(run / "model.ply").means[kept_before[0]:].numpy(),
                          read_ply(out / "model.ply").means[kept[0]:].numpy())
    summary = json.loads((out / "bootstrap" / "summary.json").read_text())
    assert summary["blocks_refined"] == [0] and summary["last_eval"] and summary["finished"] is False
