"""Where the viewer writes what a user keeps: where the command line does, never the cache.

A stage-I job started from the viewer writes the run folder `inceptiongs train SCENE` writes
without --out, ``./runs/NAME`` in the current folder (then ``NAME_2``, ``NAME_3`` ...), or
``DIR/NAME`` in a runs folder the user picks (``inceptiongs-viewer --runs DIR``, or the Training
panel's field); a bootstrap of ``RUN`` writes ``RUN_bootstrap`` (then ``RUN_bootstrap_2`` ...), and the
same-time baseline a verdict offers ``RUN_baseline`` beside it.
Saved PLYs and screenshots go to ``NAME_saved`` in the same runs folder. Every job gets a folder
of its own, never one that exists; only "Resume" writes into an existing folder: the open run,
or the open bootstrap result stopped before its end, which the user chose. The cache (a scene's
work folder) keeps only what can be rebuilt."""

from __future__ import annotations

import os
from pathlib import Path

from inceptiongs.runs.checkpoint import latest_checkpoint
from inceptiongs.runs.folder import CLI_RUNS_FOLDER, SAVED_SUFFIX, default_run_dir

# Runs the viewer made in the scene's work folder (the cache) before it wrote where the
# command line does: still listed and opened.
TRAIN_RUN_NAME = "train"
BOOTSTRAP_SUFFIX = "_bootstrap"
BASELINE_SUFFIX = "_baseline"


def fresh_folder(base: Path) -> Path:
    """``base`` when nothing exists there, else the first free ``base_2``, ``base_3`` ..."""
    base = Path(base)
    if not base.exists():
        return base
    number = 2
    while base.with_name(f"{base.name}_{number}").exists():
        number += 1
    return base.with_name(f"{base.name}_{number}")


# A double extension a name keeps whole when it is numbered: edited.compressed_2.ply would be read
# as a plain PLY.
KEPT_SUFFIXES = (".compressed.ply",)


def fresh_file(path: Path) -> Path:
    """``path`` when nothing exists there, else the first free STEM_2.EXT, STEM_3.EXT ... (EXT
    whole: .compressed.ply stays one)."""
    path = Path(path)
    suffix = next((kept for kept in KEPT_SUFFIXES if path.name.lower().endswith(kept)), path.suffix)
    stem = path.name[:len(path.name) - len(suffix)]
    candidate, number = path, 2
    while candidate.exists():
        candidate = path.with_name(f"{stem}_{number}{suffix}")
        number += 1
    return candidate


def runs_folder(chosen: Path | None = None) -> Path:
    """The folder runs go to, absolute: ``chosen``, else ./runs in the current folder (as the
    command line's default run folders: runs.folder.default_run_dir)."""
    folder = Path(chosen).expanduser() if chosen is not None else Path.cwd() / CLI_RUNS_FOLDER
    return Path(os.path.abspath(folder))


def run_name(source) -> str:
    """NAME of a source's run folders: its scene folder's (as the command line names them), else
    the opened file's or folder's."""
    scene = getattr(source, "scene", None)
    if scene is not None:
        return default_run_dir(scene.root).name
    path = Path(source.path)
    return path.stem if path.is_file() else path.name


def new_train_dir(scene_root: Path, chosen: Path | None = None) -> Path:
    """A fresh stage-I run folder: the command line's default ./runs/NAME, or NAME in the runs
    folder the user chose."""
    default = default_run_dir(scene_root)
    return fresh_folder(default if chosen is None else runs_folder(chosen) / default.name)


def saved_dir(source, chosen: Path | None = None) -> Path:
    """Where saved PLYs and screenshots go by default: NAME_saved in the runs folder."""
    return runs_folder(chosen) / f"{run_name(source)}{SAVED_SUFFIX}"


def new_bootstrap_dir(run_dir: Path) -> Path:
    """A fresh stage-II output folder beside the run it repairs."""
    run_dir = Path(run_dir)
    return fresh_folder(run_dir.with_name(run_dir.name + BOOTSTRAP_SUFFIX))


def new_baseline_dir(run_dir: Path) -> Path:
    """A fresh same-time baseline folder beside the stage-I run it continues (RUN_baseline[_N],
    as `inceptiongs demo` names it)."""
    run_dir = Path(run_dir)
    return fresh_folder(run_dir.with_name(run_dir.name + BASELINE_SUFFIX))


def run_dir_of(source) -> Path | None:
    """The run folder a source shows (a run, or a scene opened at its newest run), else None."""
    run = source.run_dir
    return Path(run) if run is not None and (Path(run) / "config.json").is_file() else None


