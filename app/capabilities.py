"""What the open source cannot do, and why, in one line each: the panel greys those controls out
with the reason beside them, and the keys that would reach them answer with the same line.

A bare PLY has no cameras and no photos: coverage counts the cameras that see each Gaussian,
the reference mode compares the GL render with the torch renderer's at training-camera scale,
and training needs the photos. Pure: no GL, no imgui."""

from __future__ import annotations

NO_CAMERAS = "this model has no cameras (a bare PLY)"
# Render modes that need the source's cameras, and what each would have shown.
MODES_NEEDING_CAMERAS = {
    "coverage": "coverage counts the cameras that see each Gaussian",
    "reference": "the reference mode checks the render against the training cameras' torch render",
}


def mode_unavailable(mode: str, source) -> str | None:
    """Why render mode ``mode`` is off for ``source`` (a sources.ViewerSource), or None."""
    if mode in MODES_NEEDING_CAMERAS and not source.cameras:
        return f"{mode} mode is off: {NO_CAMERAS}; {MODES_NEEDING_CAMERAS[mode]}"
    return None


def training_unavailable(source) -> str | None:
    """Why "train (new run)" is off for ``source``, or None: training needs a scene's photos."""
    if source.scene is None:
        return f"training is off: {source.path} is a model without its scene's photos (open the scene folder or a run)"
    return None


def bootstrap_unavailable(source, run_dir) -> str | None:
    """Why "Bootstrap flagged views" is off, or None: it repairs a trained run of a scene, which
    a bare PLY has not (a scene without a run yet answers when pressed: train first)."""
    if run_dir is None and source.scene is None:
        return f"bootstrapping is off: it repairs a trained run of a scene, and {source.path} is a bare model"
    return None


def one_line(exc: BaseException) -> str:
    """The message the command line prints for ``exc`` (without its "error: "): an InputError's own
    sentence; any other exception's message, its class named only when the message is empty."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return text or type(exc).__name__
