"""Fuzz test of every input format the CLI reads: seeded mutations of valid PLY,
COLMAP binary and text, transforms.json, poses_bounds.npy and camera JSON files (truncated,
bytes flipped, NaN/inf, wrong shapes and types). For every case, run in-process through
``inceptiongs.cli.main`` with stdout/stderr captured: exit 0, or exit 2 with exactly one
line naming the file; never a traceback (an exception escaping main), never a hang (an alarm
fails the case after a few seconds).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from inceptiongs.camera import rigid_inverse
from inceptiongs.cli import main
from inceptiongs.gaussians import Gaussians
from inceptiongs.io.ply import write_ply
from inceptiongs.scene.colmap import write_colmap_binary
from scene_cases import HEIGHT, WIDTH, known_cameras, known_points, project, write_images
from shared_run_cases import train_one_step, write_text_scene

# 6 formats x 90 = 540 seeded cases (INCEPTIONGS_FUZZ_CASES raises it for a longer search).
CASES_PER_FORMAT = int(os.environ.get("INCEPTIONGS_FUZZ_CASES", "90"))
CASE_TIMEOUT_S = 20       # a hang fails the case (a normal case takes milliseconds)


class _Hang(Exception):
    pass


def _on_alarm(signum, frame):
    raise _Hang()


def run_cli(argv: list[str]) -> tuple[int, str]:
    """main(argv) in-process -> (exit status, captured stderr). An exception escaping main is
    re-raised (the test fails: a user would have seen a traceback)."""
    stderr, stdout = io.StringIO(), io.StringIO()
    previous = signal.signal(signal.SIGALRM, _on_alarm)
    signal.alarm(CASE_TIMEOUT_S)
    try:
        with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(stdout):
            status = main(argv)
    except _Hang:
        pytest.fail(f"hang: {argv}")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    return status, stderr.getvalue()


# --- valid inputs ---------------------------------------------------------------------------------
def _opengl_c2w(camera) -> list:
    c2w = rigid_inverse(camera.world_to_camera)
    c2w[:, 1] *= -1
    c2w[:, 2] *= -1
    return c2w.tolist()


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    """One valid input of each kind: {kind: (folder or file, the file to mutate)}."""
    root = tmp_path_factory.mktemp("fuzz_valid")
    cameras = known_cameras(count=3)
    write_images(root / "images", cameras, [None] * 3)
    points = known_points()
    colours = np.tile(np.array([[10, 200, 30]], np.uint8), (len(points), 1))

    binary = root / "colmap_bin"
    (binary / "sparse" / "0").mkdir(parents=True)
    write_colmap_binary(binary / "sparse" / "0", [(c, "PINHOLE", [c.fx, c.fy, c.cx, c.cy]) for c in cameras],
                        points, colours)
    text = root / "colmap_txt"
    (text / "sparse" / "0").mkdir(parents=True)
    (text / "sparse" / "0" / "cameras.txt").write_text("".join(
        f"{i + 1} PINHOLE {c.width} {c.height} {c.fx} {c.fy} {c.cx} {c.cy}\n" for i, c in enumerate(cameras)))
    from inceptiongs.camera import rotation_to_quat
    lines = []
    for i, c in enumerate(cameras):
        q, t = rotation_to_quat(c.world_to_camera[:3, :3]), c.world_to_camera[:3, 3]
        lines.append(f"{i + 1} {' '.join(map(repr, q))} {' '.join(map(repr, t))} {i + 1} {c.name}\n")
        pixels = project(c, points[:2])
        lines.append(f"{pixels[0, 0]} {pixels[0, 1]} 1 {pixels[1, 0]} {pixels[1, 1]} 2\n")
    (text / "sparse" / "0" / "images.txt").write_text("".join(lines))
    (text / "sparse" / "0" / "points3D.txt").write_text("".join(
        f"{k + 1} {p[0]} {p[1]} {p[2]} 10 200 30 0.5 1 {k}\n" for k, p in enumerate(points[:2])))

    transforms = root / "transforms"
    transforms.mkdir()
    c = cameras[0]
    (transforms / "transforms.json").write_text(json.dumps({
        "fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy, "w": WIDTH, "h": HEIGHT, "k1": -0.05,
        "frames": [{"file_path": f"images/{cam.name}", "transform_matrix": _opengl_c2w(cam)} for cam in cameras]}))

    llff = root / "llff"
    llff.mkdir()
    rows = []
    for cam in cameras:
        c2w = rigid_inverse(cam.world_to_camera)
        # OpenCV [right, down, forward] -> LLFF [down, right, back].
        matrix = np.stack([c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3], [HEIGHT, WIDTH, cam.fx]], 1)
        rows.append(np.concatenate([matrix.ravel(), [1.0, 10.0]]))
    np.save(llff / "poses_bounds.npy", np.array(rows))

    for scene in (binary, text, transforms, llff):
        os.symlink(root / "images", scene / "images")

    n = 6
    gen = torch.Generator().manual_seed(0)
    model = root / "model.ply"
    write_ply(Gaussians(torch.tensor(points[:n], dtype=torch.float32), torch.full((n, 3), -1.0),
                        torch.randn(n, 4, generator=gen), torch.ones(n), torch.randn(n, 4, 3, generator=gen) * 0.3),
              model)
    camera_json = root / "cam.json"
    camera_json.write_text(json.dumps({**c.to_json_dict(), "width": 40, "height": 30, "fx": 20.0, "fy": 20.0,
                                       "cx": 20.0, "cy": 15.0}))
    return {
        "colmap-binary": (binary, binary / "sparse" / "0"),
        "colmap-text": (text, text / "sparse" / "0"),
        "transforms": (transforms, transforms / "transforms.json"),
        "llff": (llff, llff / "poses_bounds.npy"),
        "ply": (model, model),
        "camera": (camera_json, camera_json),
    }


# --- mutations -------------------------------------------------------------------------------------
_SPECIAL_NUMBERS = [float("nan"), float("inf"), -float("inf"), 0.0, -1.0, 1e308, -1e-320, 2**63]


def mutate_bytes(data: bytes, rng: np.random.Generator) -> bytes:
    """Truncate, flip bytes, insert garbage, or write NaN/inf doubles/floats over the data."""
    data = bytearray(data)
    kind = rng.integers(5)
    if kind == 0 or not data:
        return bytes(data[: int(rng.integers(0, len(data) + 1))])
    if kind == 1:
        for _ in range(int(rng.integers(1, 6))):
            data[int(rng.integers(len(data)))] ^= 1 << int(rng.integers(8))
        return bytes(data)
    if kind == 2:
        at = int(rng.integers(len(data) + 1))
        return bytes(data[:at]) + rng.bytes(int(rng.integers(1, 40))) + bytes(data[at:])
    if kind == 3:  # a special double at a random 8-byte-aligned offset
        value = _SPECIAL_NUMBERS[int(rng.integers(len(_SPECIAL_NUMBERS)))]
        at = int(rng.integers(max(len(data) // 8, 1))) * 8
        packed = struct.pack("<d", float(value))
        return bytes(data[:at]) + packed + bytes(data[at + 8:])
    value = _SPECIAL_NUMBERS[int(rng.integers(3))]  # NaN/inf as a float32
    at = int(rng.integers(max(len(data) // 4, 1))) * 4
    return bytes(data[:at]) + struct.pack("<f", value) + bytes(data[at + 4:])


def mutate_text(text: str, rng: np.random.Generator) -> str:
    """Text formats: swap a number for nan/inf/a word, drop or duplicate a token or a line."""
    lines = text.splitlines(keepends=True)
    kind = rng.integers(4)
    if kind == 0 and lines:
        index = int(rng.integers(len(lines)))
        tokens = lines[index].split(" ")
        tokens[int(rng.integers(len(tokens)))] = str(rng.choice(["nan", "inf", "-inf", "x", "", "1e400", "-3"]))
        lines[index] = " ".join(tokens)
        if not lines[index].endswith("\n"):
            lines[index] += "\n"
    elif kind == 1 and lines:
        index = int(rng.integers(len(lines)))
        tokens = lines[index].split(" ")
        del tokens[int(rng.integers(len(tokens)))]
        lines[index] = " ".join(tokens)
    elif kind == 2 and lines:
        index = int(rng.integers(len(lines)))
        lines.insert(index, lines[index])
    else:
        return mutate_bytes(text.encode(), rng).decode("utf-8", errors="replace")
    return "".join(lines)


def _json_paths(value, prefix=()):
    """Every (path, leaf or container) in a JSON value."""
    yield prefix, value
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _json_paths(item, prefix + (key,))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _json_paths(item, prefix + (index,))


_JSON_REPLACEMENTS = [float("nan"), float("inf"), -float("inf"), None, "text", [], {}, [1, 2], [[1, 2, 3]] * 5,
                      -5, 0, 10**30, 1e300, True, "OPENCV_FISHEYE", "EQUIRECTANGULAR"]


def mutate_json(text: str, rng: np.random.Generator) -> str:
    """Replace a random value with NaN/inf/null/a wrong type or shape, delete a key, or mangle bytes."""
    if rng.random() < 0.2:
        return mutate_bytes(text.encode(), rng).decode("utf-8", errors="replace")
    data = json.loads(text)
    paths = [p for p, _ in _json_paths(data) if p]
    path = paths[int(rng.integers(len(paths)))]
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    if rng.random() < 0.2 and isinstance(parent, dict):
        del parent[path[-1]]
    else:
        parent[path[-1]] = _JSON_REPLACEMENTS[int(rng.integers(len(_JSON_REPLACEMENTS)))]
    return json.dumps(data)  # writes NaN / Infinity as Python's json does


def mutate_npy(path: Path, rng: np.random.Generator) -> None:
    table = np.load(path)
    kind = rng.integers(4)
    if kind == 0:
        table.flat[int(rng.integers(table.size))] = _SPECIAL_NUMBERS[int(rng.integers(len(_SPECIAL_NUMBERS)))]
    elif kind == 1:
        shapes = [(table.size,), (table.shape[0], 16), (1, table.size), (0, 17), (table.shape[0] + 1, 17)]
        shape = shapes[int(rng.integers(len(shapes)))]
        table = np.resize(table, shape)
    elif kind == 2:
        table = table.astype(rng.choice([np.float32, np.int8, np.complex64]))
    else:
        path.write_bytes(mutate_bytes(path.read_bytes(), rng))
        return
    np.save(path, table)


# --- the cases -------------------------------------------------------------------------------------
def _mutated_copy(kind: str, valid: dict, workdir: Path, rng: np.random.Generator) -> tuple[Path, Path]:
    """(what to give the CLI, the mutated file) in a fresh copy under ``workdir``."""
    source, target = valid[kind]
    if source.is_dir():
        copy = workdir / source.name
        shutil.copytree(source, copy, symlinks=True)
        target = copy / target.relative_to(source)
        source = copy
    else:
        source = target = Path(shutil.copy(source, workdir / source.name))
    if kind.startswith("colmap"):
        names = sorted(p.name for p in target.iterdir())
        target = target / names[int(rng.integers(len(names)))]
    if kind == "llff":
        mutate_npy(target, rng)
    elif target.suffix == ".json":
        target.write_text(mutate_json(target.read_text(), rng))
    elif target.suffix == ".txt":
        target.write_text(mutate_text(target.read_text(), rng))
    else:
        target.write_bytes(mutate_bytes(target.read_bytes(), rng))
    return source, target


@pytest.mark.parametrize("kind", ["colmap-binary", "colmap-text", "transforms", "llff", "ply", "camera"])
def test_mutated_inputs_exit_0_or_one_line_naming_the_file(valid, tmp_path, kind):
    rng = np.random.default_rng(list(map(ord, kind)))
    outcomes = {0: 0, 2: 0}
    for case in range(CASES_PER_FORMAT):
        workdir = tmp_path / f"case{case}"
        workdir.mkdir()
        given, mutated = _mutated_copy(kind, valid, workdir, rng)
        if kind == "camera":
            argv = ["render", str(valid["ply"][0]), "--camera", str(given), "--backend", "torch",
                    "--out", str(workdir / "out.png")]
        elif kind == "ply":
            argv = ["render", str(given), "--camera", str(valid["camera"][0]), "--backend", "torch",
                    "--out", str(workdir / "out.png")]
        else:
            argv = ["info", str(given), "--json"]
        status, stderr = run_cli(argv)
        assert status in (0, 2), (case, status, stderr)
        outcomes[status] += 1
        if status == 2:
            lines = stderr.strip().splitlines()
            assert len(lines) == 1, (case, mutated, stderr)
            # The file itself, or (for a COLMAP model read as a whole) its model folder.
            assert str(mutated) in lines[0] or str(mutated.parent) in lines[0], (case, mutated, lines[0])
        shutil.rmtree(workdir)
    # Seeded mutations must exercise both outcomes (the test can tell a refusal from a pass).
    assert outcomes[2] > 0, outcomes


# --- shared runs: every file a scene or run folder holds, through every command ------------------
# Seeded cases over the run's and scene's files (config.json, split.json, metrics.jsonl, checkpoints,
# flags.json, view_fit.json, the bootstrap config, images, model.ply, the scene's image names) and
# folders, with path mutations (``..``, absolute paths, symlinks out, loops, dangling links, sparse
# files of a huge declared size). Each case asserts: exit 0 or one line with exit 2 (never a
# traceback), no write outside the case's folder, no read of the sentinel folder outside it, and
# a planted checkpoint payload never runs. INCEPTIONGS_FUZZ_RUN_CASES sets the number of cases.
RUN_CASES = int(os.environ.get("INCEPTIONGS_FUZZ_RUN_CASES", "1463"))   # with the 540 above: 2003
RUN_FILE_KINDS = ["config", "split", "metrics", "checkpoint", "flags", "view_fit", "bootstrap_config", "image",
                  "ply", "scene_names", "folder_links"]
SENTINEL_TEXT = "SENTINEL-3f9c2a-never-read"


class _WouldTrain(Exception):
    """Raised by the stubs that stand where a command's long work would begin: the case got past
    every validation of its inputs."""


class _Watch:
    """An audit hook that records file opens while armed: reads below ``forbidden`` and writes
    outside ``allowed`` folders."""

    def __init__(self):
        self.armed = False
        self.forbidden: str = ""
        self.allowed: tuple[str, ...] = ()
        self.bad: list[str] = []
        sys.addaudithook(self._hook)

    def _hook(self, event, args):
        if not self.armed or event != "open" or not args or not isinstance(args[0], (str, bytes, os.PathLike)):
            return
        path = os.fsdecode(args[0])
        real = os.path.realpath(path) if not path.startswith("/proc") else path
        mode, flags = (args[1] or ""), (args[2] or 0) if len(args) > 2 else 0
        writing = any(c in str(mode) for c in "wax+") or bool(flags & (os.O_WRONLY | os.O_RDWR))
        if real.startswith(self.forbidden) or path.startswith(self.forbidden):
            self.bad.append(f"opened {path} (sentinel folder)")
        elif writing and not any(real.startswith(root) for root in self.allowed):
            self.bad.append(f"wrote {path} outside the case folder")


_WATCH = None


def _watch() -> _Watch:
    global _WATCH
    if _WATCH is None:
        _WATCH = _Watch()
    return _WATCH


def _evil_object(marker: Path):
    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))
    return Payload()


@pytest.fixture(scope="module")
def shared_run(tmp_path_factory):
    """A pristine COLMAP-text scene (its own image copies) and a 1-step run on it with every file a
    run holds, plus a sentinel folder outside both: {"scene", "run", "sentinel", "marker", "big_png"}."""
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.io.flags import Flag, save_flags

    root = tmp_path_factory.mktemp("fuzz_run")
    scene = root / "pristine" / "scene"
    names = write_text_scene(scene)
    run = root / "pristine" / "run"
    train_one_step(scene, run)
    cameras = known_cameras(count=4)
    save_flags(run / "flags.json", [Flag("f0", cameras[1], "2026-01-01T00:00:00+00:00")])
    BootstrapConfig().save(run / "bootstrap" / "config.json")
    sentinel = root / "sentinel"
    sentinel.mkdir()
    (sentinel / "secret.txt").write_text(SENTINEL_TEXT + "\n")
    shutil.copy(scene / "images" / cameras[0].name, sentinel / "secret.png")
    # A PNG whose header declares 14000 x 14000 pixels (its data is a stub).
    import zlib
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)
    big_png = root / "big.png"
    big_png.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 14000, 14000, 8, 2, 0, 0, 0))
                        + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
    return {"scene": scene, "run": run, "sentinel": sentinel, "marker": root / "PAYLOAD_RAN",
            "big_png": big_png, "names": names}


def _snapshot(folder: Path) -> dict[str, tuple[int, float]]:
    out = {}
    for parent, dirs, names in os.walk(folder):
        for name in dirs + names:
            path = os.path.join(parent, name)
            info = os.lstat(path)
            out[path] = (info.st_size, info.st_mtime)
    return out


def _link_or_copy(source: str, target: str) -> None:
    if source.endswith((".pt", ".ply")):
        os.link(source, target)
    else:
        shutil.copy2(source, target)


def _unshare(path: Path) -> None:
    """Give a hard-linked file its own copy before it is written in place."""
    if path.is_file() and not path.is_symlink() and path.stat().st_nlink > 1:
        data = path.read_bytes()
        path.unlink()
        path.write_bytes(data)


def _case_copy(shared: dict, workdir: Path) -> tuple[Path, Path]:
    """A fresh copy of the pristine scene and run under ``workdir``; the run's config points at
    the copy of the scene."""
    scene, run = workdir / "scene", workdir / "run"
    shutil.copytree(shared["scene"], scene, symlinks=True)
    # The large binaries are only ever replaced (atomic writes), never written in place: they are
    # hard links to the pristine copies until a mutation unshares them (_unshare).
    shutil.copytree(shared["run"], run, symlinks=True, copy_function=_link_or_copy)
    config = run / "config.json"
    config.write_text(config.read_text().replace(str(shared["scene"]), str(scene)))
    return scene, run


def _path_attack(shared: dict, base: Path, rng) -> str:
    """A string naming a file outside the case folder: absolute, or climbing from ``base`` with '..'."""
    climb = os.path.relpath(shared["sentinel"] / "secret.png", base)
    choices = [str(shared["sentinel"] / "secret.png"), str(shared["sentinel"] / "secret.txt"), climb,
               "../" * 12 + "etc/passwd", "/etc/passwd", str(shared["sentinel"]), "images/../" + climb]
    return choices[int(rng.integers(len(choices)))]


def _link_attack(path: Path, shared: dict, rng) -> None:
    """Replace ``path`` (file or folder) by a symlink out, to itself, or to nothing; or by a
    sparse file of a huge declared size."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()
    kind = int(rng.integers(5))
    if kind == 0:
        os.symlink(shared["sentinel"] / ("secret.png" if path.suffix == ".png" else "secret.txt"), path)
    elif kind == 1:
        os.symlink(path, path)               # a loop
    elif kind == 2:
        os.symlink(path.parent / "missing", path)
    elif kind == 3:
        os.symlink(shared["sentinel"], path)
    else:
        with open(path, "wb") as handle:     # sparse: a huge size, no data
            handle.truncate(int(rng.choice([2**31, 2**36, 51 * 10**9])))


