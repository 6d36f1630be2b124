"""`inceptiongs generate RUN (--camera cam.json | --view NAME) --out FILE.png [--steps N] [--seed S]`.

Generates an image for any viewpoint with the run's trained prior (RUN/prior/prior.pt):
DDIM, full resolution by MultiDiffusion. --camera poses are in the scene's original frame
(like `inceptiongs render`); --view names a camera of the run's scene. --gbuffer-out writes the
G-buffer it conditioned on as a float32 .npy [H, W, 3 + 1 + Z] (normal, alpha, hash features).
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np

from ..errors import InputError
from .device import add_device_argument, command_device
from ..io.values import flag

HELP = "generate an image for any viewpoint with a run's diffusion prior"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="a run folder with a trained prior (inceptiongs prior RUN)")
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--camera", help="camera JSON (original scene frame)")
    which.add_argument("--view", help="name of a camera (image) of the run's scene")
    parser.add_argument("--out", required=True, help="output .png")
    parser.add_argument("--steps", type=flag("steps"), default=20, help="DDIM steps (default 20)")
    parser.add_argument("--seed", type=flag("seed"), default=0, help="noise seed (same seed, same image)")
    parser.add_argument("--window", type=flag("pixels"), default=None, help="MultiDiffusion window (default: patch size)")
    parser.add_argument("--stride", type=flag("pixels"), default=None, help="window stride (default: 3/4 window)")
    add_sampling_arguments(parser)
    parser.add_argument("--gbuffer-out", default=None, help="also write the G-buffer as .npy")
    add_device_argument(parser, reads_run=True)


def add_sampling_arguments(parser: argparse.ArgumentParser, context: str = "") -> None:
    """--start / --init (checked by prior.trainer.sampling_options), shared with `eval --generated`."""
    parser.add_argument("--start", type=flag("start"), default=None,
                        help=f"{context}tiny backend: start sampling at this fraction of T from a noised image "
                             "(SDEdit; default: the prior's sample_start, 1 = pure noise)")
    parser.add_argument("--init", choices=("render", "hint"), default=None,
                        help=f"{context}tiny backend: the image --start noises: the run's render of the view (the "
                             "prior repairs it) or the appearance hint (default: the prior's sample_init)")


def run(args) -> int:
    from ..io.atomic import atomic_write_bytes
    from ..camera import read_camera_json
    from ..io.images import write_png
    from ..prior.trainer import load_prior, sampling_options
    from ..runs.load import load_run

    if Path(args.out).suffix.lower() != ".png":
        raise InputError(f"{args.out}: --out must be a .png file")
    if args.gbuffer_out and Path(args.gbuffer_out).suffix.lower() != ".npy":
        raise InputError(f"{args.gbuffer_out}: --gbuffer-out must be a .npy file")
    if args.steps < 1:
        raise InputError(f"--steps: must be >= 1, got {args.steps}")
    run_dir = Path(args.run)
    chosen = command_device(args.device, run_dir)   # the prior, its G-buffer and the model on one device
    device = chosen.torch_device
    if chosen.note:
        print(chosen.note, file=sys.stderr)
    prior = load_prior(run_dir, device)  # fails fast, before the scene is loaded
    gaussians, scene, _ = load_run(run_dir)
    if args.camera:
        camera = scene.normalization.camera_to_normalized(read_camera_json(args.camera))
    else:
        camera = scene.camera_by_name(args.view)
    factor = prior.patch_multiple
    window = prior.config.patch_size if args.window is None else args.window
    if window < factor or window % factor:
        raise InputError(f"--window: must be a positive multiple of {factor}, got {window}")
    stride = args.stride
    if stride is not None and not 1 <= stride <= window:
        raise InputError(f"--stride: must be in 1..{window}, got {stride}")
    if prior.backend == "tiny":      # refused before the canvas is allocated
        from ..prior.footprint import check_sampling_fits
        from ..prior.model import denoiser_cond_channels
        check_sampling_fits(prior.config.unet, denoiser_cond_channels(prior.config), camera.height, camera.width,
                            window, f"--window {window}", device)
    options = sampling_options(prior, args.start, args.init, run_dir)
    rgb, gbuffer = prior.generate(gaussians.to(device), camera, steps=args.steps, seed=args.seed,
                                  window=window, stride=stride, progress=True, **options)
    write_png(Path(args.out), (rgb.cpu().numpy() * 255.0 + 0.5).astype(np.uint8))
    print(f"wrote {args.out} ({camera.width}x{camera.height}, {args.steps} DDIM steps, seed {args.seed})")
    if args.gbuffer_out:
        buffer = io.BytesIO()
        np.save(buffer, gbuffer.permute(1, 2, 0).cpu().numpy().astype(np.float32))
        atomic_write_bytes(args.gbuffer_out, buffer.getvalue())
        print(f"wrote {args.gbuffer_out}")
    return 0
