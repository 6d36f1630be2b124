"""Numbers, sizes and odd files a user or a shared run can give, each refused in one line naming
the flag or the file (exit status 2), never a traceback, never an allocation that cannot fit;
and a stop meeting a full disk still exits with the stop's status and its "stopped at" line."""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal

import pytest
import torch

from inceptiongs.errors import InputError
from fuzz_values_cases import Reached, run_cli
from shared_run_cases import copy_scene_and_run, save_tiny_prior, train_one_step, write_text_scene

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def one_error_line(status: int, stderr: str, *words: str) -> str:
    # A progress bar may still be on the line the error starts (its carriage return splits it).
    lines = [line[line.index("error:"):] for line in stderr.strip().splitlines() if "error:" in line]
    assert status == 2 and len(lines) == 1 and "Traceback" not in stderr, (status, stderr)
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]


# --- the rules --------------------------------------------------------------------------------------
def test_a_rule_checks_kind_range_and_names_where():
    from inceptiongs.io.values import RULES, flag

    assert RULES["seed"].check(7, "--seed") == 7
    assert RULES["minutes"].check(2, "x") == 2.0 and isinstance(RULES["minutes"].check(2, "x"), float)
    for value, words in [(-1, "--seed must be in [0, 4294967295], got -1"), (1.5, "must be an integer"),
                         (True, "must be an integer"), ("3", 'got "3"')]:
        with pytest.raises(InputError, match=None) as info:
            RULES["seed"].check(value, "--seed")
        assert words in str(info.value)
    for text in ("nan", "inf", "-inf", "text"):
        with pytest.raises(InputError, match="finite number"):
            flag("minutes").bound("--minutes")(text)


def _stub_every_command(monkeypatch) -> None:
    import inceptiongs.cli as cli

    def reached(_args):
        raise Reached()

    for module in cli.available_commands().values():
        monkeypatch.setattr(module, "run", reached)


@pytest.mark.parametrize("argv, flag", [
    (["demo", "OUT", "--seed", "-1"], "--seed"),
    (["demo-scene", "OUT", "--seed", "-1"], "--seed"),
    (["demo", "OUT", "--minutes", "nan"], "--minutes"),
    (["demo", "OUT", "--minutes", "inf"], "--minutes"),
    (["demo", "OUT", "--bootstrap-minutes", "nan"], "--bootstrap-minutes"),
    (["demo", "OUT", "--bootstrap-minutes", "inf"], "--bootstrap-minutes"),
    (["prior", "RUN", "--minutes", "nan"], "--minutes"),
    (["prior", "RUN", "--appearance-weight", "nan"], "--appearance-weight"),
    (["prior", "RUN", "--appearance-weight", "inf"], "--appearance-weight"),
    (["prior", "RUN", "--eval-every-minutes", "nan"], "--eval-every-minutes"),
    (["prior", "RUN", "--seed", "-1"], "--seed"),
    (["generate", "RUN", "--view", "v", "--out", "o.png", "--seed", "-1"], "--seed"),
    (["eval", "RUN", "--seed", "-1"], "--seed"),
    (["prior", "RUN", "--unet-width", "1e6"], "--unet-width"),
])
def test_a_flag_value_no_run_can_use_is_one_line_before_the_command_runs(argv, flag, monkeypatch):
    _stub_every_command(monkeypatch)
    status, stderr = run_cli(argv)
    one_error_line(status, stderr, flag)


# --- a scene, a one-step run and a tiny prior ----------------------------------------------------------
@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("values")
    scene, run = root / "scene", root / "run"
    names = write_text_scene(scene)
    train_one_step(scene, run)
    save_tiny_prior(run)
    return {"scene": scene, "run": run, "names": names}


@pytest.fixture
def copy(world, tmp_path):
    return copy_scene_and_run(world, tmp_path)


# --- sizes with a ceiling from the memory --------------------------------------------------------------
@pytest.mark.parametrize("flag, value", [("--unet-width", "1000000"), ("--batch-size", "100000000")])
def test_a_prior_too_large_for_the_memory_is_refused_before_it_is_built(copy, flag, value):
    status, stderr = run_cli(["prior", str(copy["run"]), "--restart", "--steps", "1", "--device", "cpu", flag, value])
    one_error_line(status, stderr, flag, "needs about", "available")


def test_a_patch_larger_than_the_photos_is_no_memory_problem(copy, monkeypatch):
    import inceptiongs.prior.trainer as prior_trainer

    def reached(self, **_kwargs):
        raise Reached()                          # checked and built: the training itself is not needed

    monkeypatch.setattr(prior_trainer.PriorTrainer, "train", reached)
    status, stderr = run_cli(["prior", str(copy["run"]), "--restart", "--steps", "1", "--device", "cpu",
                              "--unet-width", "8", "--patch-size", "1000000"])
    assert status == 0, stderr                  # patches shrink to the photos, as they always did


