"""``inceptiongs render MODEL (--camera cam.json | --view NAME) --backend gl|torch [--device D] ...``.

``--backend`` picks the renderer: ``gl`` the OpenGL splat renderer (the viewer's pictures),
``torch`` the library's rasterizer. ``--device`` is where the library's rasterizer runs (the one
device rule, :mod:`.device`; default: the run's device for a run folder): it belongs to
``--backend torch`` alone, since GL draws wherever its context runs.

MODEL is a model file (a 3DGS PLY, binary, ASCII or compressed, a .splat or a .spz:
:mod:`inceptiongs.io.models`) or a run folder (RUN/model.ply, RUN/point_cloud.ply or the newest
PLY in it; a run without a PLY falls back to its newest checkpoint). Frames: --camera poses are
in the model file's own (original) frame; with --view the camera comes from the scene (the
run's config names it, or --scene), in the scene's normalised frame, and the model is moved
into that frame with the scene's normalisation.

``--path path.json`` / ``--orbit`` render a video instead (:mod:`.render_video`, which is the
command's entry: it hands single images to :func:`run`).

``--lod GRANULARITY_PX`` / ``--lod-budget SPLATS`` draw a level-of-detail cut of the model
(:mod:`inceptiongs.lod`, the hierarchy cached by the model's content), each node blended towards
its parent near the threshold (:mod:`inceptiongs.lod.blend`); without them the model is drawn
exactly as it is.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_open, check_writable_dir
from ..io.images import write_png
from ..io.limits import check_image_size
from ..camera import Camera, read_camera_json
from ..constants import ALPHA_EPS
from ..errors import InputError
from ..io.paths import check_outside_scene, read_small_text
from .device import add_device_argument, command_device
from ..io.values import flag, shown

HELP = "render a model file (.ply, .splat, .spz) or a run folder from a camera JSON or a scene view (torch or OpenGL)"
MODES = ("rgb", "depth", "normal", "alpha")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="a model file (.ply, .compressed.ply, .splat, .spz) or a run folder")
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--camera", help="camera JSON {width, height, fx, fy, cx, cy, world_to_camera}")
    which.add_argument("--view", help="name of a camera (image) of the scene")
    which.add_argument("--path", help="camera path JSON (the viewer's Camera path panel saves one): renders a "
                                      "video to --out .mp4 (H.264) or .webm (VP9)")
    which.add_argument("--orbit", action="store_true",
                       help="render a video of one turn around what the training cameras look at (a model "
                            "without cameras: around its middle)")
    parser.add_argument("--fps", type=flag("frames per second"), help="video frames per second (default: the path's, 30 for --orbit)")
    parser.add_argument("--seconds", type=flag("positive"), default=8.0, help="--orbit: how long one turn lasts (default 8)")
    parser.add_argument("--scene", help="scene folder for --view (default: the run's scene)")
    parser.add_argument("--backend", choices=("torch", "gl"), default="gl",
                        help="which renderer draws: gl, the OpenGL splat renderer (the viewer's pictures; default), "
                             "or torch, the library's rasterizer (on --device)")
    add_device_argument(parser, reads_run=True, default_help="the run's device for a run folder, else auto; "
                                                             "--backend torch only")
    parser.add_argument("--mode", choices=MODES, default="rgb")
    parser.add_argument("--out", required=True, help="output .png (depth/normal colour-mapped) or .npy (raw float32); "
                                                     "with --path/--orbit a video .mp4 or .webm")
    parser.add_argument("--width", type=flag("pixels"), help="output width (intrinsics rescaled)")
    parser.add_argument("--height", type=flag("pixels"), help="output height (intrinsics rescaled)")
    parser.add_argument("--background", default="0,0,0", help="rgb background r,g,b in [0, 1]")
    lod = parser.add_mutually_exclusive_group()
    lod.add_argument("--lod", type=flag("length in pixels"), metavar="GRANULARITY_PX",
                     help="draw a level-of-detail cut: nodes of the model's LOD hierarchy down to this projected "
                          "size in pixels (0: every leaf; default: the exact model, no hierarchy)")
    lod.add_argument("--lod-budget", type=flag("count"), metavar="SPLATS",
                     help="draw the finest level-of-detail cut of at most this many splats")


def parse_background(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(np.isfinite(values)):
        raise InputError(f"--background: expected three numbers r,g,b, got {text!r}")
    return values  # type: ignore[return-value]


def resized_camera(camera: Camera, width: int | None, height: int | None) -> Camera:
    """The camera at a new image size; one given side keeps the aspect ratio."""
    if width is None and height is None:
        return camera
    if (width is not None and width <= 0) or (height is not None and height <= 0):
        raise InputError(f"--width/--height: must be positive, got {width}x{height}")
    if width is None:
        width = max(1, round(camera.width * height / camera.height))
    if height is None:
        height = max(1, round(camera.height * width / camera.width))
    sx, sy = width / camera.width, height / camera.height
    return replace(camera, width=int(width), height=int(height), fx=camera.fx * sx, fy=camera.fy * sy,
                   cx=camera.cx * sx, cy=camera.cy * sy)


def find_model_ply(run_dir: Path) -> Path | None:
    """RUN/model.ply, else RUN/point_cloud.ply, else the newest *.ply anywhere below RUN."""
    for name in ("model.ply", "point_cloud.ply"):
        if (run_dir / name).is_file():
            return run_dir / name
    from ..io.paths import files_below

    plies = sorted(files_below(run_dir, ".ply"), key=lambda p: p.stat().st_mtime)
    return plies[-1] if plies else None


def run_scene_path(run_dir: Path) -> str | None:
    config = run_dir / "config.json"
    if not config.is_file():
        return None
    try:
        scene = json.loads(read_small_text(config, "run config")).get("scene") or None
    except (OSError, json.JSONDecodeError, AttributeError):
        raise InputError(f"{config}: not a readable run config") from None
    if scene is not None and not isinstance(scene, str):
        raise InputError(f"{config}: scene must be a string (the scene folder), got {shown(scene)}")
    return scene


def check_out_outside_scenes(args, out: Path) -> None:
    """InputError when ``out`` lies in the --scene folder or the run's scene folder (input, never written)."""
    model = Path(args.model)
    for scene in (args.scene, run_scene_path(model) if model.is_dir() else None):
        check_outside_scene(out, scene)


