"""What the viewer opens: a scene folder (its newest trained model, else its sparse points as
small splats), a model file (.ply, .compressed.ply, .splat, .spz), or a training run folder.
Everything else is an InputError."""

from __future__ import annotations

import json
import math
import threading
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from inceptiongs.camera import Camera, camera_from_json_dict
from inceptiongs.constants import SH_C0, SH_OFFSET
from inceptiongs.errors import InputError
from inceptiongs.io.cache import scene_cache_dir

from .capabilities import one_line
from .runs import runs_folder, saved_dir

# Sparse points shown as splats get this radius relative to the points' robust extent:
# small enough to read as points, big enough to be visible at typical viewing distances.
POINT_SPLAT_RELATIVE_RADIUS = 0.002
# ... and this opacity (nearly opaque, below the renderers' ALPHA_MAX cap).
POINT_SPLAT_OPACITY = 0.95
# Scenes without sparse points are triangulated from photos at most this wide (fern: 20 photos
# at 504 px, ~2200 points, ~11 s of CPU once; cached).
TRIANGULATE_MAX_WIDTH = 640


@dataclass
class ViewerSource:
    """kind: "scene" | "ply" | "run"; gaussians: arrays keyed like Gaussians.numpy();
    cameras: training cameras (possibly empty); work_dir: where flags.json lives."""

    kind: str
    path: Path
    gaussians: dict
    cameras: list[Camera]
    work_dir: Path
    model_path: Path | None = None
    run_dir: Path | None = None  # the stage-I/II run folder shown (for Resume and Bootstrap)
    points_pending: bool = False  # a scene without sparse points: PointsWorker triangulates some
    sparse_points: bool = False
    scene: object = None
    notes: list[str] = field(default_factory=list)
    runs: list[Path] = field(default_factory=list)  # a scene's runs (sources.scene_runs), oldest first
    runs_dir: Path | None = None  # the runs folder the user chose (--runs); None: ./runs (runs.runs_folder)
    # A saved edit's view (saved_view_file): the world up [3] and the camera it was saved from.
    saved_up: np.ndarray | None = None
    saved_camera: Camera | None = None


def points_as_splats(points: np.ndarray, colors: np.ndarray | None) -> dict:
    """points: [P, 3], colors: [P, 3] uint8 or None -> isotropic degree-0 Gaussians (arrays)."""
    points = np.asarray(points, np.float32)
    count = len(points)
    if count:
        lo, hi = np.percentile(points, [5, 95], axis=0)
        extent = float(max(np.linalg.norm(hi - lo), 1e-6))  # floor: a single point has no extent
    else:
        extent = 1.0
    radius = POINT_SPLAT_RELATIVE_RADIUS * extent
    rgb = np.full((count, 3), 0.8, np.float32) if colors is None else np.asarray(colors, np.float32) / 255.0
    logit = math.log(POINT_SPLAT_OPACITY / (1.0 - POINT_SPLAT_OPACITY))
    quats = np.zeros((count, 4), np.float32)
    quats[:, 0] = 1.0
    return {
        "means": points,
        "log_scales": np.full((count, 3), math.log(radius), np.float32),
        "quats": quats,
        "opacity_logits": np.full(count, logit, np.float32),
        "sh": ((rgb - SH_OFFSET) / SH_C0)[:, None, :].astype(np.float32),
    }


def newest_ply(folder: Path) -> Path | None:
    """The most recently written *.ply under ``folder`` (recursive), or None."""
    if not folder.is_dir():
        return None
    plies = [p for p in folder.rglob("*.ply") if p.is_file()]
    return max(plies, key=lambda p: p.stat().st_mtime) if plies else None


def _read_ply(path: Path):
    """Any model file (inceptiongs.io.models), whatever its format."""
    from inceptiongs.io.models import read_model  # noqa: PLC0415 - keeps `--help` fast

    return read_model(path)


def _read_ply_arrays(path: Path) -> dict:
    return _read_ply(path).numpy()


def _newest_time(run: Path) -> float:
    return max((p.stat().st_mtime for p in run.iterdir()), default=run.stat().st_mtime)


def work_dir_runs(work_dir: Path) -> list[Path]:
    """Run folders (config.json with a model or checkpoints) anywhere in a scene's work folder:
    the viewer's jobs (runs/train[_N], their _bootstrap folders)."""
    work_dir = Path(work_dir)
    if not work_dir.is_dir():
        return []
    return sorted(c.parent for c in work_dir.rglob("config.json")
                  if (c.parent / "model.ply").is_file() or (c.parent / "checkpoints").is_dir())


