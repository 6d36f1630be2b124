"""The free-space rules' cost per maintenance step: the three Gaussian-against-camera tests
(contains_camera, before_near_bound, near_a_camera) on the numba path and on the torch path,
at a bonsai-sized rig and a street-sized one. Prints figures; asserts nothing.

    python benchmarks/bench_free_space.py [--gaussians 200000] [--cameras 197,2625] [--repeats 3]

The rig: cameras scattered along a street (x over 156 units, as the town's streets), each
looking a random way, 640x480, near bound 0.05 x the street's length; Gaussians scattered around
the cameras. Stage I runs these tests every ``densify_every`` steps (25 by default) until its
end, so a second here is a second per 25 steps.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import torch

import inceptiongs  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads libgomp)
from inceptiongs.camera import Camera, look_at
from inceptiongs.threads import use_torch_threads
from inceptiongs.train.free_space import before_near_bound, contains_camera, near_a_camera

STREET = 156.0


def street_rig(cameras: int, gaussians: int, seed: int = 0):
    """-> (cameras, centers [C, 3], near [C], means [N, 3], log_scales [N, 3], quats [N, 4])."""
    rng = np.random.default_rng(seed)
    rig = []
    for k in range(cameras):
        eye = np.array([rng.uniform(-STREET / 2, STREET / 2), rng.uniform(-3, 3), rng.uniform(1.5, 2.0)])
        target = eye + np.array([rng.normal(), rng.normal(), 0.1 * rng.normal()])
        rig.append(Camera(f"c{k}", 640, 480, 500.0, 500.0, 320.0, 240.0,
                          look_at(eye, target, up=np.array([0.0, 0.0, 1.0]))))
    centers = torch.tensor(np.stack([c.center for c in rig]))
    near = torch.full((cameras,), 0.05 * STREET / 10)
    anchor = centers[torch.from_numpy(rng.integers(0, cameras, gaussians))]
    means = (anchor + torch.tensor(rng.normal(0, 5.0, (gaussians, 3)))).float()
    log_scales = torch.tensor(rng.uniform(-5.0, 0.0, (gaussians, 3))).float()
    quats = torch.tensor(rng.normal(0, 1, (gaussians, 4))).float()
    return rig, centers, near, means, log_scales, quats


def timed(function, repeats: int) -> tuple[float, int]:
    """(median seconds of ``repeats`` calls after one warm-up, flags set)."""
    flags = function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.median(times)), int(flags.sum())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--gaussians", type=int, default=200_000)
    parser.add_argument("--cameras", default="197,2625", help="comma-separated camera counts")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    use_torch_threads()
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, torch threads "
          f"{torch.get_num_threads()}, load {os.getloadavg()[0]:.2f}")
    print("cameras  test               numba s   torch s   flags (numba / torch)")
    for count in (int(c) for c in args.cameras.split(",")):
        rig, centers, near, means, log_scales, quats = street_rig(count, args.gaussians)
        tests = {"contains_camera": lambda b: contains_camera(means, log_scales, quats, centers, 3.0, backend=b),
                 "before_near_bound": lambda b: before_near_bound(means, rig, near, backend=b),
                 "near_a_camera": lambda b: near_a_camera(means, centers, 0.5 * near, backend=b)}
        for name, test in tests.items():
            fast, fast_flags = timed(lambda: test("numba"), args.repeats)
            slow, slow_flags = timed(lambda: test("torch"), max(1, args.repeats // 3))
            print(f"{count:7d}  {name:17s}  {fast:8.3f}  {slow:8.3f}   {fast_flags} / {slow_flags}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