def test_a_generation_window_too_large_for_the_memory_is_refused_before_sampling(copy):
    out = copy["root"] / "g.png"
    status, stderr = run_cli(["generate", str(copy["run"]), "--view", copy["names"][1], "--out", str(out),
                              "--window", "8192", "--device", "cpu"])
    one_error_line(status, stderr, "--window 8192", "needs about")
    assert not out.exists()


def test_the_footprint_follows_the_sizes_and_the_ceiling_the_memory():
    from inceptiongs.prior.footprint import check_sampling_fits, check_training_fits, sampling_bytes, training_bytes
    from inceptiongs.prior.unet import UNetConfig

    unet = UNetConfig()
    small = training_bytes(unet, 16, 64, 4)
    assert 10 * 2**20 < small < 2**30                 # the default prior trains in well under a GiB
    assert training_bytes(unet, 16, 64, 8) > 1.9 * (small - training_bytes(unet, 16, 64, 0))
    assert training_bytes(UNetConfig(base_width=64), 16, 64, 0) > 3.5 * training_bytes(unet, 16, 64, 0)
    assert sampling_bytes(unet, 16, 48, 64, 8192) > 100 * sampling_bytes(unet, 16, 48, 64, 64)
    check_training_fits(unet, 16, 64, 4, "x", available=2**30)
    with pytest.raises(InputError, match="x: training the prior .* needs about"):
        check_training_fits(unet, 16, 64, 4, "x", available=small - 1)
    with pytest.raises(InputError, match="--window 256: generating a 64x48 image"):
        check_sampling_fits(unet, 16, 48, 64, 256, "--window 256", available=2**20)


# --- files that used to give tracebacks ---------------------------------------------------------------
def test_an_image_name_too_long_for_the_file_system_is_one_line(copy):
    long_name = "a" * 300 + ".png"
    images = copy["scene"] / "sparse" / "0" / "images.txt"
    images.write_text(images.read_text().replace(copy["names"][0], long_name))
    status, _, = run_cli(["info", str(copy["scene"])])[:1] + (None,)
    assert status == 0            # info reports the scene, the image among its warnings
    status, stderr = run_cli(["train", str(copy["scene"]), "--out", str(copy["root"] / "r"), "--iterations", "1"])
    one_error_line(status, stderr, "too long")


def test_bootstrap_overwrite_refuses_a_symlinked_checkpoints_folder(copy):
    elsewhere = copy["root"] / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "step_0000002.pt").write_bytes(b"kept")
    out = copy["root"] / "boot"
    out.mkdir()
    (out / "config.json").write_text((copy["run"] / "config.json").read_text())
    (out / "model.ply").write_bytes((copy["run"] / "model.ply").read_bytes())
    os.symlink(elsewhere, out / "checkpoints")
    status, stderr = run_cli(["bootstrap", str(copy["run"]), "--out", str(out), "--target-view", copy["names"][1],
                              "--iterations", "1", "--overwrite"])
    one_error_line(status, stderr, "checkpoints", "symlink")
    assert (elsewhere / "step_0000002.pt").read_bytes() == b"kept"


def test_a_run_config_naming_its_scene_by_a_number_is_one_line(copy):
    config = copy["run"] / "config.json"
    data = json.loads(config.read_text())
    data["scene"] = 5
    config.write_text(json.dumps(data))
    status, stderr = run_cli(["render", str(copy["run"]), "--view", copy["names"][1], "--out",
                              str(copy["root"] / "x.png"), "--backend", "torch"])
    one_error_line(status, stderr, "config.json", "scene must be a string")


def test_a_metrics_log_with_a_text_iteration_is_one_line_on_resume(copy):
    metrics = copy["run"] / "metrics.jsonl"
    lines = metrics.read_text().splitlines()
    record = json.loads(lines[-1])
    record["iteration"] = str(record["iteration"])
    metrics.write_text("\n".join([*lines[:-1], json.dumps(record)]) + "\n")
    status, stderr = run_cli(["train", str(copy["scene"]), "--out", str(copy["run"]), "--resume", "--device", "cpu"])
    one_error_line(status, stderr, "metrics.jsonl", "iteration must be an integer")


def test_flags_json_intrinsics_beyond_any_camera_are_one_line(copy):
    from inceptiongs.scene.loader import load_scene

    camera = load_scene(copy["scene"], require_images=False).cameras[1]
    entry = {**camera.to_json_dict(), "fx": 1e308, "fy": 1e308}
    (copy["run"] / "flags.json").write_text(json.dumps({"version": 1, "flags": [{"name": "f", "camera": entry}]}))
    status, stderr = run_cli(["bootstrap", str(copy["run"]), "--out", str(copy["root"] / "b"), "--iterations", "1"])
    one_error_line(status, stderr, "flags.json", "fx must be in")


def test_float16_parameters_in_a_checkpoint_are_one_line(copy):
    (path,) = (copy["run"] / "checkpoints").glob("step_*.pt")
    payload = torch.load(path, weights_only=True)
    payload["params"] = {name: tensor.half() for name, tensor in payload["params"].items()}
    torch.save(payload, path)
    config = copy["run"] / "config.json"
    data = json.loads(config.read_text())
    data["iterations"] = 3            # something left to train
    config.write_text(json.dumps(data))
    status, stderr = run_cli(["train", str(copy["scene"]), "--out", str(copy["run"]), "--resume", "--device", "cpu"])
    one_error_line(status, stderr, "float16")