def folder_runs(folder: Path, scene_root: Path) -> list[Path]:
    """The runs of the scene at ``scene_root`` in a runs folder the user named (whatever their
    folder names: `inceptiongs train --out DIR/anything`), ``folder`` itself included."""
    from inceptiongs.runs.folder import is_run_of  # noqa: PLC0415

    folder = Path(folder)
    if not folder.is_dir():
        return []
    candidates = [folder, *(child for child in folder.iterdir() if child.is_dir())]
    return [run for run in candidates if is_run_of(run, scene_root)]


def scene_runs(scene, runs_dir: Path | None = None) -> list[Path]:
    """Every run of a scene the viewer knows of, oldest first: the command line's under
    ./runs/NAME (`inceptiongs train` without --out, the bootstrap's NAME_bootstrap beside it, the
    viewer's jobs); those in the runs folder ``runs_dir`` the user named (--runs); and those the
    viewer once kept in the scene's work folder; and the folders beside the scene's own (the
    layout `inceptiongs demo OUT` writes: OUT/scene, OUT/run, OUT/run_bootstrap) — only runs whose
    config names this scene."""
    from inceptiongs.runs.folder import cli_run_dirs  # noqa: PLC0415

    runs = set(work_dir_runs(scene.work_dir)) | set(cli_run_dirs(scene.root))
    runs |= set(folder_runs(Path(scene.root).parent, scene.root))
    if runs_dir is not None:
        runs |= set(folder_runs(runs_folder(runs_dir), scene.root))
    return oldest_first(runs)


def oldest_first(runs) -> list[Path]:
    """Run folders by the time of their newest file, oldest first (one gone since: first)."""
    return sorted(set(runs), key=lambda run: _newest_time(run) if Path(run).is_dir() else 0.0)


def newest_model(work_dir: Path, runs: list[Path] | None = None, saved: Path | None = None) -> Path | None:
    """The newest model of a scene: a run's ``config.json`` (``runs``, default those in the work
    folder; a run's time is its newest file's) or a PLY the viewer saved (in the folder ``saved``,
    or in the work folder outside any run), whichever was written last; None when there is neither."""
    work_dir = Path(work_dir)
    runs = work_dir_runs(work_dir) if runs is None else list(runs)
    candidates = [(_newest_time(run), run / "config.json") for run in runs]
    for folder in (work_dir, saved):
        if folder is not None and Path(folder).is_dir():
            candidates += [(p.stat().st_mtime, p) for p in Path(folder).rglob("*.ply")
                           if p.is_file() and not (set(p.parents) & set(runs))]
    return max(candidates, key=lambda item: item[0])[1] if candidates else None


def saved_view_file(model: Path) -> Path:
    """NAME.view.json beside a saved edit NAME.ply, NAME.EXT.view.json beside another format's
    (web.splat and web.spz saved side by side shared one web.view.json): the up and the camera it
    was saved with, so it reopens level and where it was seen (a model alone only guesses its up
    from its shape)."""
    model = Path(model)
    if model.suffix.lower() == ".ply":
        return model.with_name(model.stem + ".view.json")
    return model.with_name(model.name + ".view.json")


def read_saved_view(model: Path) -> tuple[np.ndarray | None, Camera | None, str | None]:
    """(up [3] unit, camera, None) from saved_view_file(model); (None, None, None) when there is
    none; (None, None, the problem) when it cannot be used: the model still opens, guessed."""
    path = saved_view_file(model)
    if not path.is_file():
        return None, None, None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        up = np.asarray(data["up"], np.float64).reshape(3)
        norm = float(np.linalg.norm(up))
        if not np.isfinite(norm) or norm < 1e-6:   # a zero or broken up has no direction
            raise ValueError("its up is not a direction")
        return up / norm, camera_from_json_dict(data["camera"], str(path)), None
    except (OSError, ValueError, KeyError, TypeError, InputError) as exc:
        return None, None, f"{path}: not a readable saved view ({exc}); the view is guessed from the model"


def _cameras_json(path: Path) -> list[Camera]:
    """A run folder's cameras.json: a list of camera JSON objects (optional)."""
    if not path.is_file():
        return []
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable cameras file ({exc})") from None
    if not isinstance(data, list):
        raise InputError(f"{path}: cameras file must be a list of camera objects")
    return [camera_from_json_dict(entry, f"{path} (camera {i})") for i, entry in enumerate(data)]


