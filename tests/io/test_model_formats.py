"""Model formats (inceptiongs.io.models): each round trip within its stated error
(docs/scene_io.md), degrees a format cannot hold dropped with a note, and truncated or garbage
files refused with one line naming the file."""

from __future__ import annotations

import gzip
import struct

import numpy as np
import pytest
import torch

from inceptiongs.errors import InputError
from inceptiongs.io.model_error import model_error
from inceptiongs.io.models import open_model, read_model, write_format, write_model
from inceptiongs.io.ply import ply_field_names
from model_cases import SLACK, STATED, random_model


def round_trip(tmp_path, model: Gaussians, suffix: str):
    path = tmp_path / f"model.{suffix}"
    written = write_model(path, model)
    back = open_model(path)
    reference = model if written.order is None else model.subset(torch.as_tensor(written.order))
    return written, back, model_error(reference, back.gaussians)


@pytest.mark.parametrize("degree", [3, 0])
@pytest.mark.parametrize("suffix", list(STATED))
def test_round_trip_is_within_the_stated_error(tmp_path, suffix, degree):
    model = random_model(700, degree, seed=degree)  # 3 chunks of a compressed PLY, the last partial
    written, back, error = round_trip(tmp_path, model, suffix)
    assert len(back.gaussians) == len(model)
    for key, bound in STATED[suffix].items():
        assert error[key][0] <= bound + SLACK, (suffix, key, error[key], bound)
    expected_degree = 0 if suffix == "splat" else degree
    assert back.gaussians.sh_degree == expected_degree
    # A lossy format is lossy: the figures are not zero by accident of comparing a thing with itself.
    if suffix != "ply":
        assert error["opacity"][0] > 1e-4


def test_ply_round_trip_is_bit_exact_and_splat_drops_sh_rest_with_a_note(tmp_path):
    model = random_model(50, 3)
    written = write_model(tmp_path / "m.ply", model)
    assert written.notes == [] and written.order is None
    back = read_model(tmp_path / "m.ply")
    for name, tensor in model.tensors().items():
        assert torch.equal(tensor, back.tensors()[name]), name
    written = write_model(tmp_path / "m.splat", model)
    assert len(written.notes) == 1 and "SH degree 3 written as degree 0" in written.notes[0]
    assert written.notes[0].startswith(str(tmp_path / "m.splat"))
    assert write_model(tmp_path / "d0.splat", random_model(5, 0)).notes == []


def test_compressed_ply_is_written_in_morton_order_and_read_from_a_plain_ply_name(tmp_path):
    model = random_model(4096, 1)
    written = write_model(tmp_path / "m.compressed.ply", model)
    assert written.format == "compressed-ply"
    assert sorted(written.order.tolist()) == list(range(4096)) and written.order.tolist() != list(range(4096))
    # Consecutive splats in the file are spatial neighbours: a typical chunk of 256 (1/16 of a
    # uniform cube) lies in a box of half the cube's side (chunks straddling a Z-order cell
    # boundary are larger), where the model's own order spans the whole cube.
    means = model.means.numpy()[written.order]
    chunk_sides = [np.ptp(means[i:i + 256], axis=0).max() for i in range(0, 4096, 256)]
    assert np.median(chunk_sides) < 0.55 * np.ptp(means, axis=0).max()
    assert np.ptp(model.means.numpy()[:256], axis=0).max() > 0.9 * np.ptp(means, axis=0).max()
    plain_name = tmp_path / "renamed.ply"
    plain_name.write_bytes((tmp_path / "m.compressed.ply").read_bytes())
    assert open_model(plain_name).format == "compressed-ply"


def test_spz_flips_to_right_up_back_and_back(tmp_path):
    """On disk SPZ is RUB: y and z of the means are negated (read independently of the reader)."""
    model = random_model(20, 0)
    write_model(tmp_path / "m.spz", model)
    raw = gzip.decompress((tmp_path / "m.spz").read_bytes())
    _, version, count, degree, bits, _, _ = struct.unpack("<IIIBBBB", raw[:16])
    assert (version, count, degree) == (3, 20, 0)
    fixed = np.frombuffer(raw[16:16 + 9 * count], np.uint8).reshape(count, 3, 3).astype(np.int64)
    value = fixed[..., 0] | (fixed[..., 1] << 8) | (fixed[..., 2] << 16)
    value = np.where(value >= 1 << 23, value - (1 << 24), value) / float(1 << bits)
    expected = model.means.numpy() * np.array([1, -1, -1])
    assert np.abs(value - expected).max() <= 2.0 ** -bits


