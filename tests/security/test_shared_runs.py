"""A run or scene folder from someone else: a checkpoint never runs
code, names in scene files never leave the scene, writes never follow a planted symlink, and bad
values are one line (exit 2) instead of a traceback."""

from __future__ import annotations

import json
import os
import pickle
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch

from shared_run_cases import copy_scene_and_run, run_main, train_one_step, write_text_scene


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    root = tmp_path_factory.mktemp("shared")
    scene = root / "scene"
    names = write_text_scene(scene)
    run = root / "run"
    train_one_step(scene, run)
    return {"scene": scene, "run": run, "names": names}


@pytest.fixture
def copy(pristine, tmp_path):
    """A fresh copy of the scene and the run (whose config points at the copied scene)."""
    return copy_scene_and_run(pristine, tmp_path)


def one_error_line(status: int, stderr: str, *words: str) -> str:
    lines = [line for line in stderr.strip().splitlines() if line.startswith("error:")]
    assert status == 2 and len(lines) == 1 and "Traceback" not in stderr, (status, stderr)
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]


# --- 1. checkpoints hold data only ------------------------------------------------------------------
class _Payload:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def _plant_payload(run: Path, marker: Path, as_torch_zip: bool) -> Path:
    path = run / "checkpoints" / "step_0000099.pt"
    body = {"iteration": 99, "params": _Payload(marker)}
    if as_torch_zip:
        torch.save(body, path)
    else:
        path.write_bytes(pickle.dumps(body))
    return path


@pytest.mark.parametrize("command", ["train", "bootstrap", "bootstrap-with-model", "eval", "render", "coverage"])
@pytest.mark.parametrize("as_torch_zip", [True, False])
def test_a_planted_checkpoint_payload_never_runs(copy, command, as_torch_zip):
    run, scene = copy["run"], copy["scene"]
    marker = copy["root"] / "PAYLOAD_RAN"
    planted = _plant_payload(run, marker, as_torch_zip)
    if command != "bootstrap-with-model":
        (run / "model.ply").unlink()
    argv = {
        "train": ["train", str(scene), "--out", str(run), "--resume"],
        "bootstrap": ["bootstrap", str(run), "--out", str(copy["root"] / "boot")],
        "bootstrap-with-model": ["bootstrap", str(run), "--out", str(copy["root"] / "boot")],
        "eval": ["eval", str(run)],
        "render": ["render", str(run), "--view", copy["names"][0], "--backend", "torch",
                   "--out", str(copy["root"] / "v.png")],
        "coverage": ["coverage", str(run), "--out", str(copy["root"] / "c.png")],
    }[command]
    status, _, stderr = run_main(argv)
    one_error_line(status, stderr, str(planted), "could run code")
    assert not marker.exists()


def test_a_checkpoint_with_missing_keys_is_one_line(copy):
    run = copy["run"]
    for old in (run / "checkpoints").iterdir():
        old.unlink()
    path = run / "checkpoints" / "step_0000030.pt"
    torch.save({"iteration": 30, "params": {}}, path)
    status, _, stderr = run_main(["train", str(copy["scene"]), "--out", str(run), "--resume"])
    one_error_line(status, stderr, str(path), "not an InceptionGS training checkpoint")


@pytest.mark.parametrize("protocol", range(pickle.HIGHEST_PROTOCOL + 1))
def test_a_payload_of_every_pickle_protocol_is_refused_not_skipped_as_damaged(copy, protocol):
    """A payload is never taken for damaged bytes (which would fall back to the older checkpoint
    beside it with a warning), and the line never advises loading it unsafely."""
    run = copy["run"]
    marker = copy["root"] / "PAYLOAD_RAN"
    planted = run / "checkpoints" / "step_0000099.pt"
    planted.write_bytes(pickle.dumps({"iteration": 99, "params": _Payload(marker)}, protocol=protocol))
    status, _, stderr = run_main(["train", str(copy["scene"]), "--out", str(run), "--resume"])
    line = one_error_line(status, stderr, str(planted), "could run code")
    assert "weights_only" not in stderr and "warning" not in stderr and not marker.exists(), line


def test_non_finite_parameters_in_a_checkpoint_are_refused_on_load(copy):
    from inceptiongs.runs.checkpoint import list_checkpoints

    run = copy["run"]
    _, path = list_checkpoints(run)[-1]
    payload = torch.load(path, weights_only=True)
    payload["params"]["means"][0, 1] = float("nan")
    torch.save(payload, path)
    for _, older in list_checkpoints(run)[:-1]:
        older.unlink()   # the only checkpoint: nothing to fall back to
    status, _, stderr = run_main(["train", str(copy["scene"]), "--out", str(run), "--resume"])
    one_error_line(status, stderr, str(path), "non-finite")


