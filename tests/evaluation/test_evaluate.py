"""evaluate_run on a run folder this test writes itself: a tiny transforms.json scene whose
photos are renders of known Gaussians, a model.ply, config.json and split.json."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
import torch

from inceptiongs.camera import Camera, look_at, rigid_inverse
from inceptiongs.cli import main
from inceptiongs.errors import InputError
from inceptiongs.evaluation.run import UNAVAILABLE_FID, UNAVAILABLE_LPIPS, evaluate_run
from inceptiongs.gaussians import Gaussians
from inceptiongs.evaluation.protocols import Split, make_split

# torch 2.13 deprecates TorchScript; it is still the format the --lpips/--fid weights use.
pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")

WIDTH, HEIGHT, FOCAL = 40, 30, 36.0


def known_gaussians(seed: int = 0, count: int = 60) -> Gaussians:
    """A blob of coloured Gaussians near (5, -2, 3): far from the origin on purpose, so the
    scene normalisation has something to undo."""
    gen = torch.Generator().manual_seed(seed)
    means = torch.tensor([5.0, -2.0, 3.0]) + 0.6 * (torch.rand(count, 3, generator=gen) - 0.5)
    log_scales = torch.full((count, 3), math.log(0.12)) + 0.3 * torch.rand(count, 3, generator=gen)
    quats = torch.nn.functional.normalize(torch.randn(count, 4, generator=gen), dim=1)
    opacity_logits = torch.full((count,), 2.0)
    sh = (torch.rand(count, 1, 3, generator=gen) - 0.5) * 3.0
    return Gaussians(means, log_scales, quats, opacity_logits, sh)


def ring_cameras(count: int = 14) -> list[Camera]:
    target = np.array([5.0, -2.0, 3.0])
    cameras = []
    for i, angle in enumerate(np.linspace(0, 2 * np.pi, count, endpoint=False)):
        eye = target + np.array([2.5 * np.cos(angle), 0.4 * np.sin(2 * angle), 2.5 * np.sin(angle)])
        cameras.append(Camera(f"view{i:02d}", WIDTH, HEIGHT, FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2,
                              look_at(eye, target)))
    return cameras


def write_scene(root, gaussians: Gaussians, cameras: list[Camera]) -> None:
    """transforms.json (OpenGL camera-to-world) + PNG photos rendered from ``gaussians``."""
    from inceptiongs.rasterizer.rasterize import render

    (root / "images").mkdir(parents=True)
    frames = []
    for camera in cameras:
        with torch.no_grad():
            rgb = render(gaussians, camera)["rgb"].clamp(0, 1).numpy()
        cv2.imwrite(str(root / "images" / f"{camera.name}.png"), (rgb[..., ::-1] * 255 + 0.5).astype(np.uint8))
        camera_to_world = rigid_inverse(camera.world_to_camera) @ np.diag([1.0, -1.0, -1.0, 1.0])
        frames.append({"file_path": f"images/{camera.name}.png", "transform_matrix": camera_to_world.tolist()})
    (root / "transforms.json").write_text(json.dumps({
        "fl_x": FOCAL, "fl_y": FOCAL, "cx": WIDTH / 2, "cy": HEIGHT / 2, "w": WIDTH, "h": HEIGHT,
        "frames": frames}))


def write_run(run, scene_root, model: Gaussians, protocol: str = "unstructured", seed: int = 0):
    from inceptiongs.io.ply import write_ply
    from inceptiongs.scene.loader import load_scene
    from inceptiongs.runs.config import TrainConfig

    run.mkdir(parents=True)
    TrainConfig(scene=str(scene_root), protocol=protocol, seed=seed).save(run / "config.json")
    scene = load_scene(scene_root)
    split = make_split(scene, protocol, seed)
    split.save(run / "split.json")
    write_ply(model, run / "model.ply")
    return scene, split


@pytest.fixture(scope="module")
def scene_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("scene")
    write_scene(root, known_gaussians(), ring_cameras())
    return root


def render_and_photo(model_original: Gaussians, scene, index: int) -> tuple[np.ndarray, np.ndarray]:
    from inceptiongs.rasterizer.rasterize import render

    normalised = scene.normalization.gaussians_to_normalized(model_original)
    with torch.no_grad():
        rgb = render(normalised, scene.cameras[index])["rgb"].clamp(0, 1).numpy().astype(np.float64)
    return rgb, scene.load_image(index).astype(np.float64)


def independent_psnr(model_original: Gaussians, scene, index: int) -> float:
    """Render the view and score it with plain numpy (not inceptiongs.evaluation.metrics)."""
    rgb, photo = render_and_photo(model_original, scene, index)
    return 10 * math.log10(1 / np.mean((rgb - photo) ** 2))


def test_eval_scores_groups_and_writes_images(tmp_path, scene_root):
    truth = known_gaussians()
    degraded = Gaussians(truth.means, truth.log_scales, truth.quats, truth.opacity_logits, truth.sh * 0.6)
    scene, split = write_run(tmp_path / "run", scene_root, degraded)
    summary = evaluate_run(tmp_path / "run", progress=False)

    groups = summary["groups"]
    assert groups["scarce"]["views"] == len(split.scarce_test) > 0
    assert groups["covered"]["views"] == len(split.covered_test) > 0
    assert groups["all"]["views"] == len(split.test)
    assert summary["target_view"] == split.target_view
    assert summary["lpips"] == UNAVAILABLE_LPIPS and summary["fid"] == UNAVAILABLE_FID
    assert "lpips" not in groups["scarce"] and "fid" not in groups["scarce"]

    by_index = {v["index"]: v for v in summary["views"]}
    assert sorted(by_index) == split.test
    for index in split.test:
        view = by_index[index]
        assert view["group"] == ("scarce" if index in split.scarce_test else "covered")
        assert view["psnr"] == pytest.approx(independent_psnr(degraded, scene, index), abs=1e-3)
        panels = cv2.imread(str(tmp_path / "run" / view["image"]))
        assert panels.shape == (HEIGHT, 3 * WIDTH, 3)
    scarce = [by_index[i]["psnr"] for i in split.scarce_test]
    assert groups["scarce"]["psnr"] == pytest.approx(np.mean(scarce))
    written = json.loads((tmp_path / "run" / "eval" / "eval.json").read_text())
    assert written["groups"]["covered"]["psnr"] == pytest.approx(groups["covered"]["psnr"])


def test_true_model_scores_better_than_degraded(tmp_path, scene_root):
    truth = known_gaussians()
    write_run(tmp_path / "good", scene_root, truth, protocol="llff")
    good = evaluate_run(tmp_path / "good", progress=False)
    # Only the 8-bit quantisation of the photos separates the true model from them.
    assert good["groups"]["covered"]["psnr"] > 40
    assert good["groups"]["covered"]["ssim"] > 0.99
    assert good["groups"]["scarce"] == {"views": 0, "psnr": None, "ssim": None}


def test_cli_json_and_table(tmp_path, scene_root, capsys):
    write_run(tmp_path / "run", scene_root, known_gaussians(seed=1))
    assert main(["eval", str(tmp_path / "run"), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["lpips"] == UNAVAILABLE_LPIPS
    assert main(["eval", str(tmp_path / "run")]) == 0
    table = capsys.readouterr().out
    assert "scarce" in table and "covered" in table and "unavailable" in table
    assert main(["eval", str(tmp_path / "nothing")]) == 2
    assert "nothing" in capsys.readouterr().err


def test_local_lpips_weights_and_a_torchscript_fid_network_are_used(tmp_path, scene_root):
    from inceptiongs.evaluation.lpips_net import load_lpips, lpips_shapes

    class PooledColour(torch.nn.Module):
        def forward(self, images: torch.Tensor) -> torch.Tensor:
            return torch.cat([images.mean(dim=(2, 3)), images.std(dim=(2, 3))], dim=1)

    g = torch.Generator().manual_seed(0)
    weights = {name: torch.randn(shape, generator=g).abs() * 0.1 for name, shape in lpips_shapes().items()}
    torch.save(weights, tmp_path / "lpips.pt")
    torch.jit.script(PooledColour()).save(str(tmp_path / "fid.pt"))
    model = known_gaussians(seed=2)
    scene, _ = write_run(tmp_path / "run", scene_root, model)
    summary = evaluate_run(tmp_path / "run", lpips_weights=tmp_path / "lpips.pt",
                           fid_weights=tmp_path / "fid.pt", progress=False)
    assert summary["lpips"].startswith("computed") and summary["fid"].startswith("computed")
    network = load_lpips(tmp_path / "lpips.pt")
    for view in summary["views"]:
        rgb, photo = render_and_photo(model, scene, view["index"])
        as_batch = [torch.from_numpy(np.ascontiguousarray(x)).float().permute(2, 0, 1)[None] * 2 - 1
                    for x in (rgb, photo)]
        with torch.no_grad():
            assert view["lpips"] == pytest.approx(float(network(*as_batch)), rel=1e-4, abs=1e-6)
    assert summary["groups"]["all"]["fid"] > 0
    (tmp_path / "junk.pt").write_bytes(b"not a model")
    with pytest.raises(InputError, match="junk.pt"):
        evaluate_run(tmp_path / "run", lpips_weights=tmp_path / "junk.pt", progress=False)


def test_split_for_other_views_is_rejected(tmp_path, scene_root):
    write_run(tmp_path / "run", scene_root, known_gaussians())
    other = make_split(ring_cameras(9), "llff", 0)
    other.save(tmp_path / "run" / "split.json")
    assert main(["eval", str(tmp_path / "run")]) == 2
    assert isinstance(Split.load(tmp_path / "run" / "split.json"), Split)


def test_eval_of_a_missing_run_folder_is_one_line(tmp_path, capsys):
    """The error alone: no device line before it (the device is chosen for a run that exists)."""
    assert main(["eval", str(tmp_path / "no_such_run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "run folder does not exist" in err[0]


def test_an_unknown_outlook_is_named_once(tmp_path, scene_root, capsys):
    """eval prefixes the outlook with "repair outlook ...:", so the line's own prefix goes."""
    write_run(tmp_path / "run", scene_root, known_gaussians(seed=1))
    (tmp_path / "run" / "metrics.jsonl").write_text(json.dumps({"iteration": 0, "covered_psnr": 15.0}) + "\n")
    assert main(["eval", str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out
    assert "repair outlook for a bootstrap: unknown (" in out and out.count("repair outlook") == 1
