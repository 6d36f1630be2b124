"""--device auto|cpu|cuda (train, render; prior, generate and eval --generated): what each chooses,
and one line, exit 2, naming what is missing when cuda cannot run (GPU, gsplat, CUDA compiler
simulated absent or present)."""

from __future__ import annotations

import json

import pytest
import torch

from inceptiongs.cli import main
from inceptiongs.errors import InputError
from inceptiongs.rasterizer import interface
from inceptiongs.rasterizer.backend import numba_installed
from inceptiongs.rasterizer.interface import device_line, select_rasterizer
from inceptiongs.runs.config import TrainConfig

CPU_NAME = "numba" if numba_installed() else "torch"


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
        select_rasterizer("cuda")
    message = str(raised.value)
    assert message.startswith(f"--device cuda: {missing}") and how in message and "\n" not in message
    name, rasterizer, why = select_rasterizer("auto")   # auto falls back to the CPU, saying why
    assert (name, rasterizer.device, why) == (CPU_NAME, "cpu", missing)


def test_auto_takes_gsplat_when_nothing_is_missing(monkeypatch):
    simulate(monkeypatch, True, True, True)
    chosen = {}
    monkeypatch.setitem(interface.RASTERIZERS, "gsplat", lambda: chosen.setdefault("r", interface.ReferenceRasterizer(
        "gsplat", "torch", "cuda")))  # stands in: gsplat itself cannot import without a GPU
    name, rasterizer, why = select_rasterizer("auto")
    assert name == "gsplat" and rasterizer is chosen["r"] and "Simulated GPU" in why
    assert select_rasterizer("cuda")[0] == "gsplat"


def test_a_model_on_a_gpu_renders_with_gsplat_where_no_rasterizer_is_named(monkeypatch):
    # The prior's G-buffer and sampler start, and render_rgb, render with rasterizer_for(the
    # Gaussians' device): gsplat for CUDA tensors, the CPU's best for host ones or without gsplat.
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
    assert select_rasterizer("cpu")[0] == CPU_NAME
    from inceptiongs.commands.device import chosen_rasterizer
    rasterizer, line = chosen_rasterizer("auto")
    assert rasterizer.name == CPU_NAME
    assert line == f"device: cpu ({CPU_NAME} rasterizer): no CUDA GPU visible"
    rasterizer, line = chosen_rasterizer("cpu")
    assert rasterizer.name == CPU_NAME and line is None   # only auto says it
    assert capsys.readouterr().err == ""   # the caller prints it once the work has started
    assert device_line(*select_rasterizer("cpu")).startswith("device: cpu")


@pytest.mark.parametrize("command", [["prior", "RUN", "--steps", "1"],
                                     ["generate", "RUN", "--view", "x", "--out", "OUT/g.png"],
                                     ["eval", "RUN", "--generated"]])
def test_the_priors_commands_refuse_cuda_without_a_gpu_in_one_line_before_any_work(monkeypatch, tmp_path, capsys,
                                                                                    command):
    # torch's own error here is an AssertionError traceback; the run need not even exist.
    simulate(monkeypatch, False, False, False)
    args = [a.replace("RUN", str(tmp_path / "run")).replace("OUT", str(tmp_path)) for a in command]
    assert main(args + ["--device", "cuda"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: --device cuda: no CUDA GPU visible (torch.cuda.is_available() is False: " \
        "needs an NVIDIA GPU, its driver and a CUDA build of torch)"
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(SystemExit) as exit_info:   # argparse: a device name it does not know
        main(args + ["--device", "gpu"])
    assert exit_info.value.code == 2


def test_train_device_cuda_without_a_gpu_exits_2_with_one_line(monkeypatch, tmp_path, capsys):
    simulate(monkeypatch, False, True, True)
    status = main(["train", str(tmp_path), "--out", str(tmp_path / "run"), "--device", "cuda", "--iterations", "1"])
    err = capsys.readouterr().err.strip()
    assert status == 2 and err == "error: --device cuda: no CUDA GPU visible (torch.cuda.is_available() is False: " \
        "needs an NVIDIA GPU, its driver and a CUDA build of torch)"
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