@pytest.mark.parametrize("extra", [[], ["--overwrite"]])
def test_the_default_bootstrap_output_never_follows_a_planted_sibling_symlink(copy, extra):
    """A bundle holding run/ and run_bootstrap -> elsewhere must not make a bootstrap write its
    model, checkpoints and logs elsewhere."""
    elsewhere = copy["root"] / "elsewhere"
    elsewhere.mkdir()
    (copy["root"] / "run_bootstrap").symlink_to(elsewhere)
    status, _, stderr = run_main(["bootstrap", str(copy["run"]), "--target-view", copy["names"][0], *extra])
    one_error_line(status, stderr, "run_bootstrap", "symlink", "--out")
    assert list(elsewhere.iterdir()) == []


def test_the_old_cache_folder_inside_a_scene_is_not_followed_out_of_it(copy):
    """SCENE/.inceptiongs (older versions' cache) planted as a symlink to elsewhere: the image
    there must not be read (eval would copy it into the run)."""
    import cv2

    from inceptiongs.scene.loader import load_scene

    scene_dir = copy["scene"]
    scene = load_scene(scene_dir, downscale=2)   # resized images: the cache path is taken
    camera = scene.cameras[0]
    outside = copy["root"] / "outside"
    planted = outside / "images" / f"{camera.width}x{camera.height}" / f"{camera.name}.png"
    planted.parent.mkdir(parents=True)
    red = np.zeros((camera.height, camera.width, 3), np.uint8)
    red[..., 2] = 255
    cv2.imwrite(str(planted), red)
    (scene_dir / ".inceptiongs").symlink_to(outside)
    image = load_scene(scene_dir, downscale=2).load_image(0)
    assert not (image[..., 0] > 0.99).all(), "the image outside the scene was read"


def test_prior_files_and_generated_scores_are_not_read_through_a_symlink_out_of_the_run(copy):
    from inceptiongs.errors import InputError
    from inceptiongs.evaluation.report_prior import generated_by_steps
    from inceptiongs.prior.trainer import read_prior_checkpoint

    run, outside = copy["run"], copy["root"] / "outside"
    (outside / "prior").mkdir(parents=True)
    torch.save({"backend": "tiny"}, outside / "prior" / "prior.pt")
    (run / "prior").symlink_to(outside / "prior")
    with pytest.raises(InputError, match="leads outside"):
        read_prior_checkpoint(run)
    (outside / "generated.json").write_text(json.dumps({"by_steps": [{"ddim_steps": 4}]}))
    (run / "eval").mkdir(exist_ok=True)
    (run / "eval" / "generated.json").symlink_to(outside / "generated.json")
    with pytest.raises(InputError, match="leads outside"):
        generated_by_steps(run)
    status, _, stderr = run_main(["prior", str(run), "--steps", "1"])
    one_error_line(status, stderr, "leads outside")


def test_checkpoints_are_written_as_plain_data_that_loads_weights_only(tmp_path):
    from inceptiongs.runs.checkpoint import load_checkpoint, plain_data, save_checkpoint

    payload = {"x": np.arange(3.0), "y": np.float64(2.5), "z": {3, 1}, "t": (1, 2)}
    assert plain_data(payload)["y"] == 2.5 and plain_data(payload)["z"] == [1, 3]
    path = save_checkpoint(tmp_path, 1, {**payload, "iteration": 1}, keep=1)
    loaded = torch.load(path, weights_only=True)
    assert torch.equal(loaded["x"], torch.arange(3.0, dtype=torch.float64)) and loaded["t"] == [1, 2]
    with pytest.raises(Exception, match="not an InceptionGS training checkpoint"):
        load_checkpoint(path)   # data only, but not a training checkpoint (no params, ...)


# --- 2. names in scene files stay inside the scene ----------------------------------------------------
def _rename_first_image(scene: Path, name: str) -> None:
    path = scene / "sparse" / "0" / "images.txt"
    lines = path.read_text().splitlines()
    tokens = lines[0].split(" ")
    tokens[-1] = name
    lines[0] = " ".join(tokens)
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("attack", ["absolute", "dotdot", "symlink"])
def test_image_names_that_leave_the_scene_are_refused(copy, attack):
    scene, secret = copy["scene"], copy["root"] / "secret.png"
    shutil.copy(scene / "images" / copy["names"][0], secret)
    if attack == "absolute":
        name = str(secret)
    elif attack == "dotdot":
        name = "../../secret.png"
    else:
        os.symlink(secret, scene / "images" / "link.png")
        name = "link.png"
    _rename_first_image(scene, name)
    for argv in (["info", str(scene)], ["eval", str(copy["run"])]):
        status, stdout, stderr = run_main(argv)
        one_error_line(status, stderr, repr(name))
        assert "outside" in stderr or "absolute" in stderr