def _open_run(run_dir: Path) -> ViewerSource:
    """A trainer run folder: its model (normalised frame) with its scene's cameras."""
    from inceptiongs.runs.load import load_run  # noqa: PLC0415

    gaussians, scene, _config = load_run(run_dir)
    model = run_dir / "model.ply"
    return ViewerSource("run", run_dir, gaussians.numpy(), list(scene.cameras), scene.work_dir,
                        model_path=model if model.is_file() else None, run_dir=run_dir, scene=scene)


def open_scene_run(scene_path: Path, work_dir: Path, runs: list[Path], run_dir: Path,
                   runs_dir: Path | None = None) -> ViewerSource:
    """A scene folder shown at one of its runs (``runs``: all of them, for the panel's list)."""
    source = _open_run(Path(run_dir))
    source.kind, source.path, source.work_dir, source.runs = "scene", Path(scene_path), Path(work_dir), list(runs)
    source.runs_dir = runs_dir
    return source


def not_a_source_message(path: Path, scene_error: InputError) -> str:
    """The one line for a folder that is neither a scene nor a run: the scene loader's reason,
    its "PATH: " prefix dropped when it names the folder itself (said once, not nested)."""
    reason = str(scene_error)
    prefix = f"{path}: "
    if reason.startswith(prefix):
        return f"{path}: {reason[len(prefix):]}, and no .ply model or run inside"
    return f"{path}: not a scene ({reason}), and no .ply model or run inside"


def open_source(path: str | Path, runs_dir: Path | None = None, say=None) -> ViewerSource:
    """The viewer's source for ``path``; ``runs_dir``: the runs folder the user named (--runs),
    where new runs go and whose runs of the scene are listed (None: ./runs); ``say``: called with
    what is being read, each time that changes (the opening window shows it: loading.py)."""
    source = _open_source(Path(path), runs_dir, say or (lambda text: None))
    source.runs_dir = runs_dir
    return source


# Folders a run keeps inside itself: opened by mistake, the bootstrap's (its config.json) was read
# as a run and refused with "unknown key 'agreement_min_db'; docs/train_options.md lists the keys".
RUN_INNER_FOLDERS = ("bootstrap", "checkpoints", "prior")


def check_not_inside_a_run(path: Path) -> None:
    """InputError naming the run when the folder ``path`` is one a run keeps inside itself."""
    run = path.absolute().parent
    if path.name in RUN_INNER_FOLDERS and (run / "config.json").is_file() and (run / "split.json").is_file():
        raise InputError(f"{path}: the {path.name} folder inside the run {path.parent}; open the run itself: "
                         f"inceptiongs-viewer {path.parent}")


def check_openable(path: str | Path) -> None:
    """InputError (the line open_source would give) when ``path`` is clearly nothing the viewer
    opens: missing, a file that is no model file, a folder that is neither a run, a scene nor holds
    a .ply. Cheap (no model is read), so bad input is one line before any window opens."""
    from inceptiongs.io.models import is_model_file  # noqa: PLC0415
    from inceptiongs.scene.loader import detect_format  # noqa: PLC0415

    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: does not exist")
    if path.is_file():
        if not is_model_file(path):
            raise InputError(f"{path}: not a scene folder, a model file (.ply, .splat, .spz) or a run folder")
        return
    check_not_inside_a_run(path)
    if (path / "config.json").is_file():
        return
    try:
        detect_format(path)
    except InputError as scene_error:
        if newest_ply(path) is None:
            raise InputError(not_a_source_message(path, scene_error)) from None


def _megabytes(path: Path) -> str:
    try:
        return f"{path.stat().st_size / 1e6:,.0f} MB"
    except OSError:
        return "size unknown"


