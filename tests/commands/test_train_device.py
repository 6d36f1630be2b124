"""--device auto|cpu|cuda, one rule for every command (resolve_device): what each value chooses,
the rasterizer and the torch device together; one line, exit 2, naming what is missing when cuda
cannot run (GPU, gsplat, CUDA compiler simulated absent or present) and naming the run's
config.json when the value is the run's; --device cpu puts nothing on a GPU where one is there."""

from __future__ import annotations

import json

import pytest
import torch

from inceptiongs.cli import main
from inceptiongs.errors import InputError
from inceptiongs.rasterizer import interface
from inceptiongs.rasterizer.backend import numba_installed
from inceptiongs.rasterizer.interface import resolve_device
from inceptiongs.runs.config import TrainConfig

CPU_NAME = "numba" if numba_installed() else "torch"
NO_GPU = ("no CUDA GPU visible (torch.cuda.is_available() is False: needs an NVIDIA GPU, its driver and a CUDA "
          "build of torch)")


def simulate(monkeypatch, gpu: bool, gsplat: bool, compiler: bool) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: gpu)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda *a: "Simulated GPU")
    monkeypatch.setattr(interface, "gsplat_installed", lambda: gsplat)
    monkeypatch.setattr(interface, "cuda_compiler", lambda: "/usr/local/cuda" if compiler else None)


@pytest.mark.parametrize("gpu,gsplat,compiler,missing,how", [
    (False, True, True, "no CUDA GPU visible", "torch.cuda.is_available() is False"),
    (True, False, True, "gsplat is not installed", "pip install 'inceptiongs[cuda]'"),
    (True, True, False, "no CUDA compiler for gsplat's first build", "install a CUDA toolkit"),
])
def test_cuda_names_what_is_missing_and_how_to_get_it(monkeypatch, gpu, gsplat, compiler, missing, how):
    simulate(monkeypatch, gpu, gsplat, compiler)
    with pytest.raises(InputError) as raised:
        resolve_device("cuda")
    message = str(raised.value)
    assert message.startswith(f"--device cuda: {missing}") and how in message and "\n" not in message
    device = resolve_device("auto")   # auto falls back to the CPU, saying why
    assert (device.name, device.torch_device, device.why) == (CPU_NAME, torch.device("cpu"), missing)
    assert device.to_json() == {"asked": "auto", "device": "cpu", "rasterizer": CPU_NAME, "why": missing}
    # A value read from a run names its file, and what to give instead.
    with pytest.raises(InputError, match=r"^run/config.json: device cuda: .*; use cpu$"):
        resolve_device("cuda", "run/config.json: device", instead="use cpu")
    with pytest.raises(InputError, match=r"^run/config.json: device must be one of auto, cpu, cuda, got 'gpu'$"):
        resolve_device("gpu", "run/config.json: device")


def test_auto_takes_gsplat_when_nothing_is_missing(monkeypatch):
    simulate(monkeypatch, True, True, True)
    chosen = {}
    monkeypatch.setitem(interface.RASTERIZERS, "gsplat", lambda: chosen.setdefault("r", interface.ReferenceRasterizer(
        "gsplat", "torch", "cuda")))  # stands in: gsplat itself cannot import without a GPU
    device = resolve_device("auto")
    assert device.name == "gsplat" and device.rasterizer is chosen["r"] and "Simulated GPU" in device.why
    assert device.torch_device == torch.device("cuda")   # the prior and the run's tensors go where gsplat renders
    assert device.note == "device: cuda (gsplat rasterizer): CUDA GPU Simulated GPU and gsplat found"
    cuda = resolve_device("cuda")
    assert (cuda.name, cuda.torch_device, cuda.why, cuda.note) == ("gsplat", torch.device("cuda"), "--device cuda", None)
    # --device cpu on a machine where cuda would run: everything on the CPU.
    cpu = resolve_device("cpu")
    assert (cpu.name, cpu.torch_device, cpu.why, cpu.note) == (CPU_NAME, torch.device("cpu"), "--device cpu", None)


def test_a_model_on_a_gpu_renders_with_gsplat_where_no_rasterizer_is_named(monkeypatch):
    # The prior's G-buffer and sampler start, and render_rgb, render with rasterizer_for(the
    # Gaussians' device), the same rule: gsplat for CUDA tensors, the CPU's best for host ones
    # or without gsplat.
    simulate(monkeypatch, True, True, True)
    stand_in = interface.ReferenceRasterizer("gsplat", "torch", "cuda")
    monkeypatch.setitem(interface.RASTERIZERS, "gsplat", lambda: stand_in)
    assert interface.rasterizer_for("cuda") is stand_in
    assert interface.rasterizer_for(torch.device("cuda", 0)) is stand_in
    assert interface.rasterizer_for("cpu").name == CPU_NAME
    monkeypatch.setattr(interface, "cuda_compiler", lambda: None)   # gsplat could not build its kernels
    assert interface.rasterizer_for("cuda").name == CPU_NAME
    monkeypatch.setattr(interface, "cuda_compiler", lambda: "/usr/local/cuda")
    monkeypatch.setattr(interface, "gsplat_installed", lambda: False)
    assert interface.rasterizer_for("cuda").name == CPU_NAME


