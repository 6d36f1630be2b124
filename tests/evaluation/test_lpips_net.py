"""LPIPS as the project's own network (inceptiongs.evaluation.lpips_net): weights read as plain
tensors, TorchScript and pickled objects refused without running them, the distance checked
against an independent assembly of the same network from torch.nn layers."""

from __future__ import annotations

import pickle
import sys

import pytest
import torch
import torch.nn.functional as F

from inceptiongs.errors import InputError
from inceptiongs.evaluation.lpips_net import NORM_EPS, SCALE, SHIFT, load_lpips, lpips_shapes, read_weights

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")


def random_weights(seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    weights = {}
    for name, shape in lpips_shapes().items():
        tensor = torch.randn(shape, generator=g) * 0.1
        weights[name] = tensor.abs() if name.startswith("lin") else tensor
    return weights


def reference_distance(weights, a, b) -> float:
    """LPIPS assembled from torch.nn layers in AlexNet's published layout (torchvision's)."""
    convs = [torch.nn.Conv2d(3, 64, 11, 4, 2), torch.nn.Conv2d(64, 192, 5, 1, 2), torch.nn.Conv2d(192, 384, 3, 1, 1),
             torch.nn.Conv2d(384, 256, 3, 1, 1), torch.nn.Conv2d(256, 256, 3, 1, 1)]
    for i, conv in enumerate(convs):
        conv.weight.data, conv.bias.data = weights[f"conv{i}.weight"], weights[f"conv{i}.bias"]
    layers = [convs[0], torch.nn.ReLU(), torch.nn.MaxPool2d(3, 2), convs[1], torch.nn.ReLU(), torch.nn.MaxPool2d(3, 2),
              convs[2], torch.nn.ReLU(), convs[3], torch.nn.ReLU(), convs[4], torch.nn.ReLU()]
    taps = (1, 4, 7, 9, 11)

    def features(x):
        x = (x - torch.tensor(SHIFT).view(1, 3, 1, 1)) / torch.tensor(SCALE).view(1, 3, 1, 1)
        out = []
        for k, layer in enumerate(layers):
            x = layer(x)
            if k in taps:
                out.append(x / (x.norm(dim=1, keepdim=True) + NORM_EPS))
        return out

    total = 0.0
    for i, (fa, fb) in enumerate(zip(features(a), features(b))):
        total += float(((fa - fb) ** 2 * weights[f"lin{i}.weight"].view(1, -1, 1, 1)).sum(1).mean())
    return total


def test_the_distance_is_lpips_on_alexnet(tmp_path):
    weights = random_weights()
    torch.save(weights, tmp_path / "lpips.pt")
    network = load_lpips(tmp_path / "lpips.pt")
    g = torch.Generator().manual_seed(1)
    a = torch.rand(1, 3, 64, 80, generator=g) * 2 - 1
    b = (a + 0.2 * torch.randn(1, 3, 64, 80, generator=g)).clamp(-1, 1)
    with torch.no_grad():
        assert float(network(a, b)) == pytest.approx(reference_distance(weights, a, b), rel=1e-4)
        assert float(network(a, a)) == 0.0
        assert float(network(a, b)) > 0
        # A black image has all-zero features at some pixels: the normalisation stays finite.
        black = -torch.ones(1, 3, 40, 30)
        assert torch.isfinite(network(black, black)).all() and float(network(black, black)) == 0.0


def test_a_torchscript_file_is_refused_and_never_loaded(tmp_path, monkeypatch):
    class Distance(torch.nn.Module):
        def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
            return (a - b).abs().mean()

    torch.jit.script(Distance()).save(str(tmp_path / "lpips.pt"))
    loads = []
    monkeypatch.setattr(torch.jit, "load", lambda *args, **kwargs: loads.append(args))
    with pytest.raises(InputError, match="TorchScript") as error:
        load_lpips(tmp_path / "lpips.pt")
    assert "lpips.pt" in str(error.value) and "\n" not in str(error.value)
    assert loads == []


class _Payload:
    def __reduce__(self):
        return (open, (sys.argv[0] + ".never", "w"))


@pytest.mark.parametrize("protocol", range(pickle.HIGHEST_PROTOCOL + 1))
def test_a_pickled_object_is_refused_in_one_line_at_every_protocol(tmp_path, protocol):
    path = tmp_path / f"p{protocol}.pt"
    path.write_bytes(pickle.dumps({"conv0.weight": _Payload()}, protocol=protocol))
    with pytest.raises(InputError) as error:
        read_weights(path)
    message = str(error.value)
    assert str(path) in message and "\n" not in message and "weights_only=False" not in message


@pytest.mark.parametrize("change, words", [
    (lambda w: w.pop("lin4.weight"), "lacks 'lin4.weight'"),
    (lambda w: w.update(extra=torch.zeros(1)), "unknown key 'extra'"),
    (lambda w: w.update({"conv0.bias": torch.zeros(3)}), "shape"),
    (lambda w: w["lin0.weight"].fill_(-1.0), "negative"),
    (lambda w: w["conv2.weight"].view(-1).__setitem__(0, float("nan")), "non-finite"),
])
def test_wrong_weights_are_one_line(tmp_path, change, words):
    weights = random_weights()
    change(weights)
    torch.save(weights, tmp_path / "w.pt")
    with pytest.raises(InputError, match=words):
        load_lpips(tmp_path / "w.pt")


def test_the_converter_takes_the_published_layouts(tmp_path):
    import importlib.util
    from pathlib import Path
    spec = importlib.util.spec_from_file_location(
        "lpips_weights", Path(__file__).resolve().parents[2] / "scripts" / "lpips_weights.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    weights = random_weights(3)
    alexnet = {}
    for i, n in enumerate(script.ALEXNET_CONVS):
        alexnet[f"features.{n}.weight"] = weights[f"conv{i}.weight"]
        alexnet[f"features.{n}.bias"] = weights[f"conv{i}.bias"]
    alexnet["classifier.1.weight"] = torch.zeros(2, 2)
    linear = {f"lin{i}.model.1.weight": weights[f"lin{i}.weight"] for i in range(5)}
    torch.save(alexnet, tmp_path / "alexnet.pth")
    torch.save(linear, tmp_path / "lin.pth")
    assert script.main([str(tmp_path / "alexnet.pth"), str(tmp_path / "lin.pth"), "--out", str(tmp_path / "o.pt")]) == 0
    loaded = read_weights(tmp_path / "o.pt")
    assert set(loaded) == set(weights) and all(torch.equal(loaded[k], weights[k]) for k in weights)