def test_a_transforms_file_path_that_climbs_out_is_refused(copy):
    folder = copy["root"] / "tf"
    folder.mkdir()
    shutil.copy(copy["scene"] / "images" / copy["names"][0], copy["root"] / "secret.png")
    frame = {"file_path": "../secret.png", "transform_matrix": np.eye(4).tolist()}
    (folder / "transforms.json").write_text(json.dumps({"fl_x": 60, "fl_y": 60, "cx": 60, "cy": 45, "w": 120,
                                                        "h": 90, "frames": [frame]}))
    status, _, stderr = run_main(["info", str(folder)])
    one_error_line(status, stderr, "transforms.json frame 0", "leads outside")


# --- 3. writes never follow a planted symlink -----------------------------------------------------------
def test_eval_refuses_a_planted_eval_symlink(copy):
    elsewhere = copy["root"] / "elsewhere"
    elsewhere.mkdir()
    os.symlink(elsewhere, copy["run"] / "eval")
    status, _, stderr = run_main(["eval", str(copy["run"])])
    one_error_line(status, stderr, str(copy["run"] / "eval"), "symlink")
    assert list(elsewhere.iterdir()) == []


def test_appends_and_atomic_writes_below_a_named_folder_refuse_symlinks(tmp_path):
    from inceptiongs.io.atomic import OutputError, append_line, atomic_write_text, writing_under

    run, outside = tmp_path / "run", tmp_path / "outside.txt"
    run.mkdir()
    outside.write_text("keep\n")
    os.symlink(outside, run / "metrics.jsonl")
    os.symlink(tmp_path, run / "sub")
    with writing_under(run):
        with pytest.raises(OutputError):
            append_line(run / "metrics.jsonl", "{}")
        with pytest.raises(OutputError, match="symlink"):
            atomic_write_text(run / "sub" / "x.json", "{}")
    assert outside.read_text() == "keep\n" and not (tmp_path / "x.json").exists()
    atomic_write_text(run / "sub" / "x.json", "{}")    # outside writing_under: the caller's own path
    assert (tmp_path / "x.json").exists()


# --- 8. one line instead of a traceback ---------------------------------------------------------------
@pytest.mark.parametrize("key, value, words", [("iterations", "abc", "iterations must be an integer"),
                                               ("scene", 5, "scene must be a string"),
                                               ("downscale", "4", "downscale must be an integer"),
                                               ("downscale", 1000, "at least 11"),
                                               ("seed", -1, "seed must be in [0, 4294967295]")])
def test_config_json_with_wrong_values_is_one_line(copy, key, value, words):
    config = copy["run"] / "config.json"
    data = json.loads(config.read_text())
    data[key] = value
    config.write_text(json.dumps(data))
    status, _, stderr = run_main(["eval", str(copy["run"])])
    one_error_line(status, stderr, words)


@pytest.mark.parametrize("argv, words", [(["--seed", "-1"], "--seed"), (["--minutes", "nan"], "--minutes"),
                                         (["--minutes", "inf"], "--minutes")])
def test_train_refuses_values_it_cannot_use_and_writes_nothing(copy, argv, words):
    out = copy["root"] / "new_run"
    status, _, stderr = run_main(["train", str(copy["scene"]), "--out", str(out), *argv])
    one_error_line(status, stderr, words)
    assert not out.exists()


def test_bootstrap_refuses_minutes_nan(copy):
    status, _, stderr = run_main(["bootstrap", str(copy["run"]), "--minutes", "nan",
                                  "--out", str(copy["root"] / "boot")])
    one_error_line(status, stderr, "minutes")


def test_a_ply_declaring_400m_vertices_in_a_sparse_file_is_refused_before_allocating(copy):
    model = copy["run"] / "model.ply"
    head = model.read_bytes()
    end = head.index(b"end_header\n") + len(b"end_header\n")
    header = head[:end].decode()
    count = int(header.split("element vertex ")[1].split()[0])
    per_vertex = (len(head) - end) // count
    header = header.replace(f"element vertex {count}\n", "element vertex 400000000\n")
    with open(model, "wb") as handle:
        handle.write(header.encode())
        handle.truncate(len(header) + 400_000_000 * per_vertex)
    status, _, stderr = run_main(["render", str(copy["run"]), "--view", copy["names"][0], "--backend", "torch",
                                  "--out", str(copy["root"] / "v.png")])
    one_error_line(status, stderr, str(model), "400000000 declared vertices", "GiB")