def can_resume(run_dir: Path | None) -> bool:
    """A stage-I run folder with a config and a checkpoint to continue from, or a bootstrap
    stopped before its end that can be continued (a finished bootstrap's result has a config and
    checkpoints too, but is not one: bootstrap_resume_refusal)."""
    if run_dir is None or not (Path(run_dir) / "config.json").is_file():
        return False
    if is_bootstrap_run(run_dir):
        return bootstrap_resume_refusal(run_dir) is None
    return latest_checkpoint(Path(run_dir)) is not None


def is_bootstrap_run(run_dir: Path | None) -> bool:
    """A stage-II result: a run folder with the bootstrap's own folder (its config) inside."""
    from inceptiongs.bootstrap.runner import BOOTSTRAP_DIR  # noqa: PLC0415 (torch only when asked)

    return run_dir is not None and (Path(run_dir) / BOOTSTRAP_DIR / "config.json").is_file()


def is_bootstrap_result(run_dir: Path | None) -> bool:
    """A stage-II output folder of either kind: an ordinary bootstrap's (is_bootstrap_run) or one
    of a run in blocks, whose bootstrap configs are its blocks' (RUN2/bootstrap holds the summary)."""
    from inceptiongs.bootstrap.summary_file import SUMMARY_FILE

    return run_dir is not None and (is_bootstrap_run(run_dir) or (Path(run_dir) / SUMMARY_FILE).is_file())


# The ways forward from a bootstrap result that "resume" does not continue.
BASELINE_NOT_RESUMED = ("this is a same-time baseline (stage I continued on the photos for its bootstrap's time): "
                        "resumed, it would run longer than its bootstrap and no verdict would count it; open its "
                        "stage-I run to train further")
REPAIR_NOT_RESUMED = ("resume continues stage-I training, which would undo this bootstrap's repair: "
                      "\"Bootstrap flagged views\" repairs it further (into a new folder), or open its stage-I run")
FINISHED_NOT_RESUMED = ("this bootstrap finished: nothing is left to resume (stage-I training would undo this "
                        "bootstrap's repair); \"Bootstrap flagged views\" repairs it further (into a new folder)")


def bootstrap_resume_refusal(run_dir: Path) -> str | None:
    """Why the bootstrap result in ``run_dir`` is not continued where it stopped (one phrase), or
    None when it is: a bootstrap (not a same-time baseline, not one of a run in blocks) whose
    summary says it was stopped before its end, with a checkpoint, that no other process writes."""
    from inceptiongs.bootstrap.runner import BLOCKS_NOT_RESUMED, TARGETS_FILE
    from inceptiongs.bootstrap.summary_file import BOOTSTRAP_DIR, read_summary
    from inceptiongs.runs.lock import writer_of

    writer = writer_of(run_dir)   # first: one being resumed elsewhere still holds the summary of its stop
    if writer is not None:
        return f"in use by {writer} (a job writing this folder): wait for it to end"
    summary = read_summary(run_dir) or {}
    no_targets = is_bootstrap_run(run_dir) and not (Path(run_dir) / BOOTSTRAP_DIR / TARGETS_FILE).is_file()
    if summary.get("baseline") is True or no_targets:   # the loop without targets
        return BASELINE_NOT_RESUMED
    if "blocks_refined" in summary:
        return f"{BLOCKS_NOT_RESUMED}; bootstrap its flagged views again (into a new folder)"
    if summary.get("stopped") is not True:
        return FINISHED_NOT_RESUMED if "iteration" in summary else REPAIR_NOT_RESUMED
    if latest_checkpoint(Path(run_dir)) is None:
        return "this bootstrap stopped before it saved a checkpoint: nothing to resume from; bootstrap it again"
    return None


def resume_blocked_reason(run_dir: Path | None) -> str | None:
    """Why "resume" is disabled for ``run_dir``, or None when it is offered (or not relevant).
    A bootstrap's result holds a stage-I config and checkpoints, so resuming it as a run would
    continue stage-I training on the repaired model, undoing what the virtual views taught it:
    what "resume" continues there is the bootstrap itself, when it was stopped before its end."""
    return bootstrap_resume_refusal(run_dir) if is_bootstrap_run(run_dir) else None


def describe_model(source, run_dir: Path | None) -> str:
    """What the window title names: the model file shown, or the run whose checkpoint is shown."""
    model = getattr(source, "model_path", None)
    if model is not None:
        return str(model)
    if run_dir is not None:
        return f"{run_dir} (newest checkpoint)"
    if getattr(source, "sparse_points", False):
        return f"{source.path} (sparse points, no model yet)"
    return str(source.path)


def window_title(source, run_dir: Path | None, training=None, out_dir: Path | None = None) -> str:
    """The window's title: the model shown, the file or the job folder it comes from (``training``:
    the live job, a live_training.LiveTraining, writing to ``out_dir``; None: no job yet)."""
    if training is not None and out_dir is not None:
        shown = f"{out_dir} ({training.state})"
    else:
        shown = describe_model(source, run_dir)
    return f"InceptionGS — {shown}"