def _open_source(path: Path, runs_dir: Path | None, say) -> ViewerSource:
    from inceptiongs.io.models import is_model_file  # noqa: PLC0415

    if not path.exists():
        raise InputError(f"{path}: does not exist")
    if path.is_file():
        if not is_model_file(path):
            raise InputError(f"{path}: not a scene folder, a model file (.ply, .splat, .spz) or a run folder")
        say(f"reading the model {path.name} ({_megabytes(path)})")
        up, camera, problem = read_saved_view(path)
        # The folder beside a user's PLY is input too: flags and screenshots go to the cache.
        return ViewerSource("ply", path, _read_ply_arrays(path), [], scene_cache_dir(path, [path]),
                            model_path=path, saved_up=up, saved_camera=camera, notes=[problem] if problem else [])
    from inceptiongs.scene.loader import load_scene  # noqa: PLC0415

    check_not_inside_a_run(path)
    if (path / "config.json").is_file():
        say(f"reading the run {path.name}: its model and its scene's cameras")
        return _open_run(path)
    say(f"reading the scene {path.name}: its cameras and sparse points")
    try:
        scene = load_scene(path)
    except InputError as scene_error:
        model = newest_ply(path)
        if model is None:
            raise InputError(not_a_source_message(path, scene_error)) from None
        return ViewerSource("run", path, _read_ply_arrays(model), _cameras_json(path / "cameras.json"),
                            path, model_path=model)
    say(f"reading the scene {path.name}: {len(scene.cameras)} cameras read; looking for its runs")
    runs = scene_runs(scene, runs_dir)
    newest = newest_model(scene.work_dir, runs, saved_dir(SimpleNamespace(scene=scene, path=path), runs_dir))
    if newest is not None and newest.name == "config.json":
        say(f"reading the newest of {len(runs)} run(s) of {path.name}: {newest.parent} "
            f"({_megabytes(newest.parent / 'model.ply')})")
        source = open_scene_run(path, scene.work_dir, runs, newest.parent, runs_dir)
        source.notes.append(f"opened the newest of {len(runs)} run(s) of this scene: {newest.parent}")
        return source
    if newest is not None:  # a PLY saved in the work folder (the viewer's "save PLY"): original frame
        say(f"reading the newest model of {path.name}: {newest} ({_megabytes(newest)})")
        gaussians = scene.normalization.gaussians_to_normalized(_read_ply(newest))
        return ViewerSource("scene", path, gaussians.numpy(), list(scene.cameras), scene.work_dir,
                            model_path=newest, scene=scene, runs=runs,
                            notes=[f"opened the newest model in {scene.work_dir}: {newest.name}"])
    if len(scene.points) == 0:
        return ViewerSource("scene", path, points_as_splats(scene.points, None), list(scene.cameras),
                            scene.work_dir, sparse_points=True, scene=scene, points_pending=True, runs=runs,
                            notes=["no trained model and no sparse points: triangulating points from the "
                                   "photos (the cameras are shown meanwhile)..."])
    return ViewerSource("scene", path, points_as_splats(scene.points, scene.point_colors),
                        list(scene.cameras), scene.work_dir, sparse_points=True, scene=scene, runs=runs,
                        notes=["no trained model yet: showing the sparse points"])


def triangulated_splats(scene_root: Path) -> tuple[dict | None, str]:
    """Points triangulated from a scene's photos with its known poses (as stage I starts an
    LLFF scene; cached in the work folder), as splats, and the status line saying so. (None,
    reason) when too few points come out. Photos at most TRIANGULATE_MAX_WIDTH wide: the
    points only need to show where the scene is."""
    from inceptiongs.scene.loader import load_scene  # noqa: PLC0415
    from inceptiongs.scene.photo_store import photo_tensor  # noqa: PLC0415
    from inceptiongs.train.triangulate import cached_triangulation  # noqa: PLC0415

    scene = load_scene(scene_root, max_width=TRIANGULATE_MAX_WIDTH)
    # Photos read one at a time (from the decoded-photo cache), never all at once.
    points, colors, _ = cached_triangulation(scene.work_dir, scene.cameras, lambda i: photo_tensor(scene, i))
    if len(points) == 0:
        return None, ("no trained model and no sparse points, and no points could be triangulated from the "
                      "photos: showing the cameras only (train to get a model)")
    return (points_as_splats(points, colors),
            f"no trained model and no sparse points: showing {len(points)} points triangulated from the photos")


class PointsWorker:
    """triangulated_splats on a background thread, so the window opens at once."""

    def __init__(self, scene_root: Path) -> None:
        self.result: tuple[dict | None, str] | None = None
        self._thread = threading.Thread(target=self._run, args=(Path(scene_root),), name="inceptiongs-points",
                                        daemon=True)
        self._thread.start()

    def _run(self, scene_root: Path) -> None:
        try:
            self.result = triangulated_splats(scene_root)
        except Exception as exc:  # noqa: BLE001 - shown in the status line, the viewer keeps going
            self.result = (None, f"no sparse points, and triangulating some failed: {one_line(exc)}")

    @property
    def done(self) -> bool:
        return self.result is not None
