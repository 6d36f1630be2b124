"""A tiny COLMAP-text scene with its own image copies, and a one-step run on it: the inputs the
shared-run tests and the run fuzz suite mutate."""

from __future__ import annotations

import contextlib
import io
import shutil
from pathlib import Path

from inceptiongs.camera import rotation_to_quat
from inceptiongs.cli import main
from scene_cases import known_cameras, known_points, project, write_images


def write_text_scene(scene: Path, count: int = 4) -> list[str]:
    """A COLMAP text model in scene/sparse/0 and its images in scene/images; returns the image names."""
    cameras = known_cameras(count=count)
    write_images(scene / "images", cameras, [None] * count)
    points = known_points()
    model = scene / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text("".join(
        f"{i + 1} PINHOLE {c.width} {c.height} {c.fx} {c.fy} {c.cx} {c.cy}\n" for i, c in enumerate(cameras)))
    lines = []
    for i, c in enumerate(cameras):
        q, t = rotation_to_quat(c.world_to_camera[:3, :3]), c.world_to_camera[:3, 3]
        pose = " ".join(repr(float(v)) for v in [*q, *t])
        pixels = project(c, points[:2])
        lines.append(f"{i + 1} {pose} {i + 1} {c.name}\n"
                     f"{pixels[0, 0]} {pixels[0, 1]} 1 {pixels[1, 0]} {pixels[1, 1]} 2\n")
    (model / "images.txt").write_text("".join(lines))
    (model / "points3D.txt").write_text("".join(
        f"{k + 1} {p[0]} {p[1]} {p[2]} 10 200 30 0.5 1 {k}\n" for k, p in enumerate(points[:2])))
    return [c.name for c in cameras]


def run_main(argv: list[str]) -> tuple[int, str, str]:
    """cli.main in-process -> (status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(argv)
    return status, out.getvalue(), err.getvalue()


def train_one_step(scene: Path, run: Path) -> None:
    settings = run.parent / f"{run.name}_settings.json"
    settings.parent.mkdir(parents=True, exist_ok=True)
    settings.write_text('{"free_space": {"sky_shell": false}}')
    status, _, stderr = run_main(["train", str(scene), "--out", str(run), "--iterations", "1",
                                  "--config", str(settings)])
    assert status == 0, stderr


def save_tiny_prior(run: Path) -> None:
    """A tiny untrained prior saved in the run (the commands that read one find it)."""
    from inceptiongs.prior.model import Prior, PriorConfig
    from inceptiongs.prior.trainer import PriorTrainer, save_prior
    from inceptiongs.prior.unet import UNetConfig
    from inceptiongs.runs.load import load_run

    gaussians, loaded, _ = load_run(run)
    config = PriorConfig(patch_size=16, batch_size=1, unet=UNetConfig(base_width=8, channel_mults=(1, 2), time_dim=16))
    save_prior(run, PriorTrainer(Prior.for_gaussians(config, gaussians), gaussians, loaded.cameras[:1],
                                 lambda i: loaded.load_image(i)))


def copy_scene_and_run(world: dict, root: Path) -> dict:
    """A fresh copy of ``world``'s scene and run in ``root`` (the run's config points at the
    copied scene) -> {"scene", "run", "names", "root"}."""
    scene, run = root / "scene", root / "run"
    shutil.copytree(world["scene"], scene)
    shutil.copytree(world["run"], run)
    config = run / "config.json"
    config.write_text(config.read_text().replace(str(world["scene"]), str(scene)))
    return {"scene": scene, "run": run, "names": world["names"], "root": root}
