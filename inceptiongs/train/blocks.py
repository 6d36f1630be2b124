"""Stage I in blocks: plan the cells (partition.py), train one global stage on every photo in
RUN/blocks/global, fine-tune each block from it as an ordinary run in RUN/blocks/block_NN,
merge them into RUN.

The whole run's iterations are shared, so that a run in blocks costs the steps of one run:
``block.global_share`` of them train the global stage (a short run of the whole scene, trained
once, by rank 0, before the ranks split), the rest are divided equally among the blocks. Each
block starts from the global stage's Gaussians (block_start.py), not from the sparse points: a
block whose photos see far past its cell then only refines what one run of every photo already
placed, instead of growing its own copy of the whole scene whose floaters, inside its cell,
stay in front of the views that are not its own.

RUN is an ordinary run folder once merged: config.json (the whole run's, ``blocks`` = their
number), split.json (the whole scene's held-out views), model.ply (each block's Gaussians inside
its own cell, the rows as the block wrote them), metrics.jsonl (the merge's line), and
blocks.json (the plane, the cells, each block's photos and how many Gaussians it gave). Every
command that opens a run opens it; each block folder is a run too (resumable, with its own
held-out views: the whole run's among its photos).

A block (and the global stage) is finished when its folder holds BLOCK_DONE (written after its
last step); the same command again skips those, continues a stopped one from its checkpoint and
starts the others, so a rank that died costs only its unfinished blocks (distributed.py).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from ..errors import InputError
from ..evaluation.protocols import make_split
from ..gaussians import Gaussians
from ..io.atomic import atomic_write_text, ensure_dir
from ..io.config_json import config_value, with_values
from ..io.paths import contained_path, read_small_text
from ..io.ply import read_ply, write_ply
from ..runs.checkpoint import latest_checkpoint
from ..runs.config import SCHEDULE_FIELDS, Block, TrainConfig, sized_schedule
from ..runs.metrics import append_metrics, logged_iterations
from ..scene.loader import load_scene
from .distributed import Ranks, assign, barrier
from .optim import position_learning_rate
from .partition import (PHOTOS_PER_BLOCK, Cell, GroundPlane, balanced_cells, cell_margin, ground_plane,
                        photos_seeing)

BLOCKS_DIR = "blocks"
GLOBAL_DIR = "global"
PLAN_FILE = "blocks.json"
BLOCK_DONE = "block_done.json"


@dataclass(frozen=True)
class BlockPlan:
    """The cells of the plane and each block's photos (names), in block order."""

    plane: GroundPlane
    cells: list[Cell]
    margins: list[float]
    photos: list[list[str]]
    train_counts: list[int]         # training photos per block (the rest of its photos are held out)

    def to_json(self) -> dict:
        return {"plane": self.plane.to_json(),
                "blocks": [{"cell": cell.to_json(), "margin": margin, "photos": photos, "train_photos": count}
                           for cell, margin, photos, count in zip(self.cells, self.margins, self.photos,
                                                                  self.train_counts)]}

    @staticmethod
    def from_json(data: dict, source: str) -> "BlockPlan":
        try:
            blocks = data["blocks"]
            return BlockPlan(GroundPlane.from_json(data["plane"]), [Cell(*map(float, b["cell"])) for b in blocks],
                             [float(b["margin"]) for b in blocks], [[str(n) for n in b["photos"]] for b in blocks],
                             [int(b["train_photos"]) for b in blocks])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: not a block plan ({type(exc).__name__}: {exc})") from None

    def block_config(self, parent: TrainConfig, index: int, start: Path | None = None) -> TrainConfig:
        """Block ``index``'s run config: the whole run's settings with its share of the steps
        (stage_steps) on a schedule of that length, its photos, its cell, and ``start``: the
        global stage's folder it starts from (None: the sparse points)."""
        plane, cell = self.plane, self.cells[index]
        block = dataclasses.replace(parent.block, count=len(self.cells), index=index, photos=list(self.photos[index]),
                                    origin=[float(x) for x in plane.origin], u=[float(x) for x in plane.u],
                                    v=[float(x) for x in plane.v], cell=cell.to_json(),
                                    margin=float(self.margins[index]), start="" if start is None else str(start))
        first, steps = stage_steps(parent.iterations, parent.block.global_share, len(self.cells))
        config = stage_config(parent, steps[index])
        if parent.block.schedule == "continue" and first:
            config = continued_schedule(config, parent, first)
        return dataclasses.replace(config, blocks=0, block=block)