_TYPED_VALUES = ["abc", "4", 1000, -1, 0, 2**40, 1e308, float("nan"), float("inf"), None, True, [], {}, 5, 0.5]


def _mutate_json_file(path: Path, shared: dict, rng) -> None:
    """JSON mutations (mangled bytes, wrong types, NaN), a path string aimed outside, or a link attack."""
    choice = rng.random()
    if choice < 0.15:
        _link_attack(path, shared, rng)
        return
    text = path.read_text()
    if choice < 0.5:
        path.write_text(mutate_json(text, rng))
        return
    data = json.loads(text)
    leaves = [p for p, v in _json_paths(data) if p and not isinstance(v, (dict, list))] or \
        [p for p, _ in _json_paths(data) if p]
    if not leaves:
        path.write_text(mutate_json(text, rng))
        return
    where = leaves[int(rng.integers(len(leaves)))]
    parent = data
    for key in where[:-1]:
        parent = parent[key]
    current = parent[where[-1]]
    parent[where[-1]] = (_path_attack(shared, path.parent, rng) if isinstance(current, str) and rng.random() < 0.7
                         else _TYPED_VALUES[int(rng.integers(len(_TYPED_VALUES)))])
    path.write_text(json.dumps(data))


def _mutate_checkpoint(run: Path, shared: dict, rng) -> None:
    from inceptiongs.runs.checkpoint import latest_checkpoint

    path = latest_checkpoint(run)
    _unshare(path)
    if rng.random() < 0.5:   # without a model, eval, render and coverage read the checkpoint too
        (run / "model.ply").unlink()
    kind = int(rng.integers(7))
    if kind == 0:  # a payload that would create the marker file, as torch.save (zip) or a bare pickle
        body = {"iteration": 1, "params": _evil_object(shared["marker"])}
        if rng.random() < 0.5:
            torch.save(body, path)
        else:
            import pickle
            path.write_bytes(pickle.dumps(body))
    elif kind == 1:
        torch.save({"iteration": 30, "params": {}}, path)
    elif kind in (2, 3):  # the real payload with one entry removed or replaced
        payload = torch.load(path, weights_only=True)
        key = sorted(payload)[int(rng.integers(len(payload)))]
        if kind == 2:
            del payload[key]
        else:
            payload[key] = [torch.zeros(int(rng.integers(0, 4)), 3), "x", None, -1, {}, [1, 2],
                            float("nan")][int(rng.integers(7))]
        torch.save(payload, path)
    elif kind == 4:
        path.write_bytes(mutate_bytes(path.read_bytes(), rng))
    elif kind == 5:
        payload = torch.load(path, weights_only=True)
        name = sorted(payload["params"])[int(rng.integers(len(payload["params"])))]
        payload["params"][name] = payload["params"][name][: int(rng.integers(0, 3))]
        torch.save(payload, path)
    else:
        _link_attack(path, shared, rng)


