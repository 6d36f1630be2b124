"""Stage II on a run trained in blocks: refine only the blocks that hold the flagged views.

A flagged view belongs to the blocks whose cells it sees (the test that gave each block its
photos, inceptiongs.train.partition.photos_seeing, on the target cameras). Each such block is
bootstrapped as the ordinary run it is (RUN/blocks/block_NN -> RUN2/blocks/block_NN, with the
photos of its cell and its margin, the budget shared between them); the merge then takes those
blocks' Gaussians from RUN2 and every other block's from RUN, row for row, so the blocks nobody
flagged stay byte-identical in RUN2/model.ply. RUN2 is a run folder like any bootstrap's: its
blocks.json says which blocks were refined, bootstrap/summary.json holds each refined block's
summary and, in an ordinary bootstrap's keys, what they add up to: the merged model's held-out
scores before (``initial_eval``: RUN on RUN/split.json) and after (``last_eval``: RUN2 on
RUN2/split.json), scored once each as `inceptiongs eval` scores them, and the blocks' steps,
rounds and outlooks, so every verdict judges it as it judges any bootstrap. A block's own
summary scores the block on its own photos' split, not the scene's.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import InputError
from ..evaluation.protocols import Split
from ..evaluation.scoring import evaluate_views, flat_scores
from ..io.atomic import atomic_write_text, ensure_dir
from ..io.config_json import json_safe
from ..io.models import read_model
from ..runs.config import TrainConfig
from ..runs.frames import to_normalized_frame
from ..train.blocks import BlockPlan, block_dir, merge_blocks, read_plan
from ..train.partition import photos_seeing
from .config import BootstrapConfig
from .summary_file import BOOTSTRAP_DIR, SUMMARY_FILE, read_summary
from .targets import Target


@dataclass
class BlocksBootstrapResult:
    out_dir: Path
    refined: list[int]
    results: list                 # the refined blocks' BootstrapResult, in that order
    finished: bool
    num_gaussians: int
    initial_eval: dict            # the merged input's held-out scores ("scarce_psnr", ...; {}: none held out)
    last_eval: dict               # the merged result's


def blocks_holding(targets: Sequence[Target], plan: BlockPlan, points: np.ndarray) -> list[int]:
    """The blocks whose cells (widened by their margins) the targets' cameras see, sorted."""
    cameras = [target.camera for target in targets]
    seen = photos_seeing(plan.cells, plan.margins, plan.plane, cameras, range(len(cameras)), points)
    return [index for index, views in enumerate(seen) if views]


def bootstrap_blocks(stage1, out_dir: Path, targets: Sequence[Target] | None, config: BootstrapConfig,
                     run_one: Callable, log: Callable[[str], None], blocks: Sequence[int] | None = None,
                     rasterizer=None, progress: bool = True) -> BlocksBootstrapResult:
    """Bootstrap the blocks of ``stage1`` (a loaded Stage1 of a blocks run) that hold ``targets``
    (or ``blocks``, given: the same-time baseline refines the same blocks on their photos alone)
    into ``out_dir`` (module doc). ``run_one(block_run, block_out, targets, config)`` bootstraps
    one block and returns its BootstrapResult. The merged models are scored with ``rasterizer``
    (default: the one the run's device selects), with a progress bar when ``progress``."""
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
    outside = [index for index in refined if not 0 <= index < len(plan.cells)]
    if outside:
        raise InputError(f"{run_dir / 'blocks.json'}: the run has {len(plan.cells)} blocks, no block {outside[0] + 1}")
    names = ", ".join(f"{i + 1}" for i in refined)
    why = "the flagged views see their cells" if targets else "on their photos alone: the same-time baseline"
    log(f"blocks: refining block(s) {names} of {len(plan.cells)} ({why}); the others are kept as they are")
    if rasterizer is None:
        from .runner import run_rasterizer
        rasterizer = run_rasterizer(stage1, log)
    initial = merged_scores(stage1.gaussians, stage1.scene, stage1.split, rasterizer, progress, log,
                            f"the input {run_dir}")
    # The budget is the whole bootstrap's: the refined blocks share it.
    share = config if config.minutes is None else dataclasses.replace(config, minutes=config.minutes / len(refined))
    results = []
    for index in refined:
        results.append(run_one(block_dir(run_dir, index), block_dir(out_dir, index), targets, share))
        if stopped_by_user(results[-1]):   # a block out of its share of time leaves the next its own share
            break
    finished = len(results) == len(refined) and all(result.finished for result in results)
    refined = refined[:len(results)]    # stopped: the blocks after the stop keep their stage-I Gaussians
    sources = [block_dir(out_dir, i) if i in refined else block_dir(run_dir, i) for i in range(len(plan.cells))]
    parent = TrainConfig.load(run_dir / "config.json")
    merged_config = dataclasses.replace(parent, iterations=max(result.iteration for result in results))
    count = merge_blocks(merged_config, out_dir, plan, log, sources=sources,
                         record={"refined": refined, "sources": [str(folder) for folder in sources]})
    merged = to_normalized_frame(read_model(out_dir / "model.ply"), stage1.scene.normalization)
    last = merged_scores(merged, stage1.scene, Split.load(out_dir / "split.json", stage1.scene.cameras), rasterizer,
                         progress, log, f"the result {out_dir}")
    write_blocks_summary(out_dir, stage1, refined, results, targets, finished, initial, last)
    return BlocksBootstrapResult(out_dir, refined, results, finished, count, initial, last)