def test_spz_sh_signs_are_the_basis_under_the_frame_flip():
    from inceptiongs.io.spz import SH_REST_SIGNS
    from inceptiongs.rasterizer.sh import sh_basis

    directions = torch.nn.functional.normalize(torch.randn(64, 3, dtype=torch.float64), dim=1)
    flipped = directions * torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64)
    basis, basis_flipped = sh_basis(directions, 3), sh_basis(flipped, 3)
    signs = torch.cat([torch.ones(1, dtype=torch.float64), torch.as_tensor(SH_REST_SIGNS, dtype=torch.float64)])
    assert torch.allclose(basis_flipped, basis * signs, atol=1e-12)


def test_spz_notes_antialiasing_and_clamped_values(tmp_path):
    model = random_model(10, 1)
    model.sh[0, 1, 0] = 5.0  # beyond SPZ's SH rest range [-1, 1)
    written = write_model(tmp_path / "m.spz", model)
    assert any("1 of 90 SH rest values" in note for note in written.notes)
    raw = bytearray(gzip.decompress((tmp_path / "m.spz").read_bytes()))
    raw[14] = 0x1  # the antialiased flag
    (tmp_path / "aa.spz").write_bytes(gzip.compress(bytes(raw)))
    notes = open_model(tmp_path / "aa.spz").notes
    assert len(notes) == 1 and "antialiasing" in notes[0] and notes[0].startswith(str(tmp_path / "aa.spz"))


def test_ascii_ply_reads_like_the_binary_one(tmp_path):
    from plyfile import PlyData, PlyElement

    rng = np.random.default_rng(3)
    names = ply_field_names(2)
    record = np.zeros(9, [(name, "f4") for name in names])
    for name in names:
        record[name] = rng.standard_normal(9).astype(np.float32)
    PlyData([PlyElement.describe(record, "vertex")], text=True).write(str(tmp_path / "a.ply"))
    PlyData([PlyElement.describe(record, "vertex")], text=False).write(str(tmp_path / "b.ply"))
    ascii_model, binary_model = open_model(tmp_path / "a.ply"), open_model(tmp_path / "b.ply")
    assert (ascii_model.format, binary_model.format) == ("ply-ascii", "ply")
    assert ascii_model.gaussians.sh_degree == 2
    for name, tensor in binary_model.gaussians.tensors().items():
        assert torch.equal(tensor, ascii_model.gaussians.tensors()[name]), name


def _ascii_ply_text(rows: list[list[str]], before: str = "") -> str:
    names = ply_field_names(0)
    return ("ply\r\nformat ascii 1.0\r\n" + before + f"element vertex {len(rows)}\r\n"
            + "".join(f"property float {name}\r\n" for name in names) + "end_header\r\n"
            + "".join(" ".join(row) + "\r\n" for row in rows))


def test_ascii_ply_skips_earlier_elements_and_names_a_bad_value(tmp_path):
    width = len(ply_field_names(0))
    rows = [[str(float(i * width + j)) for j in range(width)] for i in range(3)]
    path = tmp_path / "a.ply"
    # An element before the vertices: its rows are lines to skip, not vertices.
    path.write_bytes(_ascii_ply_text(rows, "element extra 2\r\nproperty float a\r\n").replace(
        "end_header\r\n", "end_header\r\n7\r\n8\r\n").encode())
    means = read_model(path).means.numpy()
    assert means.tolist() == [[float(i * width + j) for j in range(3)] for i in range(3)]
    rows[1][6] = "abc"  # f_dc_0
    path.write_text(_ascii_ply_text(rows))
    with pytest.raises(InputError, match="ASCII PLY body is malformed") as info:
        read_model(path)
    assert "\n" not in str(info.value) and str(info.value).startswith(str(path))


def _truncate(path, keep: float = 0.6):
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * keep) - 13])  # 13: not a whole number of .splat records


@pytest.mark.parametrize("suffix", ["ply", "ascii.ply", "compressed.ply", "splat", "spz"])
@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty"])
def test_damaged_files_are_one_line_errors_naming_the_file(tmp_path, suffix, damage):
    path = tmp_path / f"m.{suffix}"
    if suffix == "ascii.ply":
        from plyfile import PlyData, PlyElement

        record = np.zeros(40, [(name, "f4") for name in ply_field_names(0)])
        PlyData([PlyElement.describe(record, "vertex")], text=True).write(str(path))
    else:
        write_model(path, random_model(300, 1))
    if damage == "truncated":
        _truncate(path)
    elif damage == "garbage":
        path.write_bytes(np.random.default_rng(1).integers(0, 256, 32 * 97, dtype=np.uint8).tobytes())
    else:
        path.write_bytes(b"")
    if suffix == "splat" and damage == "empty":
        assert len(read_model(path)) == 0  # zero records is an empty model, not an error
        return
    with pytest.raises(InputError) as info:
        read_model(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(path)), message