def _mutate_metrics(path: Path, shared: dict, rng) -> None:
    if rng.random() < 0.15:
        _link_attack(path, shared, rng)
        return
    lines = path.read_text().splitlines()
    kind = int(rng.integers(3))
    if kind == 0:
        lines.append(json.dumps({"iteration": _TYPED_VALUES[int(rng.integers(len(_TYPED_VALUES)))],
                                 "wall_s": _TYPED_VALUES[int(rng.integers(len(_TYPED_VALUES)))], "all_psnr": 20.0}))
    elif kind == 1 and lines:
        index = int(rng.integers(len(lines)))
        lines[index] = mutate_json(lines[index], rng)
    else:
        lines = mutate_text("\n".join(lines) + "\n", rng).splitlines()
    path.write_text("\n".join(lines) + "\n")


def _mutate_image(scene: Path, shared: dict, rng) -> None:
    images = sorted((scene / "images").iterdir())
    path = images[int(rng.integers(len(images)))]
    kind = int(rng.integers(4))
    if kind == 0:
        path.write_bytes(mutate_bytes(path.read_bytes(), rng))
    elif kind == 1:
        shutil.copy(shared["big_png"], path)
    else:
        _link_attack(path, shared, rng)


def _mutate_ply(path: Path, shared: dict, rng) -> None:
    _unshare(path)
    kind = int(rng.integers(3))
    if kind == 0:
        path.write_bytes(mutate_bytes(path.read_bytes(), rng))
    elif kind == 1:  # a header declaring 400M vertices, sparse to exactly the declared size
        head = path.read_bytes()
        end = head.index(b"end_header\n") + len(b"end_header\n")
        header = head[:end].decode("ascii")
        count = int(header.split("element vertex ")[1].split()[0])
        per_vertex = (len(head) - end) // max(count, 1)
        header = header.replace(f"element vertex {count}\n", "element vertex 400000000\n")
        with open(path, "wb") as handle:
            handle.write(header.encode("ascii"))
            handle.truncate(len(header) + 400_000_000 * per_vertex)
    else:
        _link_attack(path, shared, rng)