def stopped_by_user(result) -> bool:
    """Whether the block bootstrap ``result`` (a BootstrapResult) ended on the user's stop, as its
    summary says, rather than at its last step or at the end of its time."""
    return (read_summary(result.out_dir) or {}).get("stopped") is True


def merged_scores(gaussians, scene, split: Split, rasterizer, progress: bool, log: Callable[[str], None],
                  what: str) -> dict:
    """The held-out scores of a merged model (``gaussians`` in the normalised frame) on
    ``split``'s held-out views, flat ("scarce_psnr", "all_ssim", ...) and rendered as `inceptiongs
    eval` renders them (black background, every held-out view); {} when the split holds none out.
    ``what`` names the model in the log lines: one before the views are rendered (a run in
    blocks is a large scene: this takes a while; ``progress`` adds a bar), one with the scores."""
    if not split.test:
        return {}
    log(f"blocks: scoring {what} on its {len(split.test)} held-out views")
    scores = flat_scores(evaluate_views(gaussians, scene, split, progress=progress, rasterizer=rasterizer)["groups"])
    log(f"blocks: {what}: held-out " + ", ".join(f"{group} {scores[f'{group}_psnr']:.2f} dB"
                                                 for group in ("scarce", "covered", "all")
                                                 if f"{group}_psnr" in scores))
    return scores


def write_blocks_summary(out_dir: Path, stage1, refined: Sequence[int], results: Sequence, targets, finished: bool,
                         initial_eval: dict, last_eval: dict) -> None:
    """RUN2/bootstrap/summary.json: the refined blocks' own summaries and what they add up to,
    the merged model's held-out scores before and after (module doc)."""
    per_block = []
    for index, result in zip(refined, results):
        path = result.out_dir / SUMMARY_FILE
        per_block.append({"block": index, "folder": str(result.out_dir),
                          "summary": json.loads(path.read_text()) if path.is_file() else None})
    summaries = [(entry["block"], entry["summary"]) for entry in per_block if isinstance(entry["summary"], dict)]
    summary = {"run": str(Path(stage1.run_dir).resolve()), "baseline": targets is None, "finished": finished,
               "blocks_refined": list(refined), "blocks": per_block,
               "targets": [{"name": t.name, "origin": t.origin} for t in targets or []],
               "start_iteration": min((r.start_iteration for r in results), default=0),
               "iteration": max((r.iteration for r in results), default=0),
               "wall_s": sum(r.wall_s for r in results),
               "virtual_views": sum(r.virtual_views for r in results),
               "virtual_steps": sum(r.virtual_steps or 0 for r in results),
               "initial_eval": initial_eval, "last_eval": last_eval,
               "steps": summed_steps([data for _, data in summaries]),
               "rounds": [{**round_record, "block": index} for index, data in summaries
                          for round_record in data.get("rounds", ()) if isinstance(round_record, dict)]}
    outlook = blocks_outlook([(index, data.get("outlook")) for index, data in summaries])
    if outlook is not None:
        summary["outlook"] = outlook
    ensure_dir(out_dir / BOOTSTRAP_DIR)
    atomic_write_text(out_dir / SUMMARY_FILE, json.dumps(json_safe(summary), indent=1) + "\n")


def summed_steps(summaries: Sequence[dict]) -> dict:
    """The step counts per kind ("real", a virtual branch, ...) of the blocks' summaries, added up."""
    total: dict = {}
    for data in summaries:
        steps = data.get("steps")
        for kind, count in (steps.items() if isinstance(steps, dict) else ()):
            if isinstance(count, int) and not isinstance(count, bool):
                total[kind] = total.get(kind, 0) + count
    return total


def blocks_outlook(outlooks: Sequence[tuple[int, object]]) -> dict | None:
    """One outlook (an Outlook's JSON) for the refined blocks' own ``[(block index, outlook JSON
    or None)]``: each block followed the outlook of its own curve, so the line names each block's;
    one block's figures are kept, several blocks' are not one figure. The verdict is the blocks'
    when they agree, else each block's in turn. None when no block recorded one."""
    said = [(index, outlook) for index, outlook in outlooks
            if isinstance(outlook, dict) and isinstance(outlook.get("line"), str)
            and isinstance(outlook.get("verdict"), str)]
    if not said:
        return None
    if len(said) == 1:
        index, outlook = said[0]
        return {**outlook, "line": f"block {index + 1}: {outlook['line']}"}
    verdicts = {outlook["verdict"] for _, outlook in said}
    return {"verdict": verdicts.pop() if len(verdicts) == 1 else
            "; ".join(f"block {index + 1}: {outlook['verdict']}" for index, outlook in said),
            "line": "; ".join(f"block {index + 1}: {outlook['line']}" for index, outlook in said)}
