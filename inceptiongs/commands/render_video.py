"""``inceptiongs render MODEL (--path path.json | --orbit) --out video.mp4|.webm [--fps F]``.

The frames of a camera path (inceptiongs.camera_path; poses in the model file's frame, as
``--camera``) or of an orbit around what the training cameras look at are drawn one by one by
the GL renderer in one offscreen context (``inceptiongs.frame_renderers``; ``--backend torch``
draws them with the library's rasterizer) and encoded as they come (inceptiongs.io.video), a
progress bar on stderr. A model of at least VIDEO_LOD_MIN_GAUSSIANS draws, per frame, the cut
of its level-of-detail hierarchy at SETTLED_GRANULARITY_PX blended towards the parents (the
viewer's still frames; the hierarchy built once, cached by content); --lod / --lod-budget choose
the cut for any model."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ..camera_path import DEFAULT_FPS, FPS_MAX, CameraPath, orbit_path, path_cameras, read_path_json
from ..errors import InputError
from ..io.video import check_video_path, open_video
from . import render as render_image
from .render import HELP as IMAGE_HELP
from .render import add_arguments  # noqa: F401 - the command's arguments are render's

HELP = IMAGE_HELP + "; or a video (--path path.json | --orbit) to .mp4/.webm"

# The viewer draws a level-of-detail cut above this many Gaussians (app/detail.py's
# LOD_MIN_GAUSSIANS), its still frames at this granularity (SETTLED_GRANULARITY_PX).
VIDEO_LOD_MIN_GAUSSIANS = 500_000
SETTLED_GRANULARITY_PX = 1.0
FRAME_RENDERERS = "inceptiongs.frame_renderers"


def model_and_cameras(model_arg: str, scene_arg: str | None):
    """(Gaussians in the model file's own frame, training cameras in that frame (possibly
    none)) of a model file or a run folder; a run's scene gives the cameras."""
    from ..io.models import read_model
    from .render import run_scene_path, find_model_ply

    model = Path(model_arg)
    if not model.exists():
        raise InputError(f"{model}: model does not exist")
    run_dir = model if model.is_dir() else None
    ply = find_model_ply(model) if run_dir else model
    scene_path = scene_arg or (run_scene_path(run_dir) if run_dir else None)
    scene = None
    if scene_path:
        from ..scene.loader import load_scene
        scene = load_scene(scene_path, require_images=False)
    if ply is None:
        if run_dir is None or scene is None:
            raise InputError(f"{model}: no .ply model in the run folder")
        from ..runs.load import load_run
        gaussians, scene, _ = load_run(run_dir)  # newest checkpoint, normalised frame
        gaussians = scene.normalization.gaussians_to_original(gaussians)
    else:
        gaussians = read_model(ply)
    cameras = [scene.normalization.camera_to_original(c) for c in scene.cameras] if scene is not None else []
    return gaussians, cameras