def _mutate_scene_names(scene: Path, shared: dict, rng) -> None:
    """An image name in images.txt aimed outside: absolute, '..', or an in-folder symlink out."""
    path = scene / "sparse" / "0" / "images.txt"
    lines = path.read_text().splitlines()
    rows = [i for i, line in enumerate(lines) if line.strip()]
    index = rows[int(rng.integers(len(rows)))]
    tokens = lines[index].split(" ")
    if rng.random() < 0.3:
        os.symlink(shared["sentinel"] / "secret.png", scene / "images" / "link_out.png")
        tokens[-1] = "link_out.png"
    else:
        tokens[-1] = _path_attack(shared, scene / "images", rng)
    lines[index] = " ".join(tokens)
    path.write_text("\n".join(lines) + "\n")


def _mutate_folder_links(run: Path, shared: dict, rng) -> None:
    """A run folder whose sub-folders or logs are symlinks planted to lead out."""
    name = ["eval", "checkpoints", "prior", "bootstrap", "metrics.jsonl", "model.ply", "view_fit.json"][
        int(rng.integers(7))]
    _link_attack(run / name, shared, rng)


def _mutate_run_file(kind: str, scene: Path, run: Path, shared: dict, rng) -> None:
    files = {"config": run / "config.json", "split": run / "split.json", "flags": run / "flags.json",
             "view_fit": run / "view_fit.json", "bootstrap_config": run / "bootstrap" / "config.json"}
    if kind in files:
        _mutate_json_file(files[kind], shared, rng)
    elif kind == "metrics":
        _mutate_metrics(run / "metrics.jsonl", shared, rng)
    elif kind == "checkpoint":
        _mutate_checkpoint(run, shared, rng)
    elif kind == "image":
        _mutate_image(scene, shared, rng)
    elif kind == "ply":
        _mutate_ply(run / "model.ply", shared, rng)
    elif kind == "scene_names":
        _mutate_scene_names(scene, shared, rng)
    else:
        _mutate_folder_links(run, shared, rng)


