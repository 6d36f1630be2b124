"""Stage II: a stage-I run in, a repaired run folder out, as a pipeline: ``prepare.prepare``
(RUN2, the state, the round plan, the pool) -> ``loop.run_rounds`` -> ``loop.finish``.

RUN2 is a run folder (docs/training.md): config.json (the stage-I config, extended schedule),
split.json (copied, so evaluations are comparable), checkpoints/, model.ply, metrics.jsonl
(wall_s counted from the start of the bootstrap); plus RUN2/bootstrap/ (config.json,
summary.json, cache/, views/*.png) and RUN2/prior/ when a prior was trained here.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Callable, Sequence

from ..errors import InputError
from ..gaussians import Gaussians
from ..io.flags import FLAGS_FILE_NAME
from ..runs.lock import run_folder_lock
from ..threads import use_torch_threads
from ..train.loop import StepLoop, default_log, expected_total_steps  # noqa: F401 (expected_total_steps: re-exported)
from ..runs.folder import holds_result, next_free_folder
from .config import BootstrapConfig
from .loop import BootstrapResult, finish, run_rounds
from .plan import resume_point
from .prepare import TARGETS_FILE, prepare
from .stage1 import Stage1, as_stage1, load_stage1  # noqa: F401 (load_stage1: re-exported)
from .summary_file import BOOTSTRAP_DIR, read_summary  # noqa: F401 (BOOTSTRAP_DIR: re-exported)
from .targets import Target, flag_targets, named_target, split_targets


# Why `bootstrap --resume` and the viewer's resume refuse a bootstrap of a run in blocks: its blocks
# are refined one after the other into folders of their own and merged; RUN2 has no checkpoint of its own.
BLOCKS_NOT_RESUMED = "a bootstrap of a run in blocks is not resumed"


def default_out_dir(run_dir: str | Path) -> Path:
    run_dir = Path(run_dir)
    return run_dir.with_name(run_dir.name + "_bootstrap")


def check_default_out_dir(out_dir: Path) -> Path:
    """``out_dir`` when it may take a default output: the folder beside the input run belongs
    to whoever made that bundle, so a symlink there (which could send the model, checkpoints and
    logs anywhere) is refused in one line; an --out the user gives is their choice."""
    if out_dir.is_symlink():
        raise InputError(f"{out_dir}: the default output folder is a symlink (to {os.readlink(out_dir)}); "
                         f"give --out to choose where the bootstrap writes")
    return out_dir


def check_output_folder(out_dir: Path, overwrite: bool) -> None:
    """InputError (one line) when ``out_dir`` holds a result and the user did not ask to replace it."""
    if not holds_result(out_dir) or overwrite or killed_before_first_save(out_dir):
        return
    stopped = stopped_bootstrap_step(out_dir)
    if stopped is not None:
        raise InputError(f"{out_dir}: holds a stopped bootstrap (checkpoint at step {stopped}); give --resume to "
                         f"continue it, --overwrite to replace it, or another --out")
    raise InputError(f"{out_dir}: already holds a result; give --overwrite to replace it, or another "
                     f"--out (e.g. {next_free_folder(out_dir)})")


def killed_before_first_save(out_dir: Path) -> bool:
    """Whether ``out_dir`` holds only the start of a bootstrap killed before it saved anything
    (no model, no checkpoint): a rerun may start it again, since nothing there is a result."""
    from ..runs.checkpoint import list_checkpoints

    return ((out_dir / BOOTSTRAP_DIR).is_dir() and not (out_dir / "model.ply").exists()
            and not list_checkpoints(out_dir))


def stopped_bootstrap_step(out_dir: Path) -> int | None:
    """The newest checkpoint's step when ``out_dir`` holds a bootstrap that was stopped (its
    summary says so, or it has none: killed), else None."""
    from ..runs.checkpoint import list_checkpoints

    kept = list_checkpoints(out_dir)
    if not kept:
        return None
    summary = read_summary(out_dir) or {}
    ended = "iteration" in summary and summary.get("stopped") is not True
    return None if ended else kept[-1][0]


# --- inputs ----------------------------------------------------------------------------------------
def default_flag_files(scene, run_dir: str | Path | None = None) -> list[Path]:
    """Where the viewer's flags.json may be, first found wins: the run folder, ./runs/NAME_saved
    (where the viewer keeps them), the scene's cache folder (older viewers), then (read-only) the
    scene folder's .inceptiongs/ written by older versions."""
    from ..runs.folder import default_saved_dir

    found = [Path(run_dir) / FLAGS_FILE_NAME] if run_dir is not None else []
    found.append(default_saved_dir(scene.root) / FLAGS_FILE_NAME)
    with contextlib.suppress(InputError):
        found.append(Path(scene.work_dir) / FLAGS_FILE_NAME)
    return found + [Path(scene.legacy_work_dir) / FLAGS_FILE_NAME]