@pytest.mark.parametrize("problem, match", [
    ("old_layout", "older SuperSplat layout"),
    ("chunk_count", "declares 1 chunks for 300 splats"),
    ("sh_count", "not an SH degree 1-3"),
])
def test_compressed_ply_layout_problems_are_named(tmp_path, problem, match):
    path = tmp_path / "m.compressed.ply"
    write_model(path, random_model(300, 1))
    data = path.read_bytes()
    end = data.index(b"end_header\n")
    header, body = data[:end].decode(), data[end:]
    if problem == "old_layout":
        for bound in ("min", "max"):
            for channel in "rgb":
                header = header.replace(f"property float {bound}_{channel}\n", "")
    elif problem == "chunk_count":
        header = header.replace("element chunk 2", "element chunk 1")
    else:
        header = header.replace("property uchar f_rest_8\n", "")
    path.write_bytes(header.encode() + body)
    with pytest.raises(InputError, match=match):
        read_model(path)


@pytest.mark.parametrize("version, match", [(5, "version 5 is not supported"), (3, None)])
def test_spz_header_checks(tmp_path, version, match):
    write_model(tmp_path / "m.spz", random_model(4, 0))
    raw = bytearray(gzip.decompress((tmp_path / "m.spz").read_bytes()))
    raw[4:8] = struct.pack("<I", version)
    raw[8:12] = struct.pack("<I", 40)  # more splats than the arrays hold
    (tmp_path / "bad.spz").write_bytes(gzip.compress(bytes(raw)))
    with pytest.raises(InputError, match=match or "truncated or corrupt SPZ"):
        read_model(tmp_path / "bad.spz")


def test_model_names(tmp_path):
    assert [write_format(name) for name in ("a.ply", "a.Compressed.PLY", "a.splat", "a.spz")] == \
        ["ply", "compressed-ply", "splat", "spz"]
    for name in ("a.txt", "a.ksplat", "a"):
        with pytest.raises(InputError, match="not a model file name"):
            write_format(name)
    (tmp_path / "a.txt").write_text("x")
    with pytest.raises(InputError, match="not a model file"):
        read_model(tmp_path / "a.txt")
    with pytest.raises(InputError, match="does not exist"):
        read_model(tmp_path / "missing.spz")
    (tmp_path / "folder.splat").mkdir()
    with pytest.raises(InputError, match="not a file"):
        read_model(tmp_path / "folder.splat")


@pytest.mark.parametrize("suffix", ["compressed.ply", "splat", "spz", "spz-inner"])
def test_mutated_files_read_or_fail_with_one_line(tmp_path, suffix):
    """Seeded truncations, bit flips and insertions (inside the gzip stream too, for
    "spz-inner"): each file either reads to finite values or is one InputError line naming it."""
    rng = np.random.default_rng(len(suffix))
    source = tmp_path / f"source.{suffix.split('-')[0]}"
    write_model(source, random_model(300, 3))
    data = source.read_bytes()
    if suffix == "spz-inner":
        data = gzip.decompress(data)
    path = tmp_path / f"mutated.{suffix.split('-')[0]}"
    for case in range(40):
        buffer = bytearray(data)
        kind = case % 3
        if kind == 0:
            buffer = buffer[:rng.integers(0, len(buffer))]
        elif kind == 1:
            for _ in range(rng.integers(1, 8)):
                index = rng.integers(0, 400 if case % 2 else len(buffer))
                buffer[index] ^= 1 << int(rng.integers(0, 8))
        else:
            index = rng.integers(0, len(buffer))
            buffer[index:index] = rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()
        path.write_bytes(gzip.compress(bytes(buffer)) if suffix == "spz-inner" else bytes(buffer))
        try:
            model = read_model(path)
        except InputError as exc:
            assert "\n" not in str(exc) and str(exc).startswith(str(path)), (case, str(exc))
        else:
            assert all(bool(t.isfinite().all()) for t in model.tensors().values()), case


def test_values_beyond_a_format_are_noted_or_refused_naming_the_file(tmp_path):
    model = random_model(10, 0)
    model.log_scales[0, 0] = -30.0  # below the compressed PLY's [-20, 20]
    notes = write_model(tmp_path / "m.compressed.ply", model).notes
    assert notes == [f"{tmp_path / 'm.compressed.ply'}: 1 of 30 log scales lie outside [-20, 20] and are clamped"]
    model.means[0, 0] = 1e7  # beyond SPZ's 24-bit positions even with 1 fractional bit
    with pytest.raises(InputError, match=r"m.spz: a coordinate of 1e\+07 is beyond SPZ's 24-bit positions"):
        write_model(tmp_path / "m.spz", model)
    assert not (tmp_path / "m.spz").exists()
