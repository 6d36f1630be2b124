"""Torch rasterizer benchmark: forward and forward+backward time and peak memory.

N random Gaussians in a unit cube in front of the camera, 512x512, 2 torch threads, for the
"torch" rasterizer of the registry (inceptiongs.rasterizer.interface: the reference with
projection, SH colour and composite in torch) and (when numba imports) the "numba" one (the
numba kernels wherever they cover the case: here all three stages). Each (N, backend) runs in a fresh interpreter so its peak RSS (ru_maxrss) is its own; "peak MB" is that peak
minus the interpreter's RSS right before the first render (model and imports excluded).

    python benchmarks/bench_torch_rasterizer.py [--sizes 10000 100000 1000000] [--repeats 3] [--device cuda]

``--device cuda`` runs the torch reference on the GPU (numba is CPU-only) and reports the peak
of torch's CUDA allocator instead of the RSS (docs/rendering.md, "On a GPU").

Timings are medians over --repeats after one warm-up call. The machine is shared: treat the
figures as indicative.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
from pathlib import Path

WORKER = textwrap.dedent("""
    import json, resource, sys
    sys.path.insert(0, sys.argv[6])   # benchmarks/: the shared timing rule
    from timing import median_ms
    import inceptiongs  # before torch: sets OMP_WAIT_POLICY=PASSIVE (docs/training.md, "Speed")
    import numpy as np, torch
    torch.set_num_threads(2)
    from inceptiongs.camera import Camera, look_at
    from inceptiongs.gaussians import Gaussians
    from inceptiongs.rasterizer.interface import get_rasterizer

    n, backend, repeats, size, device = int(sys.argv[1]), sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
    cuda = device.startswith("cuda")
    gen = torch.Generator().manual_seed(0)
    # Unit cube centred at the origin, camera 2.5 units away looking at it; per-Gaussian size
    # shrinks with density (~ mean spacing / 3) so the cube looks like a filled volume at every N.
    spacing = n ** (-1.0 / 3.0)
    params = dict(
        means=torch.rand(n, 3, generator=gen) - 0.5,
        log_scales=np.log(spacing / 3.0) + 0.4 * torch.randn(n, 3, generator=gen),
        quats=torch.randn(n, 4, generator=gen),
        opacity_logits=torch.randn(n, generator=gen),
        sh=0.3 * torch.randn(n, 4, 3, generator=gen),
    )
    params = {k: v.float().to(device).requires_grad_(True) for k, v in params.items()}
    g = Gaussians(**params)
    camera = Camera("bench", size, size, 1.1 * size, 1.1 * size, size / 2, size / 2,
                    look_at(np.array([0.3, -0.4, -2.5]), np.zeros(3)))
    outputs = ("rgb", "alpha", "depth")
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if cuda:
        torch.cuda.synchronize()
        allocated_before = torch.cuda.memory_allocated()
        torch.cuda.reset_peak_memory_stats()

    def sync():
        if cuda:  # kernels run asynchronously: a timing must wait for them
            torch.cuda.synchronize()

    rasterizer = get_rasterizer(backend)

    def forward():
        return rasterizer(g, camera, outputs=outputs)

    def forward_backward():
        out = forward()
        loss = out["rgb"].sum() + out["depth"].mean() + out["alpha"].sum()
        loss.backward()
        for p in params.values():
            p.grad = None
        return out

    with torch.no_grad():
        fwd_ms = median_ms(forward, repeats, sync)
    fwd_bwd_ms = median_ms(forward_backward, repeats, sync)
    out = forward()
    rss_after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    peak_mb = ((torch.cuda.max_memory_allocated() - allocated_before) / 2**20 if cuda
               else (rss_after - rss_before) / 1024.0)
    print(json.dumps({
        "n": n, "backend": backend, "forward_ms": fwd_ms, "forward_backward_ms": fwd_bwd_ms,
        "peak_mb": peak_mb, "visible": int((out["radii"] > 0).sum()),
        "mean_alpha": float(out["alpha"].detach().mean()),
    }))
""")


def numba_available() -> bool:
    try:
        import inceptiongs.rasterizer.composite_numba  # noqa: F401
    except ImportError:
        return False
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--backends", nargs="+", default=None, help="registry names (default: torch, and numba if importable)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--image", type=int, default=512, help="square image size in pixels")
    parser.add_argument("--device", default="cpu", help="torch device (cuda: the torch backend on the GPU)")
    args = parser.parse_args()
    on_cpu = args.device == "cpu"
    backends = args.backends or (["torch", "numba"] if on_cpu and numba_available() else ["torch"])

    header = f"{'N':>9} {'backend':>8} {'fwd ms':>10} {'fwd+bwd ms':>11} {'peak MB':>9} {'visible':>9} {'mean a':>7}"
    where = "2 threads" if on_cpu else f"{args.device}, peak MB of torch's CUDA allocator"
    print(f"torch rasterizer, {args.image}x{args.image}, {where}, median of {args.repeats}")
    print(header)
    print("-" * len(header))
    for n in args.sizes:
        for backend in backends:
            result = subprocess.run([sys.executable, "-c", WORKER, str(n), backend, str(args.repeats), str(args.image),
                                     args.device, str(Path(__file__).resolve().parent)],
                                    capture_output=True, text=True)
            if result.returncode != 0:
                reason = (result.stderr.strip().splitlines() or ["failed"])[-1]
                print(f"{n:>9} {backend:>8}  failed: {reason}")
                continue
            r = json.loads(result.stdout.strip().splitlines()[-1])
            print(f"{r['n']:>9} {r['backend']:>8} {r['forward_ms']:>10.1f} {r['forward_backward_ms']:>11.1f} "
                  f"{r['peak_mb']:>9.0f} {r['visible']:>9} {r['mean_alpha']:>7.3f}", flush=True)


if __name__ == "__main__":
    main()