def resolve_targets(scene, split, targets_file: str | Path | None, target_view: str | None,
                    rounds: int, run_dir: str | Path | None = None) -> list[Target]:
    """--targets FILE, else --target-view NAME, else the viewer's flags.json when it exists
    (:func:`default_flag_files`), else j*."""
    train_cameras = [scene.cameras[i] for i in split.train]
    if targets_file is not None and target_view is not None:
        raise InputError("give either --targets or --target-view, not both")
    if targets_file is not None:
        return flag_targets(Path(targets_file), train_cameras)
    if target_view is not None:
        return [named_target(scene, target_view)]
    for default_flags in default_flag_files(scene, run_dir):
        if default_flags.is_file():
            return flag_targets(default_flags, train_cameras)
    return split_targets(split, scene, rounds)


# --- the loop --------------------------------------------------------------------------------------
def run_bootstrap(run: Stage1 | str | Path, out_dir: str | Path, targets: Sequence[Target] | None,
                  config: BootstrapConfig, control=None,
                  on_snapshot: Callable[[int, Gaussians, dict], None] | None = None, snapshot_every: int = 0,
                  log: Callable[[str], None] | None = None, progress: bool = True,
                  rasterizer=None, overwrite: bool = False, resume: bool = False) -> BootstrapResult:
    """Bootstrap RUN (a loaded :class:`Stage1`, or its folder) into RUN2 (see the module doc).
    ``targets=None`` with an empty pool is the same-time baseline: the stage-I loop continued on
    the photos alone (``baseline_run``). An ``out_dir`` that already holds a result is refused
    (InputError) unless ``overwrite`` (see ``inceptiongs.runs.folder.next_free_folder`` for
    a fresh name instead). ``resume``: continue the stopped bootstrap in ``out_dir`` from its newest
    checkpoint, with its saved targets (``targets`` is then ignored). ``rasterizer``
    (inceptiongs.rasterizer.interface.Rasterizer) defaults to the one the stage-I run's device
    selects."""
    config.validate()
    use_torch_threads()
    out_dir = Path(out_dir)
    if out_dir.resolve() == Path(run if not isinstance(run, Stage1) else run.run_dir).resolve():
        raise InputError(f"{out_dir}: the output folder must differ from the input run")
    with run_folder_lock(out_dir):   # one writer per run folder (a second gets one line naming the first)
        return _run_bootstrap(run, out_dir, targets, config, control, on_snapshot, snapshot_every, log, progress,
                              rasterizer, overwrite, resume)


def run_rasterizer(run: Stage1, log: Callable[[str], None]):
    """The rasterizer the stage-I run's recorded device selects (the one device rule,
    resolve_device); "auto" logs which and why."""
    from ..rasterizer.interface import resolve_device

    device = resolve_device(run.config.device, f"{run.run_dir / 'config.json'}: device")
    if device.note:
        log(device.note)
    return device.rasterizer


