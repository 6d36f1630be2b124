"""Every photo of a capture against a trained run's model: PSNR per view in capture order.

    python benchmarks/bench_view_fit.py RUN [--plot F.png] [--segment 0:108]
        [--observations DSCF5615.JPG --observations-png F.png]

Renders every camera of RUN's scene (training and held-out views alike) from RUN's final model
and prints the PSNR per view in capture (file-name) order, the mean per group (train, scarce,
covered) and, with --segment A:B, the means inside and outside photos A..B-1. A static scene
fits its training photos about equally well; a stretch of photos far below the rest (training
views included) is a capture that disagrees with itself (moved objects, wrong poses), which no
stage-I setting fixes and which caps what held-out views in that stretch can score. The trainer
reports such training photos itself (RUN/view_fit.json, inceptiongs.train.view_fit); this script
adds the held-out views and the picture. --observations NAME (COLMAP scenes) draws the image
points the structure-from-motion model ties to 3-D points over that photo, beside the final
model's render of it: where a photo shows an object that no 3-D point of it observes, the
sparse model itself says the photo disagrees with the others there. RUN is only read.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import inceptiongs  # noqa: F401  (sets OMP_WAIT_POLICY before torch loads)
import numpy as np
import torch

from inceptiongs.errors import InputError
from inceptiongs.evaluation.metrics import psnr
from inceptiongs.evaluation.protocols import Split
from inceptiongs.rasterizer.interface import cpu_rasterizer
from inceptiongs.runs.load import load_run

GROUP_COLOURS = {"train": "#4c72b0", "scarce": "#dd8452", "covered": "#c44e52"}


def view_scores(run: Path, gaussians, scene) -> list[dict]:
    """One row per camera of RUN's split in capture order: index, name, group, psnr."""
    split = Split.load(run / "split.json", scene.cameras)
    group = {i: "train" for i in split.train}
    group.update({i: "covered" for i in split.test})
    group.update({i: "scarce" for i in split.scarce_test})
    rows = []
    for index in sorted(group, key=lambda i: scene.cameras[i].name):
        photo = torch.as_tensor(np.asarray(scene.load_image(index), np.float32))
        with torch.no_grad():
            rgb = cpu_rasterizer()(gaussians, scene.cameras[index], outputs=("rgb",))["rgb"].clamp(0, 1)
        rows.append({"index": index, "name": scene.cameras[index].name, "group": group[index],
                     "psnr": float(psnr(rgb.to(torch.float32), photo))})
    return rows


def observations_figure(gaussians, scene, config, name: str, path: Path) -> None:
    """The final model's render of photo ``name`` | the photo with the image points its COLMAP
    model ties to 3-D points (green), side by side, 2x enlarged."""
    import cv2
    import pycolmap

    matches = [i for i, camera in enumerate(scene.cameras) if camera.name == name]
    if not matches:
        raise InputError(f"{config.scene}: no photo named {name}")
    sparse = [p for p in (Path(config.scene) / "sparse" / "0", Path(config.scene) / "sparse") if (p / "images.bin").is_file()]
    if not sparse:
        raise InputError(f"{config.scene}: no COLMAP model (sparse/0/images.bin) to read observations from")
    model = pycolmap.Reconstruction(str(sparse[0]))
    image = next((im for im in model.images.values() if im.name == name), None)
    if image is None:
        raise InputError(f"{sparse[0]}: no image named {name}")
    camera = scene.cameras[matches[0]]
    photo = np.asarray(scene.load_image(matches[0]), np.float32)
    # The COLMAP camera has the photo's full resolution; the scene's may be downscaled.
    factor = camera.width / model.cameras[image.camera_id].width
    marked = (photo * 255).astype(np.uint8).copy()
    for point in image.points2D:
        if point.has_point3D():
            x, y = (np.asarray(point.xy) * factor).astype(int)
            cv2.circle(marked, (int(x), int(y)), 1, (0, 255, 0), -1)
    with torch.no_grad():
        rgb = cpu_rasterizer()(gaussians, camera, outputs=("rgb",))["rgb"].clamp(0, 1).numpy()
    panel = np.concatenate([(rgb * 255).astype(np.uint8), marked], 1)
    panel = cv2.resize(panel, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    if not cv2.imwrite(str(path), cv2.cvtColor(panel, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85]):
        raise InputError(f"{path}: could not write the figure")


def plot(rows: list[dict], path: Path, title: str) -> None:
    """PSNR against capture order, one colour per group."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 3.2), dpi=110)
    for name, colour in GROUP_COLOURS.items():
        xs = [k for k, r in enumerate(rows) if r["group"] == name]
        if xs:
            ax.scatter(xs, [rows[k]["psnr"] for k in xs], s=9 if name == "train" else 22, c=colour,
                       label=f"{name} ({len(xs)})", zorder=3 if name != "train" else 2)
    ax.set_xlabel("photo, in capture order")
    ax.set_ylabel("PSNR of the render (dB)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--plot", type=Path, default=None)
    parser.add_argument("--segment", default=None, help="A:B, photos A..B-1 in capture order")
    parser.add_argument("--observations", default=None, help="photo name: draw its COLMAP observations")
    parser.add_argument("--observations-png", type=Path, default=Path("observations.png"))
    args = parser.parse_args(argv)
    try:
        gaussians, scene, config = load_run(args.run)   # once: both parts render its model
        rows = view_scores(args.run, gaussians, scene)
        if args.observations:
            observations_figure(gaussians, scene, config, args.observations, args.observations_png)
            print(f"observations of {args.observations}: {args.observations_png}")
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for start in range(0, len(rows), 12):
        print(f"{start:4d} " + " ".join(f"{r['psnr']:5.1f}{r['group'][0]}" for r in rows[start:start + 12]))
    print("(t = training view, s = scarce, c = covered held-out view)")

    def means(selected: list[dict]) -> str:
        parts = []
        for name in GROUP_COLOURS:
            values = [r["psnr"] for r in selected if r["group"] == name]
            if values:
                parts.append(f"{name} {np.mean(values):.2f} dB ({len(values)})")
        return ", ".join(parts)

    print(f"all photos: {means(rows)}")
    if args.segment:
        a, b = (int(v) for v in args.segment.split(":"))
        print(f"photos {a}..{b - 1}: {means(rows[a:b])}")
        print(f"the others:   {means(rows[:a] + rows[b:])}")
    if args.plot:
        plot(rows, args.plot, f"{Path(config.scene).name}: every photo against the final model of {args.run}")
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