def load_model_and_camera(args):
    """-> (Gaussians, Camera) in one frame, per the rules in the module docstring."""
    from ..io.models import read_model

    model = Path(args.model)
    if not model.exists():
        raise InputError(f"{model}: model does not exist")
    run_dir = model if model.is_dir() else None
    ply = find_model_ply(model) if run_dir else model
    if args.camera:
        if ply is None:
            raise InputError(f"{model}: no .ply model in the run folder (--camera needs one)")
        return read_model(ply), read_camera_json(args.camera)
    from ..scene.loader import load_scene

    scene_path = args.scene or (run_scene_path(run_dir) if run_dir else None)
    if not scene_path:
        raise InputError(f"{model}: --view needs --scene (or a run folder whose config names its scene)")
    # The camera at the scene's stated (full) size, whether the run finished (model.ply) or
    # only checkpointed: --width/--height are the way to another size.
    scene = load_scene(scene_path, require_images=False)
    if run_dir is not None and ply is None:
        from ..runs.load import load_run
        gaussians, _, _ = load_run(run_dir)  # newest checkpoint, normalised frame (same normalisation)
    else:
        gaussians = scene.normalization.gaussians_to_normalized(read_model(ply))
    return gaussians, scene.camera_by_name(args.view)


BACKEND_ENTRY_POINTS = "inceptiongs.render_backends"


def render_torch(gaussians, camera: Camera, mode: str, background, rasterizer=None) -> np.ndarray:
    """The library's own render (``--backend torch``) with ``rasterizer`` (default: the CPU's)."""
    import torch

    from ..rasterizer.interface import cpu_rasterizer
    rasterizer = cpu_rasterizer() if rasterizer is None else rasterizer
    with torch.no_grad():
        out = rasterizer(gaussians, camera, outputs=(mode,), background=torch.tensor(background))
    return out[mode].cpu().numpy().astype(np.float32)


def render_backend(name: str):
    """The render function of backend ``name``: ``torch`` is the library's own; the others
    (``gl``) come from the packages above the library, registered as entry points in the
    group ``inceptiongs.render_backends``, so the library imports no GL."""
    if name == "torch":
        return render_torch
    from importlib.metadata import entry_points

    for entry in entry_points(group=BACKEND_ENTRY_POINTS):
        if entry.name == name:
            return entry.load()
    raise InputError(f"--backend {name}: not installed (no {BACKEND_ENTRY_POINTS} entry point named {name!r}; "
                     "reinstall the package)")