def _run_bootstrap(run, out_dir: Path, targets, config: BootstrapConfig, control, on_snapshot, snapshot_every: int,
                   log, progress: bool, rasterizer, overwrite: bool, resume: bool) -> BootstrapResult:
    payload = None
    if resume:
        payload, targets = resumable(out_dir)
    else:
        check_output_folder(out_dir, overwrite)
    run = as_stage1(run)
    if rasterizer is None:
        rasterizer = run_rasterizer(run, log or default_log)
    baseline = targets is None
    # A time-budgeted run's bar shows the steps its measured rate fits into the budget.
    loop = StepLoop(control, total=config.rounds * config.iterations, desc="baseline" if baseline else "bootstrap",
                    progress=progress, budget_s=None if config.minutes is None else 60.0 * config.minutes,
                    on_snapshot=on_snapshot, snapshot_every=snapshot_every,
                    wall_start_s=float(payload["wall_s"]) if payload else 0.0,
                    train_start_s=float(payload["train_s"]) if payload else 0.0)
    log = log or default_log
    setting, plan, state, pool = prepare(run, out_dir, targets, config, loop, rasterizer, log, resume=payload)
    first_round, steps_left = 0, None
    if payload is not None:
        point = resume_point(plan, state.train.iteration, payload["bootstrap"]["round"])
        first_round, steps_left, state.rounds_done = point.first_round, point.steps_left, point.rounds_done
        if steps_left is not None:
            log(f"resumed at step {state.train.iteration} (round {first_round + 1}, {steps_left} steps of it left)")
        spent_s = float(payload["wall_s"])
        if config.minutes is not None and spent_s >= 60.0 * config.minutes:   # else it ends with no step, unsaid
            log(f"its budget of {config.minutes:g} min was spent before it stopped ({spent_s:.0f} s): no step will "
                f"be made; give --minutes more than {spent_s / 60.0:.2f} to go on")
    try:
        run_rounds(setting, config, plan, state, pool, first_round, steps_left)
    finally:
        loop.close()
    return finish(setting, config, plan, state, pool)


def resumable(out_dir: Path) -> tuple[dict, list[Target] | None]:
    """The newest checkpoint of the stopped bootstrap in ``out_dir`` and its targets (None: the
    same-time baseline); InputError (one line) when there is nothing to continue."""
    from ..runs.checkpoint import latest_checkpoint, load_newest_checkpoint

    if latest_checkpoint(out_dir) is None:
        raise InputError(f"{out_dir}: no bootstrap checkpoint to resume from (run `inceptiongs bootstrap` "
                         f"without --resume)")
    path, payload = load_newest_checkpoint(out_dir)
    if not isinstance(payload.get("bootstrap"), dict) or "round" not in payload["bootstrap"]:
        raise InputError(f"{path}: not a bootstrap checkpoint (a stage-I run is continued by `inceptiongs train "
                         f"--resume`)")
    return payload, saved_targets(out_dir)


def saved_targets(out_dir: Path) -> list[Target] | None:
    """The targets the bootstrap in ``out_dir`` was started with (RUN2/bootstrap/targets.json;
    None: it has none, a same-time baseline); InputError (one line) when the file is unreadable."""
    import json

    from .targets import targets_from_json

    targets_path = Path(out_dir) / BOOTSTRAP_DIR / TARGETS_FILE
    if not targets_path.is_file():
        return None
    try:
        data = json.loads(targets_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{targets_path}: cannot read the bootstrap's targets ({exc})") from None
    return targets_from_json(data, str(targets_path))


def baseline_run(run: Stage1 | str | Path, out_dir: str | Path, minutes: float | None, iterations: int,
                 seed: int = 0, progress: bool = True, log=None, eval_every: int = 0,
                 overwrite: bool = False, rasterizer=None) -> BootstrapResult:
    """Stage I continued on the photos alone, with the same continuation schedule the bootstrap
    uses, for ``minutes`` (the bootstrap's total time) or ``iterations``: the comparison baseline."""
    config = BootstrapConfig(seed=seed, iterations=iterations, minutes=minutes, rounds=1, log_every=1,
                             eval_every=eval_every)
    return run_bootstrap(run, out_dir, None, config, progress=progress, log=log, overwrite=overwrite,
                         rasterizer=rasterizer)