def test_a_huge_sparse_exclude_photos_file_is_one_line_not_read(copy):
    big = copy["root"] / "names.txt"
    with open(big, "wb") as handle:
        handle.truncate(50 * 2**30)
    status, stderr = run_cli(["train", str(copy["scene"]), "--out", str(copy["root"] / "r"), "--iterations", "1",
                              "--exclude-photos", str(big)])
    one_error_line(status, stderr, "names.txt", "too large")


# --- messages that were unclear -----------------------------------------------------------------------
class _Payload:
    def __reduce__(self):
        return (os.getcwd, ())


@pytest.mark.parametrize("damage", ["truncated", "payload"])
def test_a_corrupt_or_payload_prior_checkpoint_is_one_plain_line(copy, damage):
    import pickle

    prior = copy["run"] / "prior" / "prior.pt"
    if damage == "truncated":
        prior.write_bytes(prior.read_bytes()[:3000])
    else:
        prior.write_bytes(pickle.dumps(_Payload(), protocol=0))
    status, stderr = run_cli(["generate", str(copy["run"]), "--view", copy["names"][1], "--out",
                              str(copy["root"] / "g.png"), "--device", "cpu"])
    line = one_error_line(status, stderr, "prior.pt")
    assert "\x1b" not in stderr and len(stderr.strip().splitlines()) == 1
    assert "weights_only" not in line             # torch's advice to load it unsafely is not passed on


def test_a_short_write_without_an_error_number_on_a_full_disk_says_no_space(tmp_path, monkeypatch):
    from inceptiongs.io.atomic import output_error

    class Full:
        f_bavail, f_frsize = 0, 4096

    monkeypatch.setattr(os, "statvfs", lambda path: Full())
    exc = OSError("400000 requested and 0 written")          # what numpy's tofile raises
    assert str(output_error(tmp_path / "x.npy", exc)) == f"{tmp_path / 'x.npy'}: cannot write (no space left on device)"
    monkeypatch.setattr(os, "statvfs", lambda path: type("Free", (), {"f_bavail": 10**6, "f_frsize": 4096})())
    assert "400000 requested and 0 written" in str(output_error(tmp_path / "x.npy", exc))
    assert "no space left" in str(output_error(tmp_path / "x", OSError(errno.ENOSPC, "No space left on device")))


def test_a_stop_whose_save_meets_a_full_disk_exits_130_with_its_stopped_line(copy, monkeypatch):
    import inceptiongs.train.trainer as trainer
    from inceptiongs.io.atomic import OutputError

    def stopped_then_full(config, out, **kwargs):
        kwargs["control"].listening.set()             # its loop has begun
        os.kill(os.getpid(), signal.SIGINT)           # Ctrl+C during training: the handler asks to stop
        raise OutputError(f"{out}/model.ply: cannot write (no space left on device)")

    monkeypatch.setattr(trainer, "train", stopped_then_full)
    status, stderr = run_cli(["train", str(copy["scene"]), "--out", str(copy["root"] / "r"), "--iterations", "5"])
    assert status == 130, stderr
    assert "Traceback" not in stderr and "no space left on device" in stderr
    assert "stopped at" in stderr and "--resume" in stderr


def test_bootstrap_into_its_own_run_says_only_that_the_folders_must_differ(copy):
    status, stderr = run_cli(["bootstrap", str(copy["run"]), "--out", str(copy["run"]), "--target-view",
                              copy["names"][1]])
    line = one_error_line(status, stderr, "must differ")
    assert "stopped bootstrap" not in line and "--resume" not in line


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_image_and_a_looping_images_folder_are_named_as_such(copy):
    fifo = copy["scene"] / "images" / copy["names"][1]
    fifo.unlink()
    os.mkfifo(fifo)
    status, stderr = run_cli(["train", str(copy["scene"]), "--out", str(copy["root"] / "r1"), "--iterations", "1"])
    one_error_line(status, stderr, "FIFO")
    images = copy["scene"] / "images"
    shutil.rmtree(images)
    os.symlink(images, images)                         # a link to itself: a loop
    status, stderr = run_cli(["train", str(copy["scene"]), "--out", str(copy["root"] / "r2"), "--iterations", "1"])
    one_error_line(status, stderr, "symlink loop")
    assert "does not exist" not in stderr


@pytest.mark.parametrize("key", ["k", "l"])
def test_virtual_view_counts_past_the_memory_are_one_line_before_any_pose_is_made(tmp_path, key):
    from inceptiongs.bootstrap.config import BootstrapConfig

    BootstrapConfig(**{key: 1000}).validate("x.json")      # large but fits: a long, fine-grained path
    with pytest.raises(InputError, match=rf"x.json: k x l = \d+ virtual view poses per target needs about"):
        BootstrapConfig(**{key: 10**12}).validate("x.json")