def level_of_detail(gaussians, camera: Camera, granularity_px: float | None, budget: int | None):
    """-> (the Gaussians to draw, a note for stderr or None). Without --lod/--lod-budget the
    model is drawn as it is; with one, the cut of its hierarchy (cached by content)."""
    if granularity_px is None and budget is None:
        return gaussians, None
    if granularity_px is not None and not granularity_px >= 0.0:
        raise InputError(f"--lod: the granularity must be >= 0 pixels, got {granularity_px}")
    if budget is not None and budget < 0:
        raise InputError(f"--lod-budget: the budget must be >= 0 splats, got {budget}")
    from ..lod.cache import load_or_build
    from ..gaussians import Gaussians
    from ..lod.blend import blend_weights, blended_arrays
    from ..lod.cut import budget_cut_nodes, cut_nodes

    tree, cached = load_or_build(gaussians)
    if budget is not None:
        nodes, granularity_px = budget_cut_nodes(tree, camera, budget)
    else:
        nodes = cut_nodes(tree, camera, granularity_px)
    note = (f"lod: {len(nodes):,} of {len(gaussians):,} splats at {granularity_px:g} px "
            f"(hierarchy {'from the cache' if cached else 'built'})")
    # Blended towards their parents near the threshold: a camera path's frames do not pop.
    arrays = blended_arrays(tree, nodes, blend_weights(tree, camera, nodes, granularity_px))
    return Gaussians.from_numpy(arrays, device=gaussians.device), note


def render_image(gaussians, camera: Camera, backend: str, mode: str, background, rasterizer=None) -> np.ndarray:
    """[H, W, 3] (rgb, normal) or [H, W, 1] (depth, alpha) float32 from either renderer;
    ``rasterizer``: the library's, for backend "torch"."""
    if backend == "torch":
        return render_torch(gaussians, camera, mode, background, rasterizer)
    return render_backend(backend)(gaussians, camera, mode, background)


def to_png_rgb(image: np.ndarray, mode: str) -> np.ndarray:
    """Float image -> uint8 [H, W, 3] for viewing: rgb clipped; alpha grey; normal 0.5 n + 0.5;
    depth through a colour map over its valid range (black where nothing was drawn)."""
    if mode == "rgb":
        shown = np.clip(image, 0.0, 1.0)
    elif mode == "alpha":
        shown = np.repeat(np.clip(image, 0.0, 1.0), 3, axis=-1)
    elif mode == "normal":
        shown = np.clip(0.5 * image + 0.5, 0.0, 1.0)
    else:
        import matplotlib
        depth = image[..., 0]
        valid = depth > ALPHA_EPS
        shown = np.zeros(depth.shape + (3,), np.float32)
        if valid.any():
            low, high = float(depth[valid].min()), float(depth[valid].max())
            span = high - low if high > low else 1.0  # a flat depth map maps to one colour
            t = np.clip((depth - low) / span, 0.0, 1.0)
            shown = matplotlib.colormaps["turbo"](t)[..., :3].astype(np.float32)
            shown[~valid] = 0.0
    return (shown * 255.0 + 0.5).astype(np.uint8)


def write_output(image: np.ndarray, mode: str, out: Path) -> None:
    if out.suffix.lower() == ".npy":
        with atomic_open(out, "wb") as handle:
            np.save(handle, image.astype(np.float32))
        return
    write_png(out, to_png_rgb(image, mode))


def torch_rasterizer(args):
    """(the library's rasterizer, the line saying what auto chose or None) for --backend torch,
    by the one device rule; (None, None) for gl, which takes no --device (one line if given)."""
    if args.backend != "torch":
        if args.device is not None:
            raise InputError(f"--device {args.device}: applies to --backend torch (the library's rasterizer); "
                             f"--backend {args.backend} draws wherever its OpenGL context runs")
        return None, None
    model = Path(args.model)
    device = command_device(args.device, model if model.is_dir() else None)
    return device.rasterizer, device.note


def run(args) -> int:
    out = Path(args.out)
    if out.suffix.lower() not in (".png", ".npy"):
        raise InputError(f"{out}: output must end in .png or .npy")
    background = parse_background(args.background)
    check_out_outside_scenes(args, out)
    check_writable_dir(out.parent)  # a bad --out is one line before any work
    if args.width is not None and args.height is not None:
        check_image_size(args.width, args.height, "--width/--height")
    rasterizer, device_note = torch_rasterizer(args)
    gaussians, camera = load_model_and_camera(args)
    camera = resized_camera(camera, args.width, args.height)
    check_image_size(camera.width, camera.height, "--width/--height" if args.width or args.height else
                     f"{args.camera or args.view}")
    gaussians, lod_note = level_of_detail(gaussians, camera, args.lod, args.lod_budget)
    try:
        image = render_image(gaussians, camera, args.backend, args.mode, background, rasterizer)
    except RuntimeError as exc:
        # RendererError (no usable GL) is not the user's input, but it is one line to show.
        if type(exc).__name__ != "RendererError":
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 1
    write_output(image, args.mode, out)
    for note in (device_note, lod_note):
        if note:
            print(note, file=sys.stderr)
    print(f"wrote {out} ({camera.width}x{camera.height}, {args.mode}, {args.backend})")
    return 0