def _commands(kind: str, scene: Path, run: Path, workdir: Path, names: list[str], rng) -> list[str]:
    """One command line that reads the mutated file (chosen at random among those that do)."""
    view = names[int(rng.integers(len(names)))]
    options = {
        "info": ["info", str(scene), "--json"],
        "report": ["report", str(run)],
        "eval": ["eval", str(run), "--json"],
        "render": ["render", str(run), "--view", view, "--backend", "torch", "--out", str(workdir / "view.png")],
        "coverage": ["coverage", str(run), "--out", str(workdir / "coverage.png")],
        "train": ["train", str(scene), "--out", str(run), "--resume", "--iterations", "1"],
        "train_new": ["train", str(scene), "--out", str(workdir / "new_run"), "--iterations", "1"],
        "bootstrap": ["bootstrap", str(run), "--out", str(workdir / "boot"), "--targets", str(run / "flags.json")],
        "prior": ["prior", str(run), "--steps", "1"],
        "generate": ["generate", str(run), "--view", view, "--out", str(workdir / "gen.png")],
        # No command reads a bootstrap result's config back; the viewer and library do, here directly.
        "bootstrap_config": [_LOAD_BOOTSTRAP_CONFIG, str(run / "bootstrap" / "config.json")],
    }
    readers = {
        "config": ["report", "eval", "render", "coverage", "train", "bootstrap", "prior", "generate"],
        "split": ["eval", "bootstrap", "train", "coverage"],
        "metrics": ["report", "train"],
        "checkpoint": ["train", "bootstrap", "eval", "render", "coverage", "prior"],
        "flags": ["bootstrap"],
        "view_fit": ["train_new", "eval", "render"],
        "bootstrap_config": ["bootstrap_config"],
        "image": ["info", "train_new", "eval", "render", "coverage"],
        "ply": ["render", "eval", "coverage", "bootstrap", "prior", "generate"],
        "scene_names": ["info", "train_new", "eval", "render", "coverage"],
        "folder_links": ["eval", "train", "bootstrap", "prior", "render", "report", "coverage"],
    }[kind]
    chosen = readers[int(rng.integers(len(readers)))]
    argv = options[chosen]
    if chosen == "train_new" and kind == "view_fit":
        argv = argv + ["--exclude-photos", str(run)]
    return argv


