"""Stage II on a run trained in blocks: refine only the blocks that hold the flagged views.

A flagged view belongs to the blocks whose cells it sees (the test that gave each block its
photos, inceptiongs.train.partition.photos_seeing, on the target cameras). Each such block is
bootstrapped as the ordinary run it is (RUN/blocks/block_NN -> RUN2/blocks/block_NN, with the
photos of its cell and its margin, the budget shared between them); the merge then takes those
blocks' Gaussians from RUN2 and every other block's from RUN, row for row, so the blocks nobody
flagged stay byte-identical in RUN2/model.ply. RUN2 is a run folder like any bootstrap's: its
blocks.json says which blocks were refined, bootstrap/summary.json holds each refined block's
summary and the merged model's held-out scores before and after.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import InputError
from ..io.atomic import atomic_write_text, ensure_dir
from ..io.config_json import json_safe
from ..runs.config import TrainConfig
from ..train.blocks import BlockPlan, block_dir, merge_blocks, read_plan
from ..train.partition import photos_seeing
from .config import BootstrapConfig
from .summary_file import BOOTSTRAP_DIR, SUMMARY_FILE
from .targets import Target


@dataclass
class BlocksBootstrapResult:
    out_dir: Path
    refined: list[int]
    results: list                 # the refined blocks' BootstrapResult, in that order
    finished: bool
    num_gaussians: int


def blocks_holding(targets: Sequence[Target], plan: BlockPlan, points: np.ndarray) -> list[int]:
    """The blocks whose cells (widened by their margins) the targets' cameras see, sorted."""
    cameras = [target.camera for target in targets]
    seen = photos_seeing(plan.cells, plan.margins, plan.plane, cameras, range(len(cameras)), points)
    return [index for index, views in enumerate(seen) if views]


def bootstrap_blocks(stage1, out_dir: Path, targets: Sequence[Target] | None, config: BootstrapConfig,
                     run_one: Callable, log: Callable[[str], None], blocks: Sequence[int] | None = None
                     ) -> BlocksBootstrapResult:
    """Bootstrap the blocks of ``stage1`` (a loaded Stage1 of a blocks run) that hold ``targets``
    (or ``blocks``, given: the same-time baseline refines the same blocks on their photos alone)
    into ``out_dir`` (module doc). ``run_one(block_run, block_out, targets, config)`` bootstraps
    one block and returns its BootstrapResult."""
    run_dir = Path(stage1.run_dir)
    plan = read_plan(run_dir)
    if plan is None:
        raise InputError(f"{run_dir}: config.json says blocks {stage1.config.blocks} but there is no blocks.json")
    if blocks is None:
        if not targets:
            raise InputError(f"{run_dir}: a run in blocks needs targets (or the blocks) to know which blocks to refine")
        blocks = blocks_holding(targets, plan, np.asarray(stage1.scene.points, np.float64).reshape(-1, 3))
        if not blocks:
            raise InputError(f"{run_dir}: no block's cell is seen from the flagged views")
    refined = sorted(blocks)
    names = ", ".join(f"{i + 1}" for i in refined)
    log(f"blocks: refining block(s) {names} of {len(plan.cells)} (the flagged views see their cells); "
        f"the others are kept as they are")
    # The budget is the whole bootstrap's: the refined blocks share it.
    share = config if config.minutes is None else dataclasses.replace(config, minutes=config.minutes / len(refined))
    results = []
    for index in refined:
        results.append(run_one(block_dir(run_dir, index), block_dir(out_dir, index), targets, share))
        if not results[-1].finished:
            break
    finished = len(results) == len(refined) and all(result.finished for result in results)
    sources = [block_dir(out_dir, i) if i in refined else block_dir(run_dir, i) for i in range(len(plan.cells))]
    parent = TrainConfig.load(run_dir / "config.json")
    merged_config = dataclasses.replace(parent, iterations=max(result.iteration for result in results))
    count = merge_blocks(merged_config, out_dir, plan, log, sources=sources,
                         record={"refined": refined, "sources": [str(folder) for folder in sources]})
    write_blocks_summary(out_dir, stage1, refined, results, targets, finished)
    return BlocksBootstrapResult(out_dir, refined, results, finished, count)


def write_blocks_summary(out_dir: Path, stage1, refined: Sequence[int], results: Sequence, targets, finished: bool
                         ) -> None:
    """RUN2/bootstrap/summary.json: the refined blocks' own summaries and what they add up to."""
    per_block = []
    for index, result in zip(refined, results):
        path = result.out_dir / SUMMARY_FILE
        per_block.append({"block": index, "folder": str(result.out_dir),
                          "summary": json.loads(path.read_text()) if path.is_file() else None})
    summary = {"run": str(Path(stage1.run_dir).resolve()), "baseline": targets is None, "finished": finished,
               "blocks_refined": list(refined), "blocks": per_block,
               "targets": [{"name": t.name, "origin": t.origin} for t in targets or []],
               "start_iteration": min((r.start_iteration for r in results), default=0),
               "iteration": max((r.iteration for r in results), default=0),
               "wall_s": sum(r.wall_s for r in results),
               "virtual_views": sum(r.virtual_views for r in results),
               "virtual_steps": sum(r.virtual_steps or 0 for r in results)}
    ensure_dir(out_dir / BOOTSTRAP_DIR)
    atomic_write_text(out_dir / SUMMARY_FILE, json.dumps(json_safe(summary), indent=1) + "\n")