def test_cpu_and_the_auto_line_on_a_machine_without_a_gpu(monkeypatch, capsys):
    simulate(monkeypatch, False, False, False)
    assert resolve_device("cpu").name == CPU_NAME
    from inceptiongs.commands.device import command_device
    device = command_device("auto")
    assert device.name == CPU_NAME
    assert device.note == f"device: cpu ({CPU_NAME} rasterizer): no CUDA GPU visible"
    device = command_device("cpu")
    assert device.name == CPU_NAME and device.note is None   # only auto says it
    assert device.line.startswith("device: cpu")
    assert capsys.readouterr().err == ""   # the caller prints it once the work has started


@pytest.mark.parametrize("command", [["prior", "RUN", "--steps", "1"],
                                     ["generate", "RUN", "--view", "x", "--out", "OUT/g.png"],
                                     ["eval", "RUN", "--generated"], ["eval", "RUN"],
                                     ["render", "RUN", "--view", "x", "--backend", "torch", "--out", "OUT/r.png"],
                                     ["demo", "OUT/demo"]])
def test_every_command_refuses_cuda_without_a_gpu_in_one_line_before_any_work(monkeypatch, tmp_path, capsys, command):
    # torch's own error here is an AssertionError traceback; the run need not even exist, and
    # the demo writes no scene.
    simulate(monkeypatch, False, False, False)
    args = [a.replace("RUN", str(tmp_path / "run")).replace("OUT", str(tmp_path)) for a in command]
    assert main(args + ["--device", "cuda"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: --device cuda: {NO_GPU}"
    assert list(tmp_path.iterdir()) == []
    assert main(args + ["--device", "gpu"]) == 2   # argparse: a device name it does not know, one line
    assert capsys.readouterr().err.count("\n") == 1


def test_train_device_cuda_without_a_gpu_exits_2_with_one_line(monkeypatch, tmp_path, capsys):
    simulate(monkeypatch, False, True, True)
    status = main(["train", str(tmp_path), "--out", str(tmp_path / "run"), "--device", "cuda", "--iterations", "1"])
    err = capsys.readouterr().err.strip()
    assert status == 2 and err == f"error: --device cuda: {NO_GPU}"
    assert not (tmp_path / "run").exists()


def test_render_device_cuda_without_gsplat_exits_2(monkeypatch, tmp_path, capsys):
    simulate(monkeypatch, True, False, True)
    status = main(["render", str(tmp_path / "model.ply"), "--camera", str(tmp_path / "cam.json"), "--backend", "torch",
                   "--device", "cuda", "--out", str(tmp_path / "out.png")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "pip install 'inceptiongs[cuda]'" in err[0]


def test_config_records_the_device_and_old_files_load(tmp_path):
    config = TrainConfig(scene=str(tmp_path), device="cpu")
    config.save(tmp_path / "config.json")
    saved = json.loads((tmp_path / "config.json").read_text())
    assert saved["device"] == "cpu" and TrainConfig.load(tmp_path / "config.json").device == "cpu"
    del saved["device"]                      # a config.json written before the field existed
    (tmp_path / "old.json").write_text(json.dumps(saved))
    assert TrainConfig.load(tmp_path / "old.json").device == "auto"
    saved["device"] = "gpu"
    (tmp_path / "bad.json").write_text(json.dumps(saved))
    with pytest.raises(InputError, match="device must be one of auto, cpu, cuda"):
        TrainConfig.load(tmp_path / "bad.json")


@pytest.fixture
def gpu_that_must_not_be_used(monkeypatch):
    """A machine where --device auto would choose the GPU; choosing gsplat fails the test. On a
    machine without CUDA (as here) any tensor sent to the GPU raises as well."""
    simulate(monkeypatch, True, True, True)

    def gsplat_chosen():
        raise AssertionError("gsplat was chosen under --device cpu")
    monkeypatch.setitem(interface.RASTERIZERS, "gsplat", gsplat_chosen)


CPU_RECORD = {"asked": "cpu", "device": "cpu", "rasterizer": CPU_NAME, "why": "--device cpu"}


@pytest.mark.slow
def test_device_cpu_puts_the_prior_and_the_data_on_the_cpu_beside_a_gpu(gpu_that_must_not_be_used, tmp_path, capsys):
    from inceptiongs.prior.trainer import read_prior_checkpoint
    from demo_cases import copy_of_demo_scene
    from inceptiongs.scene.loader import load_scene

    scene = copy_of_demo_scene(tmp_path / "scene")
    run = tmp_path / "run"
    assert main(["train", str(scene), "--out", str(run), "--downscale", "4", "--iterations", "2", "--protocol",
                 "unstructured", "--prior", "1", "--device", "cpu"]) == 0
    assert json.loads((run / "config.json").read_text())["device"] == "cpu"
    assert read_prior_checkpoint(run)["device"] == "cpu"          # train --prior: the prior beside the run
    assert main(["prior", str(run), "--steps", "1", "--device", "cpu"]) == 0
    assert read_prior_checkpoint(run)["device"] == "cpu"
    view = load_scene(scene, downscale=4).cameras[0].name
    assert main(["generate", str(run), "--view", view, "--out", str(tmp_path / "g.png"), "--steps", "1",
                 "--device", "cpu"]) == 0
    assert main(["eval", str(run), "--generated", "--ddim-steps", "1", "--device", "cpu", "--json"]) == 0
    assert json.loads((run / "eval" / "eval.json").read_text())["device"] == CPU_RECORD
    assert main(["bootstrap", str(run), "--out", str(tmp_path / "boot"), "--iterations", "1"]) == 0   # the run's device
    summary = json.loads((tmp_path / "boot" / "bootstrap" / "summary.json").read_text())
    assert summary["device"] == {"device": "cpu", "rasterizer": CPU_NAME}
    assert "device:" not in capsys.readouterr().err   # an explicit --device prints no choice


def test_a_runs_recorded_device_is_the_default_and_the_flag_overrides_it(monkeypatch, tmp_path, capsys):
    from prior_cases import make_stand_in_run

    run = make_stand_in_run(tmp_path, protocol="unstructured")
    saved = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**saved, "device": "cuda"}))   # trained on a GPU
    simulate(monkeypatch, False, False, False)
    refused = f"error: {run / 'config.json'}: device cuda: {NO_GPU}; --device cpu or --device auto runs it here"
    view = ["--view", load_scene_view(run)]
    for command in (["eval", str(run)], ["prior", str(run), "--steps", "1"],
                    ["coverage", str(run), "--out", str(tmp_path / "c.png")],
                    ["render", str(run), *view, "--backend", "torch", "--out", str(tmp_path / "r.png")]):
        assert main(command) == 2, command
        assert capsys.readouterr().err.strip() == refused, command
    # The bootstrap has no --device (its few flags; it runs where stage I ran): the same line without the way out.
    assert main(["bootstrap", str(run), "--out", str(tmp_path / "boot")]) == 2
    assert capsys.readouterr().err.strip() == refused.split("; --device")[0]
    assert not (tmp_path / "boot").exists()
    assert main(["eval", str(run), "--device", "cpu", "--json"]) == 0
    assert json.loads((run / "eval" / "eval.json").read_text())["device"] == CPU_RECORD
    assert main(["render", str(run), *view, "--backend", "torch", "--device", "cpu", "--out",
                 str(tmp_path / "r.png")]) == 0
    # --device is the library rasterizer's: the GL renderer takes none (one line, before any GL).
    assert main(["render", str(run), *view, "--backend", "gl", "--device", "cpu", "--out", str(tmp_path / "g.png")]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "error: --device cpu: applies to --backend torch (the library's rasterizer); --backend gl draws wherever its "
        "OpenGL context runs")


def load_scene_view(run) -> str:
    from inceptiongs.scene.loader import load_scene

    return load_scene(TrainConfig.load(run / "config.json").scene, downscale=4).cameras[0].name


def test_train_resume_takes_the_runs_device_unless_told(monkeypatch, tmp_path, capsys):
    from demo_cases import copy_of_demo_scene

    scene = copy_of_demo_scene(tmp_path / "scene")
    run = tmp_path / "run"
    train = ["train", str(scene), "--out", str(run), "--downscale", "4", "--iterations", "1", "--protocol", "none"]
    assert main(train + ["--device", "cpu"]) == 0
    saved = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**saved, "device": "cuda"}))   # as if trained on a GPU
    simulate(monkeypatch, False, False, False)
    capsys.readouterr()
    assert main(train + ["--resume"]) == 2
    assert capsys.readouterr().err.strip() == (f"error: {run / 'config.json'}: device cuda: {NO_GPU}; --device cpu "
                                               "or --device auto runs it here")
    assert main(train + ["--resume", "--device", "cpu"]) == 0   # checkpoints are CPU tensors: it resumes here
    assert json.loads((run / "config.json").read_text())["device"] == "cpu"