def _stub_long_work(monkeypatch) -> None:
    """Where a command's long work would begin, stop the case: its inputs all passed validation."""
    import inceptiongs.bootstrap.runner as runner
    import inceptiongs.prior.joint as joint
    import inceptiongs.train.trainer as trainer

    def stop(*args, **kwargs):
        raise _WouldTrain()

    import inceptiongs.evaluation.coverage_map as coverage_map

    # The coverage figure is drawn from computed numbers only (seconds of matplotlib per case).
    monkeypatch.setattr(coverage_map, "plot", lambda result, out, title=None: Path(out).write_bytes(b"png"))
    monkeypatch.setattr(runner, "run_bootstrap", stop)
    monkeypatch.setattr(joint, "training_views", stop)
    monkeypatch.setattr(trainer, "truncate_metrics", stop)   # a resume, after its state restored
    monkeypatch.setattr(trainer, "new_state", stop)          # a new run, after its data prepared


_LOAD_BOOTSTRAP_CONFIG = "load-bootstrap-config"


def _main_or_load(argv: list[str]) -> int:
    """cli.main, or (for the bootstrap config) its loader with the CLI's handling of InputError."""
    if argv[0] != _LOAD_BOOTSTRAP_CONFIG:
        return main(argv)
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.errors import InputError
    from inceptiongs.io.atomic import writing_under

    try:
        with writing_under(Path(argv[1]).parent.parent):   # the run, as the viewer names it
            BootstrapConfig.load(argv[1])
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