def test_a_huge_sparse_points3d_bin_is_refused_before_reading(tmp_path):
    from inceptiongs.io.limits import available_memory_bytes
    from inceptiongs.scene.colmap import write_colmap_binary
    from scene_cases import known_cameras, known_points

    cameras = known_cameras(count=2)
    model = tmp_path / "scene" / "sparse" / "0"
    model.mkdir(parents=True)
    write_colmap_binary(model, [(c, "PINHOLE", [c.fx, c.fy, c.cx, c.cy]) for c in cameras], known_points(),
                        np.zeros((20, 3), np.uint8))
    size = max(51 * 10**9, 2 * (available_memory_bytes() or 0))
    with open(model / "points3D.bin", "r+b") as handle:
        handle.truncate(size)
    status, _, stderr = run_main(["info", str(tmp_path / "scene")])
    one_error_line(status, stderr, "points3D.bin", "GiB of memory")


@pytest.mark.parametrize("link", ["dangling", "loop"])
def test_a_dangling_or_looping_ply_symlink_in_a_run_is_no_traceback(copy, link):
    run = copy["run"]
    (run / "model.ply").unlink()
    target = run / "missing.ply" if link == "dangling" else run / "other.ply"
    os.symlink(target, run / "other.ply")
    status, _, stderr = run_main(["render", str(run), "--view", copy["names"][0], "--backend", "torch",
                                  "--out", str(copy["root"] / "v.png")])
    assert status in (0, 2) and "Traceback" not in stderr
    if status == 2:
        one_error_line(status, stderr)


def test_coverage_refuses_a_nan_roi(copy):
    status, _, stderr = run_main(["coverage", str(copy["run"]), "--roi", "nan", "0", "0", "1", "1", "1",
                                  "--out", str(copy["root"] / "c.png")])
    one_error_line(status, stderr, "--roi")


def test_report_names_a_metrics_line_whose_iteration_is_not_a_number(copy):
    metrics = copy["run"] / "metrics.jsonl"
    metrics.write_text(metrics.read_text() + json.dumps({"iteration": "x", "wall_s": 1.0, "all_psnr": 20.0}) + "\n")
    status, _, stderr = run_main(["report", str(copy["run"])])
    one_error_line(status, stderr, str(metrics), "iteration")


# --- 9. clear messages ------------------------------------------------------------------------------------
def _valid_huge_png(path: Path, side: int = 14000) -> None:
    """A valid side x side black RGB PNG, streamed (its pixels are never held in memory)."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)
    packer, row, parts = zlib.compressobj(9), b"\0" * (1 + 3 * side), []
    for _ in range(side):
        parts.append(packer.compress(row))
    parts.append(packer.flush())
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", side, side, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b""))


def test_a_valid_14000_pixel_png_is_called_too_large_with_the_limit(copy):
    image = copy["scene"] / "images" / copy["names"][0]
    _valid_huge_png(image)
    status, _, stderr = run_main(["train", str(copy["scene"]), "--out", str(copy["root"] / "r2"),
                                  "--iterations", "1"])
    line = one_error_line(status, stderr, str(image), "too large", "at most")
    assert "cannot read image header" not in line


def test_an_image_symlinked_to_itself_is_a_symlink_loop(copy):
    image = copy["scene"] / "images" / copy["names"][0]
    image.unlink()
    os.symlink(image, image)
    status, _, stderr = run_main(["train", str(copy["scene"]), "--out", str(copy["root"] / "r2"),
                                  "--iterations", "1"])
    one_error_line(status, stderr, "symlink loop")


def test_resume_with_more_iterations_says_the_stored_schedule_is_kept(copy):
    status, _, stderr = run_main(["train", str(copy["scene"]), "--out", str(copy["run"]), "--resume",
                                  "--iterations", "60"])
    assert status == 0, stderr
    assert "keeps its schedule of 1 iterations" in stderr and "--iterations 60 is ignored" in stderr


def test_report_does_not_read_a_metrics_log_that_leads_out_of_the_run(copy):
    secret = copy["root"] / "secret.txt"
    secret.write_text(json.dumps({"iteration": 1, "wall_s": 1.0, "all_psnr": 99.0}) + "\n")
    metrics = copy["run"] / "metrics.jsonl"
    metrics.unlink()
    os.symlink(secret, metrics)
    status, stdout, stderr = run_main(["report", str(copy["run"])])
    one_error_line(status, stderr, str(metrics), "outside")
    assert "99" not in stdout
