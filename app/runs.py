"""Where the viewer's jobs write: every job gets a folder of its own, never one that exists.

A stage-I job started from the viewer writes ``<scene work dir>/runs/train`` (then ``train_2``,
``train_3`` ...); a bootstrap of ``RUN`` writes ``RUN_bootstrap`` (then ``RUN_bootstrap_2`` ...).
Only "Resume" writes into an existing folder: the open run, which the user chose."""

from __future__ import annotations

from pathlib import Path

from inceptiongs.train.checkpoint import latest_checkpoint

# The viewer's stage-I runs sit where `inceptiongs train` puts its default run.
TRAIN_RUN_NAME = "train"
BOOTSTRAP_SUFFIX = "_bootstrap"


def fresh_folder(base: Path) -> Path:
    """``base`` when nothing exists there, else the first free ``base_2``, ``base_3`` ..."""
    base = Path(base)
    if not base.exists():
        return base
    number = 2
    while base.with_name(f"{base.name}_{number}").exists():
        number += 1
    return base.with_name(f"{base.name}_{number}")


def new_train_dir(work_dir: Path) -> Path:
    """A fresh stage-I run folder in the scene's work folder."""
    return fresh_folder(Path(work_dir) / "runs" / TRAIN_RUN_NAME)


def new_bootstrap_dir(run_dir: Path) -> Path:
    """A fresh stage-II output folder beside the run it repairs."""
    run_dir = Path(run_dir)
    return fresh_folder(run_dir.with_name(run_dir.name + BOOTSTRAP_SUFFIX))


def run_dir_of(source) -> Path | None:
    """The run folder a source shows (a run, or a scene opened at its newest run), else None."""
    run = source.run_dir
    return Path(run) if run is not None and (Path(run) / "config.json").is_file() else None


def can_resume(run_dir: Path | None) -> bool:
    """A stage-I run folder with a config and a checkpoint to continue from (a bootstrap's
    result has both, but is not one: resume_blocked_reason)."""
    return (run_dir is not None and (Path(run_dir) / "config.json").is_file()
            and latest_checkpoint(Path(run_dir)) is not None and not is_bootstrap_run(run_dir))


def is_bootstrap_run(run_dir: Path | None) -> bool:
    """A stage-II result: a run folder with the bootstrap's own folder (its config) inside."""
    from inceptiongs.bootstrap.runner import BOOTSTRAP_DIR  # noqa: PLC0415 (torch only when asked)

    return run_dir is not None and (Path(run_dir) / BOOTSTRAP_DIR / "config.json").is_file()


def resume_blocked_reason(run_dir: Path | None) -> str | None:
    """Why "resume" is disabled for ``run_dir``, or None when it is offered (or not relevant).
    A bootstrap's result holds a stage-I config and checkpoints, so resuming it would continue
    stage-I training on the repaired model, undoing what the virtual views taught it, and the
    bootstrap itself cannot continue from a checkpoint."""
    if is_bootstrap_run(run_dir):
        return ("resume continues stage-I training, which would undo this bootstrap's repair: "
                "\"Bootstrap flagged views\" repairs it further (into a new folder), or open its stage-I run")
    return None


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
