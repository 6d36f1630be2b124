"""Saving the edited model: the shown Gaussians written to a model file in the format its name
says (.ply, .compressed.ply, .splat, .spz) in the user's frame (a scene's original frame, as the
trainer's model.ply), never over an existing file nor into the scene folder, with the up and
the camera it was seen with beside it (sources.saved_view_file), so the file reopens level and
where it was seen."""

from __future__ import annotations

import json
from pathlib import Path

from inceptiongs.errors import InputError

from .runs import fresh_file, saved_dir


def write_saved_view(model: Path, view) -> None:
    """sources.saved_view_file(model): the up and the camera ``view`` (view.View) shows, in the
    model file's frame (its shape alone may say another up: the courtyard's edit reopened 32
    degrees tilted, seen from below)."""
    from inceptiongs.io.atomic import atomic_write_text  # noqa: PLC0415

    from .sources import saved_view_file  # noqa: PLC0415

    camera = view.current_camera()
    scene = view.source.scene
    if scene is not None:   # the normalisation is a shift and a scale: the up is unchanged
        camera = scene.normalization.camera_to_original(camera)
    data = {"up": [float(v) for v in view.up], "camera": camera.to_json_dict()}
    atomic_write_text(saved_view_file(model), json.dumps(data, indent=1))


class EditSaver:
    """The Edit panel's "file" field and "save PLY" for the model ``view`` (view.View) shows;
    ``status``: the status line. ``path``: the field's text; it offers a new file in the visible
    NAME_saved folder beside the runs, and after each save the next free name of the same series
    (edited.ply, edited_2.ply ...)."""

    def __init__(self, view, status) -> None:
        self.view, self.status = view, status
        self.series = saved_dir(view.source, getattr(view.source, "runs_dir", None)) / "edited.ply"
        self.path = self.offered = str(fresh_file(self.series))

    def save_ply(self, path: str | Path) -> Path:
        """Write the shown Gaussians (atomic) to ``path``, or to the first free name after it
        when it exists (runs.fresh_file: a save never replaces one); the "file" field then
        offers the next free name. Models of a scene are stored in the scene's original frame,
        like the trainer's model.ply. -> the file written."""
        from inceptiongs.gaussians import Gaussians  # noqa: PLC0415 (torch only when saving)
        from inceptiongs.io.models import write_format, write_model  # noqa: PLC0415

        source = self.view.source
        scene = source.scene
        typed = Path(path).expanduser()
        # The format the name says (.ply, .compressed.ply, .splat, .spz), as `convert` writes it:
        # a typed .splat got a PLY under that name, which no .splat reader opens. InputError for
        # a name that is no model file, before anything is written.
        write_format(typed)
        # A save never replaces a file: the first free name of the series (name_2.ply ...).
        path = fresh_file(typed)
        if scene is not None and Path(scene.root).resolve() in [path.resolve(), *path.resolve().parents]:
            raise InputError(f"{path}: inside the scene folder {scene.root}, which is input and never written; "
                             f"save elsewhere (the default is {saved_dir(source, getattr(source, 'runs_dir', None))})")
        gaussians = Gaussians.from_numpy(self.view.edit.visible_arrays())
        if scene is not None:  # everything shown for a scene or run is in its normalised frame
            gaussians = scene.normalization.gaussians_to_original(gaussians)
        path.parent.mkdir(parents=True, exist_ok=True)
        written = write_model(path, gaussians)
        write_saved_view(path, self.view)
        if str(typed) != self.offered:   # a name the user typed starts a series of its own
            self.series = typed
        self.path = self.offered = str(fresh_file(self.series))
        kept = f" ({typed.name} exists: kept)" if path != typed else ""
        # What the format dropped or clamped, without the path the line has just named.
        notes = "".join(f"; {note.removeprefix(f'{path}: ')}" for note in written.notes)
        self.status.text = f"saved {len(gaussians)} Gaussians to {path}{kept}{notes}"
        return Path(path)
