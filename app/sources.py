"""What the viewer opens: a scene folder (its newest trained model, else its sparse points as
small splats), a model PLY, or a training run folder. Everything else is an InputError."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from inceptiongs.camera import Camera, camera_from_json_dict
from inceptiongs.constants import SH_C0, SH_OFFSET
from inceptiongs.errors import InputError

# Sparse points shown as splats get this radius relative to the points' robust extent:
# small enough to read as points, big enough to be visible at typical viewing distances.
POINT_SPLAT_RELATIVE_RADIUS = 0.002
# ... and this opacity (nearly opaque, below the renderers' ALPHA_MAX cap).
POINT_SPLAT_OPACITY = 0.95


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
    sparse_points: bool = False
    scene: object = None
    notes: list[str] = field(default_factory=list)


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


def _read_ply_arrays(path: Path) -> dict:
    from inceptiongs.io.ply import read_ply  # noqa: PLC0415 - keeps `--help` fast

    return read_ply(path).numpy()


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
    from inceptiongs.train.run_folder import load_run  # noqa: PLC0415

    gaussians, scene, _config = load_run(run_dir)
    model = run_dir / "model.ply"
    return ViewerSource("run", run_dir, gaussians.numpy(), list(scene.cameras), scene.work_dir,
                        model_path=model if model.is_file() else None, run_dir=run_dir, scene=scene)


def open_source(path: str | Path) -> ViewerSource:
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: does not exist")
    if path.is_file():
        if path.suffix.lower() != ".ply":
            raise InputError(f"{path}: not a scene folder, a .ply model or a run folder")
        return ViewerSource("ply", path, _read_ply_arrays(path), [], path.parent / ".inceptiongs",
                            model_path=path)
    from inceptiongs.scene.loader import load_scene  # noqa: PLC0415

    if (path / "config.json").is_file():
        return _open_run(path)
    try:
        scene = load_scene(path)
    except InputError as scene_error:
        model = newest_ply(path)
        if model is None:
            raise InputError(f"{path}: neither a scene folder ({scene_error}) nor a run folder "
                             f"(no .ply inside)") from None
        return ViewerSource("run", path, _read_ply_arrays(model), _cameras_json(path / "cameras.json"),
                            path, model_path=model)
    runs = [c.parent for c in scene.work_dir.rglob("config.json")
            if (c.parent / "model.ply").is_file() or (c.parent / "checkpoints").is_dir()]
    if runs:
        newest = max(runs, key=lambda run: max(p.stat().st_mtime for p in run.iterdir()))
        source = _open_run(newest)
        source.kind, source.path, source.work_dir = "scene", path, scene.work_dir
        return source
    return ViewerSource("scene", path, points_as_splats(scene.points, scene.point_colors),
                        list(scene.cameras), scene.work_dir, sparse_points=True, scene=scene,
                        notes=["no trained model yet: showing the sparse points"])
