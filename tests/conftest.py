"""Shared fixtures. Real data lives beside the project in ../shared/data (or wherever
$INCEPTIONGS_DATA points); tests that need it skip with the reason when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import inceptiongs  # noqa: F401  (sets OMP_WAIT_POLICY before torch loads libgomp)
import torch  # noqa: E402

REPO_ROOT = Path(__file__).resolve().parents[1]

# Two cores on CI: keep torch from oversubscribing them.
torch.set_num_threads(min(2, os.cpu_count() or 1))


def shared_data_dir() -> Path | None:
    env = os.environ.get("INCEPTIONGS_DATA")
    candidates = [Path(env)] if env else []
    candidates.append(REPO_ROOT.parent / "shared" / "data")
    for candidate in candidates:
        if candidate.is_dir():
            return candidate
    return None


@pytest.fixture(scope="session")
def shared_data() -> Path:
    root = shared_data_dir()
    if root is None:
        pytest.skip("real data not found: set INCEPTIONGS_DATA or place it at ../shared/data")
    return root


def require_data(relative: str) -> Path:
    """Path of one real-data item, or skip the calling test with the reason."""
    root = shared_data_dir()
    if root is None:
        pytest.skip("real data not found: set INCEPTIONGS_DATA or place it at ../shared/data")
    path = root / relative
    if not path.exists():
        pytest.skip(f"real data item missing: {path}")
    return path


@pytest.fixture
def one_torch_thread():
    """Run a test with one torch thread: for tiny models the per-op threading overhead
    dominates, and on a busy 2-core machine two spinning OpenMP threads are many times slower."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
