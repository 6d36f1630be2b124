"""Shared fixtures. Real data lives beside the project in ../shared/data (or wherever
$INCEPTIONGS_DATA points); tests that need it skip with the reason when it is absent."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

import inceptiongs  # noqa: F401  (sets OMP_WAIT_POLICY before torch loads libgomp)
import torch  # noqa: E402
from inceptiongs.threads import use_torch_threads  # noqa: E402

REPO_ROOT = Path(__file__).resolve().parents[1]

# Two cores on CI: keep torch from oversubscribing them.
use_torch_threads()


@pytest.fixture(autouse=True, scope="session")
def _private_cache_dir(tmp_path_factory):
    """Caches of the whole pytest run go to one temporary folder, never to the user's
    ~/.cache (and never into scene folders, which the library no longer writes)."""
    previous = os.environ.get("INCEPTIONGS_CACHE_DIR")
    os.environ["INCEPTIONGS_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
    yield
    if previous is None:
        os.environ.pop("INCEPTIONGS_CACHE_DIR", None)
    else:
        os.environ["INCEPTIONGS_CACHE_DIR"] = previous


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


def offscreen_context_or_skip():
    """A headless (EGL) moderngl context, or skip the calling test saying why there is none."""
    pytest.importorskip("moderngl")
    from inceptiongs.renderer.context import RendererError, create_offscreen_context
    try:
        return create_offscreen_context()
    except RendererError as exc:
        pytest.skip(f"no usable EGL OpenGL context: {exc}")


@pytest.fixture(scope="module")
def gl_context():
    """One headless GL context per test module."""
    ctx = offscreen_context_or_skip()
    yield ctx
    ctx.release()


def _free_display() -> int:
    for number in range(90, 200):
        if not (Path(f"/tmp/.X{number}-lock").exists() or Path(f"/tmp/.X11-unix/X{number}").exists()):
            return number
    raise RuntimeError("no free X display number between 90 and 199")


@pytest.fixture(scope="session")
def xvfb():
    """One Xvfb server for the whole pytest run; DISPLAY points at it while tests run.

    One server, not one per module: GLFW keeps its X connection open until glfw.terminate(),
    and Xlib ends the process (exit 1, "XIO: fatal IO error") when a server it is connected
    to goes away. So GLFW is terminated before the server is stopped."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (scripts/install.sh --dev installs it)")
    number = _free_display()
    process = subprocess.Popen(["Xvfb", f":{number}", "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    socket = Path(f"/tmp/.X11-unix/X{number}")
    deadline = time.time() + 10
    while not socket.exists() and time.time() < deadline and process.poll() is None:
        time.sleep(0.05)
    if not socket.exists():
        process.kill()
        pytest.skip(f"Xvfb :{number} did not start")
    previous = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = f":{number}"
    yield f":{number}"
    if "glfw" in sys.modules:
        sys.modules["glfw"].terminate()
    if previous is None:
        os.environ.pop("DISPLAY", None)
    else:
        os.environ["DISPLAY"] = previous
    process.terminate()
    process.wait(10)


@pytest.fixture(autouse=True, scope="module")
def _viewer_runs_in_a_temporary_folder(request, tmp_path_factory):
    """The viewer's tests (tests/app) run from a folder of their own, one per module (a module's
    tests see each other's runs): their jobs, saved PLYs and screenshots go to ./runs in the
    current folder, as the command line's do, never into the project's checkout."""
    if Path(str(request.path)).parent.name != "app":
        yield
        return
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(tmp_path_factory.mktemp("cwd"))
        yield
