"""How many CPU threads torch may use for training, rendering and tests."""

from __future__ import annotations

import os


def torch_thread_count() -> int:
    """OMP_NUM_THREADS when the user set it to a positive integer, else min(2, cores).

    Two threads is what the CI machine has; more rarely helps the small kernels of a step, and
    two jobs side by side (two benchmarks, a test run beside a training) each need to be told to
    take one core, or their idle workers steal each other's (see OMP_WAIT_POLICY in __init__).
    """
    setting = os.environ.get("OMP_NUM_THREADS", "").strip()
    if setting.isdigit() and int(setting) > 0:
        return int(setting)
    return min(2, os.cpu_count() or 1)


def use_torch_threads() -> int:
    """Sets torch's intra-op thread count to torch_thread_count(); returns it."""
    import torch

    count = torch_thread_count()
    torch.set_num_threads(count)
    return count