def _run_case(argv: list[str], watch: _Watch) -> tuple[int, str, str]:
    stderr, stdout = io.StringIO(), io.StringIO()
    previous = signal.signal(signal.SIGALRM, _on_alarm)
    signal.alarm(CASE_TIMEOUT_S)
    watch.armed = True
    try:
        with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(stdout):
            status = _main_or_load(argv)
    except _WouldTrain:
        status = 0
    except _Hang:
        pytest.fail(f"hang: {argv}")
    finally:
        watch.armed = False
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    return status, stdout.getvalue(), stderr.getvalue()


def _outputs_hold_sentinel(workdir: Path) -> list[str]:
    found = []
    for parent, _, names in os.walk(workdir):
        for name in names:
            path = Path(parent) / name
            if path.is_symlink() or not path.is_file() or path.stat().st_size > 1_000_000 \
                    or path.stat().st_nlink > 1:
                continue
            if SENTINEL_TEXT.encode() in path.read_bytes():
                found.append(str(path))
    return found


@pytest.mark.parametrize("kind", RUN_FILE_KINDS)
def test_mutated_run_and_scene_files_never_run_code_read_or_write_outside(shared_run, tmp_path, monkeypatch, kind):
    _stub_long_work(monkeypatch)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    watch = _watch()
    watch.forbidden = str(shared_run["sentinel"])
    cache = os.environ.get("INCEPTIONGS_CACHE_DIR", "")
    watch.allowed = tuple(os.path.realpath(p) for p in (tmp_path, cache) if p) + (
        os.path.realpath(os.path.expanduser("~/.cache")), os.path.realpath(os.path.expanduser("~/.config")),
        "/dev/")
    outside = {**_snapshot(shared_run["sentinel"]), **_snapshot(shared_run["scene"].parent)}
    rng = np.random.default_rng([RUN_FILE_KINDS.index(kind), 44])
    count = max(1, RUN_CASES // len(RUN_FILE_KINDS))
    outcomes = {0: 0, 2: 0}
    for case in range(count):
        workdir = tmp_path / f"case{case}"
        workdir.mkdir()
        scene, run = _case_copy(shared_run, workdir)
        _mutate_run_file(kind, scene, run, shared_run, rng)
        argv = _commands(kind, scene, run, workdir, shared_run["names"], rng)
        watch.bad = []
        status, stdout, stderr = _run_case(argv, watch)
        where = (kind, case, argv[0])
        assert status in (0, 2), (where, status, stderr[-2000:])
        if status == 2:
            lines = [line for line in stderr.strip().splitlines() if line.startswith("error:")]
            assert len(lines) == 1 and "Traceback" not in stderr, (where, stderr[-2000:])
        outcomes[status] += 1
        assert not watch.bad, (where, watch.bad[:3])
        assert not shared_run["marker"].exists(), (where, "a checkpoint payload ran")
        assert SENTINEL_TEXT not in stdout + stderr, where
        assert not _outputs_hold_sentinel(workdir), where
        shutil.rmtree(workdir)
    assert {**_snapshot(shared_run["sentinel"]), **_snapshot(shared_run["scene"].parent)} == outside
    assert outcomes[2] > 0, outcomes


def test_the_watch_sees_a_sentinel_read_and_a_write_outside(tmp_path):
    """The suite's audit hook can fail a case: a read below the sentinel folder and a write
    outside the allowed folders are both recorded (and nothing while disarmed)."""
    watch = _watch()
    sentinel, allowed, outside = tmp_path / "sentinel", tmp_path / "case", tmp_path / "elsewhere.txt"
    sentinel.mkdir()
    allowed.mkdir()
    (sentinel / "secret.txt").write_text(SENTINEL_TEXT)
    watch.forbidden, watch.allowed, watch.bad = str(sentinel), (str(allowed),), []
    watch.armed = True
    try:
        (allowed / "ok.txt").write_text("fine")
        (sentinel / "secret.txt").read_text()
        outside.write_text("not fine")
    finally:
        watch.armed = False
    outside.write_text("disarmed")
    assert len(watch.bad) == 2 and "sentinel" in watch.bad[0] and "outside" in watch.bad[1], watch.bad