def stage_steps(total: int, share: float, count: int) -> tuple[int, list[int]]:
    """(the global stage's steps, each block's) for a run in ``count`` blocks of ``total`` steps
    in all: round(share x total) for the global stage (at least 1 when share > 0), the rest
    divided among the blocks, the first ones one more when it does not divide. They add up to
    ``total``; InputError when a block would get no step."""
    first = max(1, round(share * total)) if share > 0 else 0
    rest = total - first
    if rest < count:
        raise InputError(f"--iterations {total}: too few for {count} blocks after the global stage's {first} "
                         f"(block.global_share {share:g}); every block needs at least one step")
    return first, [rest // count + (1 if index < rest % count else 0) for index in range(count)]


def stage_config(parent: TrainConfig, steps: int) -> TrainConfig:
    """``parent`` (the whole run's config, its schedule sized to all its iterations) for a stage
    of ``steps`` steps: a milestone the schedule sized (the default's) is sized to ``steps`` as
    the command line sizes one run, a milestone given keeps its fraction of the run. The
    Gaussian budget stays the whole run's: it bounds each stage's model as it bounds one run's."""
    sized = sized_schedule(parent, steps)
    default = sized_schedule(parent, parent.iterations)
    values = {}
    for path in SCHEDULE_FIELDS:
        value = config_value(parent, path)
        if path == "densification.max_gaussians":
            values[path] = value
        elif value != config_value(default, path):   # given: scaled (parent.iterations >= 1)
            values[path] = max(1, round(value * steps / parent.iterations))
        else:
            values[path] = config_value(sized, path)
    return with_values(dataclasses.replace(sized, blocks=0), values)


def continued_schedule(block: TrainConfig, parent: TrainConfig, done: int) -> TrainConfig:
    """``block`` (a block's stage config, block.iterations steps) on the rest of the whole run's
    schedule after its global stage's ``done`` steps, compressed into the block's steps: the
    position step size starts where the whole run's would be at ``done`` (and decays to its
    final value as the whole run's does), a milestone of the whole run maps to the block's step
    in the same place of the rest (before ``done``: the block's first step; densification ends
    at once when the whole run's window has closed), and the SH degree the global stage reached
    comes back within its first steps."""
    whole = stage_config(parent, parent.iterations)
    rest = max(1, parent.iterations - done)

    def mapped(step: int) -> int:     # the whole run's step -> the block's
        return max(0, round((step - done) * block.iterations / rest))

    # The whole run's step size at ``done``, per unit of scene extent (the block scales it by its own).
    values = {"learning_rates.means": position_learning_rate(done, parent, 1.0), "sh.increase_every": 1,
              "densification.densify_every": max(1, round(whole.densification.densify_every
                                                          * block.iterations / rest))}
    for path in ("densification.densify_from", "densification.densify_until", "densification.prune_large_from",
                 "pgsr_terms.normal_from", "pgsr_terms.multiview_from"):
        values[path] = mapped(config_value(whole, path))
    return with_values(block, values)


def global_config(parent: TrainConfig, count: int) -> TrainConfig | None:
    """The global stage's run config (every photo, the whole run's split, its share of the
    steps), or None when the whole run has no global stage (global_share 0)."""
    steps = stage_steps(parent.iterations, parent.block.global_share, count)[0]
    if not steps:
        return None
    return dataclasses.replace(stage_config(parent, steps), block=Block(global_share=parent.block.global_share,
                                                                        start_keep=parent.block.start_keep))


def block_count(asked: str | int, train_photos: int) -> int:
    """``--blocks auto|N`` -> the number of blocks; InputError for one no capture can use."""
    if asked == "auto":
        return max(1, math.ceil(train_photos / PHOTOS_PER_BLOCK))
    try:
        count = int(asked)
    except (TypeError, ValueError):
        raise InputError(f"--blocks: 'auto' or a number of blocks, got {asked!r}") from None
    if count < 1:
        raise InputError(f"--blocks: must be 'auto' or >= 1, got {count}")
    if count > train_photos:
        raise InputError(f"--blocks {count}: more blocks than training photos ({train_photos})")
    return count


def plan_blocks(config: TrainConfig, count: int, log: Callable[[str], None]) -> BlockPlan:
    """The cells and their photos for ``config``'s scene and split (partition.py)."""
    scene = load_scene(config.scene, downscale=config.downscale, max_width=config.max_width)
    split = make_split(scene, config.protocol, config.seed, config.scarce_views, config.exclude_photos)
    cameras = scene.cameras
    plane = ground_plane([cameras[i] for i in split.train])
    camera_coords = plane.coordinates(np.stack([cameras[i].camera_to_world[:3, 3] for i in split.train]))
    points = np.asarray(scene.points, np.float64).reshape(-1, 3)
    cells = balanced_cells(camera_coords, plane.coordinates(points) if len(points) else np.zeros((0, 2)), count)
    margins = [cell_margin(cell) for cell in cells]
    seen = photos_seeing(cells, margins, plane, cameras, sorted(split.train + split.test), points, config.seed)
    train = set(split.train)
    counts = [sum(1 for view in views if view in train) for views in seen]
    for index, (cell, trained) in enumerate(zip(cells, counts)):
        if not trained:
            raise InputError(f"{config.scene}: block {index}'s cell {[round(x, 3) for x in cell.to_json()]} is seen "
                             f"by no training photo; give fewer blocks")
    log(f"blocks: {count} cells on the ground plane; training photos per block "
        f"{', '.join(str(n) for n in counts)} (of {len(split.train)}, with their margins)")
    return BlockPlan(plane, cells, margins, [[cameras[i].name for i in views] for views in seen], counts)


def block_dir(run_dir: Path, index: int) -> Path:
    return Path(run_dir) / BLOCKS_DIR / f"block_{index:02d}"


def global_dir(run_dir: Path) -> Path:
    return Path(run_dir) / BLOCKS_DIR / GLOBAL_DIR


def block_finished(folder: Path) -> bool:
    return (folder / BLOCK_DONE).is_file() and (folder / "model.ply").is_file()


def read_plan(run_dir: Path) -> BlockPlan | None:
    """RUN/blocks.json, read through the read guard; None when there is none."""
    path = Path(run_dir) / PLAN_FILE
    if not path.is_file():
        return None
    text = read_small_text(contained_path(run_dir, PLAN_FILE, str(run_dir)), "block plan")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: not a block plan")
    return BlockPlan.from_json(data, str(path))


@dataclass
class BlocksResult:
    run_dir: Path
    blocks: int
    trained: list[int]            # blocks this process trained to their end now
    skipped: list[int]            # blocks already finished before
    stopped: bool                 # a block of this process was stopped before its end
    merged: bool
    num_gaussians: int = 0


def train_blocks(config: TrainConfig, run_dir: str | Path, count: int, ranks: Ranks, train_one,
                 log: Callable[[str], None], stop_requested: Callable[[], bool] = lambda: False) -> BlocksResult:
    """Train ``config`` in ``count`` blocks into ``run_dir`` (module doc): this rank's share of
    them (distributed.assign), then, on rank 0 once every rank is done, the merge.
    ``train_one(config, folder, resume)`` trains one block and returns its TrainResult.
    ``stop_requested()``: whether a stop (Ctrl+C, SIGTERM) came; a stage that finishes while one
    is pending is kept, and no further stage starts."""
    run_dir = Path(run_dir)
    if ranks.world > count:
        raise InputError(f"torchrun: {ranks.world} ranks for {count} blocks; start at most {count} (a rank "
                         f"without a block would only wait)")
    stage_steps(config.iterations, config.block.global_share, count)   # too few steps: one line, nothing written
    plan = read_plan(run_dir)
    if plan is not None and len(plan.cells) != count:
        raise InputError(f"{run_dir / PLAN_FILE}: holds {len(plan.cells)} blocks, not {count} (give --blocks "
                         f"{len(plan.cells)} to continue it, or another --out)")
    if plan is None and ranks.rank == 0:
        plan = plan_blocks(config, count, log)
        ensure_dir(run_dir)
        atomic_write_text(run_dir / PLAN_FILE, json.dumps(plan.to_json(), indent=1) + "\n")
        config.save(run_dir / "config.json")
    barrier(ranks)   # every rank once, whatever it found: the plan is on disk after it
    plan = plan or read_plan(run_dir)
    first = global_config(config, count)
    start = global_dir(run_dir) if first is not None else None
    for index in range(count):   # a plan edited by hand: one line before any block trains
        plan.block_config(config, index, start).validate(str(run_dir / PLAN_FILE))
    result = BlocksResult(run_dir, count, [], [], False, False)
    if first is not None and ranks.rank == 0:
        result.stopped = not train_global(first, start, train_one, log)
    # A stop that came as a stage finished ends the run here: the next stage would only set up
    # (and leave a step-0 checkpoint) before it honoured it.
    result.stopped = result.stopped or stop_requested()
    if result.stopped:
        return result    # as a stopped block: the same command later continues it
    barrier(ranks)   # the global stage is finished after it: every block starts from it
    mine = assign(plan.train_counts, ranks.world)[ranks.rank]
    for index in mine:
        folder = block_dir(run_dir, index)
        if stop_requested() and not block_finished(folder):
            result.stopped = True
            break
        if block_finished(folder):
            result.skipped.append(index)
            log(f"block {index + 1} of {count}: finished earlier ({folder})")
            continue
        resume = latest_checkpoint(folder) is not None
        block_config = plan.block_config(config, index, start)
        log(f"block {index + 1} of {count}: {block_config.iterations} steps, {plan.train_counts[index]} training photos"
            + (" (continued from its checkpoint)" if resume else "") + f" -> {folder}")
        trained = train_one(block_config, folder, resume)
        if not trained.finished:
            result.stopped = True
            break
        atomic_write_text(folder / BLOCK_DONE, json.dumps({"iteration": trained.iteration,
                                                           "gaussians": trained.num_gaussians}) + "\n")
        result.trained.append(index)
    if result.stopped:
        return result   # no barrier: a stopped rank ends now; the same command later continues it
    barrier(ranks)
    if ranks.rank == 0:
        missing = [i for i in range(count) if not block_finished(block_dir(run_dir, i))]
        if missing:
            raise InputError(f"{run_dir}: block(s) {', '.join(str(i) for i in missing)} not finished; run the "
                             f"same command again to train them")
        if merged_up_to_date(run_dir, len(plan.cells)):
            log(f"{run_dir}: every block finished and merged earlier; nothing to do")
        else:
            result.num_gaussians = merge_blocks(config, run_dir, plan, log)
            result.merged = True
    barrier(ranks)
    return result


def train_global(config: TrainConfig, folder: Path, train_one, log: Callable[[str], None]) -> bool:
    """The global stage into ``folder`` unless it finished earlier (continued from its checkpoint
    when one is there) -> whether it is finished now."""
    if block_finished(folder):
        log(f"global stage: finished earlier ({folder})")
        return True
    resume = latest_checkpoint(folder) is not None
    log(f"global stage: {config.iterations} steps on every training photo"
        + (" (continued from its checkpoint)" if resume else "") + f" -> {folder}")
    trained = train_one(config, folder, resume)
    if trained.finished:
        atomic_write_text(folder / BLOCK_DONE, json.dumps({"iteration": trained.iteration,
                                                           "gaussians": trained.num_gaussians}) + "\n")
    return trained.finished


def merged_up_to_date(run_dir: Path, count: int) -> bool:
    """Whether RUN/model.ply was merged after every block finished (a rerun then writes nothing)."""
    model = Path(run_dir) / "model.ply"
    if not model.is_file():
        return False
    done = [block_dir(run_dir, i) / BLOCK_DONE for i in range(count)]
    return all(path.is_file() for path in done) and all(path.stat().st_mtime <= model.stat().st_mtime
                                                        for path in done)


def merge_blocks(config: TrainConfig, run_dir: Path, plan: BlockPlan, log: Callable[[str], None],
                 sources: Sequence[Path] | None = None, record: dict | None = None) -> int:
    """RUN/model.ply from the finished blocks: each block's Gaussians whose centre lies in its
    own cell (half-open cells: none twice, none lost), rows as the block wrote them, SH padded to
    the highest degree; RUN's split.json is the whole scene's. ``sources``: the folder each block's
    model.ply is read from (default RUN/blocks/block_NN); ``record``: more for blocks.json.
    Returns the number of Gaussians."""
    scene = load_scene(config.scene, downscale=config.downscale, max_width=config.max_width)
    sources = [block_dir(run_dir, i) for i in range(len(plan.cells))] if sources is None else list(sources)
    missing = [str(folder) for folder in sources if not (folder / "model.ply").is_file()]
    if missing:
        raise InputError(f"{missing[0]}: the block has no model.ply; run the same command again to train it")
    parts, kept = [], []
    for cell, folder in zip(plan.cells, sources):
        model = read_ply(folder / "model.ply")
        coords = plan.plane.coordinates(scene.normalization.to_normalized(model.means.double().numpy()))
        inside = torch.from_numpy(cell.contains(coords))
        parts.append(model.subset(inside))
        kept.append(int(inside.sum()))
    merged = concatenate(parts)
    ensure_dir(run_dir)
    write_ply(merged, run_dir / "model.ply")
    split = make_split(scene, config.protocol, config.seed, config.scarce_views, config.exclude_photos)
    split.save(run_dir / "split.json")
    data = {**plan.to_json(), **(record or {}), "kept_gaussians": kept}
    atomic_write_text(run_dir / PLAN_FILE, json.dumps(data, indent=1) + "\n")
    config.save(run_dir / "config.json")
    if config.iterations not in logged_iterations(run_dir):
        append_metrics(run_dir, {"iteration": config.iterations, "phase": "merged", "num_gaussians": len(merged),
                                 "blocks": len(plan.cells)})
    log(f"merged {len(plan.cells)} blocks into {run_dir / 'model.ply'}: {len(merged)} Gaussians "
        f"({', '.join(str(n) for n in kept)} per block)")
    return len(merged)


def concatenate(parts: Sequence[Gaussians]) -> Gaussians:
    """One model from ``parts``, SH padded with zeros to the highest degree among them."""
    coefficients = max(part.sh.shape[1] for part in parts)
    def padded(sh: torch.Tensor) -> torch.Tensor:
        return torch.cat([sh, sh.new_zeros(sh.shape[0], coefficients - sh.shape[1], 3)], dim=1)
    return Gaussians(*(torch.cat([getattr(p, name) for p in parts]) for name in
                       ("means", "log_scales", "quats", "opacity_logits")),
                     torch.cat([padded(p.sh) for p in parts]))
