"""Make an LPIPS weights file InceptionGS reads (a dict of plain tensors, see
inceptiongs/evaluation/lpips_net.py) from the two published state dicts:

    python scripts/lpips_weights.py ALEXNET.pth LPIPS_ALEX.pth --out lpips_alex.pt

ALEXNET.pth: torchvision's AlexNet ImageNet weights (keys features.0.weight, ...); LPIPS_ALEX.pth:
the LPIPS linear layers for AlexNet, version 0.1 (keys lin0.model.1.weight, ...). Both are read
with torch.load(weights_only=True), so neither can run code here either.
"""

from __future__ import annotations

import argparse
import sys

import torch

from inceptiongs.errors import InputError
from inceptiongs.evaluation.lpips_net import lpips_shapes, read_weights
from inceptiongs.io.atomic import atomic_open

ALEXNET_CONVS = (0, 3, 6, 8, 10)   # torchvision's features.N of the five conv layers


def convert(alexnet: dict, linear: dict) -> dict[str, torch.Tensor]:
    out = {}
    for i, n in enumerate(ALEXNET_CONVS):
        out[f"conv{i}.weight"] = alexnet[f"features.{n}.weight"]
        out[f"conv{i}.bias"] = alexnet[f"features.{n}.bias"]
        out[f"lin{i}.weight"] = linear[f"lin{i}.model.1.weight"]
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("alexnet")
    parser.add_argument("linear")
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    try:
        weights = convert(read_weights(args.alexnet, "AlexNet weights"), read_weights(args.linear, "LPIPS weights"))
    except KeyError as exc:
        print(f"error: missing key {exc} in the given state dicts", file=sys.stderr)
        return 2
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    shapes = lpips_shapes()
    bad = [k for k, v in weights.items() if tuple(v.shape) != shapes[k]]
    if bad:
        print(f"error: {bad[0]} has shape {tuple(weights[bad[0]].shape)}, expected {shapes[bad[0]]}", file=sys.stderr)
        return 2
    with atomic_open(args.out, "wb") as handle:
        torch.save({k: v.float().contiguous() for k, v in weights.items()}, handle)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
