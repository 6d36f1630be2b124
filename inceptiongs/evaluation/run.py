"""Evaluation of a run folder on its held-out views: loads RUN (stage I or a bootstrap), scores
it with :mod:`.scoring`, and writes RUN/eval/*.png and RUN/eval/eval.json. Sits above training
(it reads run folders); scoring itself stays below it.

LPIPS and FID are computed only from weights the user gives as local files (LPIPS as plain
tensors, .lpips_net; FID as a TorchScript network given on the command line; docs/evaluation.md says what they must compute); without them the result says "unavailable" -
never a stand-in under that name.
"""

from __future__ import annotations

import json
from pathlib import Path


from ..errors import InputError
from ..io.atomic import atomic_write_text
from ..io.config_json import json_safe
from ..runs.load import load_run
from .lpips_net import load_lpips
from .networks import load_torchscript
from .protocols import Split
from .scoring import evaluate_views


UNAVAILABLE_LPIPS = "unavailable (no --lpips-weights given)"
UNAVAILABLE_FID = "unavailable (no --fid-weights given)"


def evaluate_run(run_dir: str | Path, lpips_weights: str | Path | None = None,
                 fid_weights: str | Path | None = None, progress: bool = True, device=None) -> dict:
    """Evaluate RUN/model (via inceptiongs.runs.load.load_run) on RUN/split.json's held-out views.

    Writes RUN/eval/<group>_<index>_<name>.png (render | photo | error) and RUN/eval/eval.json,
    and returns the same dict as eval.json: {"run", "protocol", "seed", "target_view",
    "groups": {"scarce"|"covered"|"all": {"views", "psnr", "ssim"[, "lpips"][, "fid"]}},
    "views": [...], "lpips": "computed ..." | "unavailable ...", "fid": ...,
    "device": {"asked", "device", "rasterizer", "why"}}. ``device``
    (inceptiongs.rasterizer.interface.Device): what renders; default the device the run records,
    by the one device rule (scores do not depend on it beyond float rounding).
    """
    from ..rasterizer.interface import resolve_device


    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: run folder does not exist")
    gaussians, scene, config = load_run(run_dir)
    if device is None:
        device = resolve_device(config.device, f"{run_dir / 'config.json'}: device")
    split = Split.load(run_dir / "split.json", scene.cameras)
    if not split.test:
        raise InputError(f"{run_dir / 'split.json'}: the split holds out no views (protocol "
                         f"{split.protocol!r}); nothing to evaluate")
    lpips_model = load_lpips(lpips_weights) if lpips_weights else None
    fid_model = load_torchscript(fid_weights, "FID") if fid_weights else None
    eval_dir = run_dir / "eval"
    # The trainer scores its test views on black (the rasterizer's default); so do we.
    result = evaluate_views(gaussians, scene, split, save_dir=eval_dir, lpips_model=lpips_model,
                            fid_model=fid_model, progress=progress, rasterizer=device.rasterizer)
    for view in result["views"]:
        view["image"] = f"eval/{view['image']}"
    groups = result["groups"]
    summary = {
        "run": str(run_dir.resolve()),
        "protocol": split.protocol,
        "seed": split.seed,
        "target_view": split.target_view,
        "groups": groups,
        "views": result["views"],
        "lpips": f"computed with {lpips_weights}" if lpips_weights else UNAVAILABLE_LPIPS,
        "fid": f"computed with {fid_weights}" if fid_weights else UNAVAILABLE_FID,
        "device": device.to_json(),
    }
    atomic_write_text(eval_dir / "eval.json", json.dumps(json_safe(summary), indent=1) + "\n")
    return summary