def model_bounds(gaussians) -> tuple[np.ndarray, float]:
    """(median [3], half the 2-98 % box diagonal) of the means: the model's robust middle and size."""
    means = gaussians.means.detach().cpu().numpy().astype(np.float64)
    means = means[:: max(len(means) // 200_000, 1)]
    if len(means) == 0:
        return np.zeros(3), 1.0
    low, high = np.percentile(means, [2, 98], axis=0)
    return np.median(means, axis=0), float(max(0.5 * np.linalg.norm(high - low), 1e-3))


def video_path(args, gaussians, cameras) -> CameraPath:
    """The path of --path, or the orbit of --orbit (--seconds long), at --fps when given."""
    if args.fps is not None and not 0.0 < args.fps <= FPS_MAX:
        raise InputError(f"--fps: must be in (0, {FPS_MAX:g}], got {args.fps:g}")
    if args.path:
        path = read_path_json(args.path)
    else:
        if not 0.0 < args.seconds <= 600.0:
            raise InputError(f"--seconds: the orbit must last (0, 600] seconds, got {args.seconds:g}")
        center, radius = model_bounds(gaussians)
        path = orbit_path(cameras, center, radius, args.width or 1280, args.height or 720, args.seconds,
                          args.fps or DEFAULT_FPS)
    if args.fps is not None:
        path = CameraPath(path.keyframes, path.width, path.height, float(args.fps))
    if args.path and (args.width or args.height):
        width = args.width or max(1, round(path.width * args.height / path.height))
        height = args.height or max(1, round(path.height * args.width / path.width))
        path = CameraPath(path.keyframes, width, height, path.fps)
    return path


class DetailCuts:
    """Per frame, the Gaussians to draw: the model itself, or its level-of-detail cut (the
    hierarchy built once)."""

    def __init__(self, gaussians, granularity_px: float | None, budget: int | None) -> None:
        self.gaussians, self.granularity_px, self.budget = gaussians, granularity_px, budget
        if granularity_px is None and budget is None and len(gaussians) >= VIDEO_LOD_MIN_GAUSSIANS:
            self.granularity_px = SETTLED_GRANULARITY_PX
        self.tree = None
        if self.granularity_px is not None or budget is not None:
            from ..lod.cache import load_or_build
            self.tree, _ = load_or_build(gaussians)

    def arrays_for(self, camera):
        """The Gaussians' arrays for ``camera``, or None when they are the whole model (set once)."""
        if self.tree is None:
            return None
        from ..lod.blend import blend_weights, blended_arrays
        from ..lod.cut import budget_cut_nodes, cut_nodes

        if self.budget is not None:
            nodes, granularity = budget_cut_nodes(self.tree, camera, self.budget)
        else:
            nodes, granularity = cut_nodes(self.tree, camera, self.granularity_px), self.granularity_px
        return blended_arrays(self.tree, nodes, blend_weights(self.tree, camera, nodes, granularity))


def frame_renderer(backend: str):
    """A context manager with set_gaussians(g) and render(camera, mode, background): the GL
    renderer's (entry point ``gl`` of inceptiongs.frame_renderers) or the library's (torch)."""
    if backend == "torch":
        return TorchFrames()
    from importlib.metadata import entry_points

    for entry in entry_points(group=FRAME_RENDERERS):
        if entry.name == backend:
            return entry.load()()
    raise InputError(f"--backend {backend}: not installed (no {FRAME_RENDERERS} entry point; reinstall the package)")


class TorchFrames:
    """Frames from the library's rasterizer, with the interface of the GL renderer's OffscreenFrames."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        return None

    def set_gaussians(self, gaussians) -> None:
        from ..gaussians import Gaussians
        self.gaussians = Gaussians.from_numpy(gaussians) if isinstance(gaussians, dict) else gaussians

    def render(self, camera, mode, background) -> np.ndarray:
        from .render import render_torch
        return render_torch(self.gaussians, camera, mode, background)


def render_video(gaussians, cameras: list, out: Path, fps: float, backend: str = "gl", background=(0.0, 0.0, 0.0),
                 lod_px: float | None = None, lod_budget: int | None = None, progress: bool = True) -> int:
    """Draw ``cameras`` (one size, even sides) and encode them at ``fps`` into ``out``. -> frames."""
    from tqdm import tqdm

    from .render import to_png_rgb

    cuts = DetailCuts(gaussians, lod_px, lod_budget)
    width, height = cameras[0].width, cameras[0].height
    with frame_renderer(backend) as renderer, open_video(out, width, height, fps) as video:
        if cuts.tree is None:
            renderer.set_gaussians(gaussians)
        for camera in tqdm(cameras, desc=f"rendering {out.name}", unit="frame", disable=not progress,
                           file=sys.stderr, mininterval=0.5):
            arrays = cuts.arrays_for(camera)
            if arrays is not None:
                renderer.set_gaussians(arrays)
            video.write(to_png_rgb(renderer.render(camera, "rgb", background), "rgb"))
        return video.frames


def run(args) -> int:
    """The `render` command: a video for --path/--orbit, else one image (render.run)."""
    if not (args.path or args.orbit):
        if args.fps is not None:
            raise InputError("--fps: only for a video (--path or --orbit)")
        return render_image.run(args)
    return run_video(args)


def run_video(args) -> int:
    from .render import parse_background

    out = check_video_path(args.out)
    if args.mode != "rgb":
        raise InputError(f"--mode {args.mode}: a video is rgb (render single frames for {args.mode})")
    if args.device is not None and args.backend != "torch":
        raise InputError(f"--device {args.device}: applies to --backend torch")
    if args.width is not None and args.width <= 0 or args.height is not None and args.height <= 0:
        raise InputError(f"--width/--height: must be positive, got {args.width}x{args.height}")
    background = parse_background(args.background)
    from ..io.atomic import check_writable_dir
    from .render import check_out_outside_scenes
    check_out_outside_scenes(args, out)
    check_writable_dir(out.parent)
    gaussians, cameras = model_and_cameras(args.model, args.scene)
    path = video_path(args, gaussians, cameras)
    frames = path_cameras(path)
    try:
        count = render_video(gaussians, frames, out, path.fps, args.backend, background, args.lod, args.lod_budget)
    except RuntimeError as exc:
        if type(exc).__name__ != "RendererError":
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 1
    codec = "H.264 MP4" if out.suffix.lower() == ".mp4" else "VP9 WebM"
    print(f"wrote {out} ({count} frames, {frames[0].width}x{frames[0].height}, {path.fps:g} fps, "
          f"{count / path.fps:.2f} s, {codec})")
    return 0
