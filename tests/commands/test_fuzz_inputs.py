"""Fuzz test of every input format the CLI reads (issue 18): seeded mutations of valid PLY,
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
