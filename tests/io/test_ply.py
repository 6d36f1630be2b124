"""3DGS PLY: bit-exact round trips, SH layout, tolerated extras and clear errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import require_data
from inceptiongs.errors import InputError
from inceptiongs.gaussians import Gaussians
from inceptiongs.io.ply import ply_field_names, read_ply, write_ply


def _write_raw_ply(path, fields: dict[str, np.ndarray], fmt="binary_little_endian", extra_header=""):
    """A PLY written independently of ply.py: fields in the given order, any numpy dtype."""
    order = "<" if fmt == "binary_little_endian" else ">"
    type_names = {"f4": "float", "f8": "double", "u1": "uchar", "i4": "int"}
    dtype = np.dtype([(name, order + values.dtype.str[1:]) for name, values in fields.items()])
    n = len(next(iter(fields.values())))
    record = np.zeros(n, dtype)
    for name, values in fields.items():
        record[name] = values
    header = (f"ply\nformat {fmt} 1.0\ncomment written by a test\n{extra_header}element vertex {n}\n"
              + "".join(f"property {type_names[v.dtype.str[1:]]} {k}\n" for k, v in fields.items())
              + "end_header\n")
    path.write_bytes(header.encode() + record.tobytes())


def _standard_fields(n: int, degree: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {name: rng.standard_normal(n).astype(np.float32) for name in ply_field_names(degree)}


def _bits(t: torch.Tensor) -> np.ndarray:
    return t.numpy().view(np.int32)


def test_donut_round_trip_is_bit_exact(tmp_path):
    source = require_data("splats/donut.ply")
    g = read_ply(source)
    assert len(g) == 45624 and g.sh_degree == 0 and g.means.dtype == torch.float32

    # Independent parse of the original file with a hand-written dtype.
    raw = source.read_bytes()
    header_end = raw.index(b"end_header\n") + len(b"end_header\n")
    names = [line.split()[2] for line in raw[:header_end].decode().splitlines() if line.startswith("property")]
    original = np.frombuffer(raw, dtype=np.dtype([(n, "<f4") for n in names]), offset=header_end)
    for name, (attr, col) in {"x": ("means", 0), "z": ("means", 2), "f_dc_1": ("sh", None),
                              "opacity": ("opacity_logits", None), "scale_2": ("log_scales", 2),
                              "rot_0": ("quats", 0), "rot_3": ("quats", 3)}.items():
        tensor = getattr(g, attr)
        values = tensor[:, 0, 1] if attr == "sh" else (tensor if col is None else tensor[:, col])
        assert np.array_equal(values.numpy().view(np.int32), original[name].view(np.int32)), name

    first = tmp_path / "a.ply"
    second = tmp_path / "b.ply"
    write_ply(g, first)
    g2 = read_ply(first)
    for name, tensor in g.tensors().items():
        assert np.array_equal(_bits(tensor), _bits(g2.tensors()[name])), name
    write_ply(g2, second)
    assert first.read_bytes() == second.read_bytes()
    # The standard fields of the written file carry the original bytes.
    written_raw = first.read_bytes()
    written_end = written_raw.index(b"end_header\n") + len(b"end_header\n")
    written = np.frombuffer(written_raw, dtype=np.dtype([(n, "<f4") for n in ply_field_names(0)]),
                            offset=written_end)
    for name in names:
        assert written[name].tobytes() == original[name].tobytes(), name


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_layout_is_channel_major(tmp_path, degree):
    n = 7
    fields = _standard_fields(n, degree, seed=degree)
    path = tmp_path / "g.ply"
    _write_raw_ply(path, fields)
    g = read_ply(path)
    k = (degree + 1) ** 2
    assert g.sh_degree == degree and tuple(g.sh.shape) == (n, k, 3)
    for c in range(3):
        assert np.array_equal(g.sh[:, 0, c].numpy(), fields[f"f_dc_{c}"])
        for j in range(k - 1):
            assert np.array_equal(g.sh[:, j + 1, c].numpy(), fields[f"f_rest_{c * (k - 1) + j}"])
    out = tmp_path / "out.ply"
    write_ply(g, out)
    # The file written by a test and the one written by ply.py hold the same bytes per field.
    again = read_ply(out)
    for name, tensor in g.tensors().items():
        assert torch.equal(tensor, again.tensors()[name])


def test_extra_fields_and_other_order_and_big_endian(tmp_path):
    fields = _standard_fields(5, 1)
    shuffled = dict(reversed(list(fields.items())))
    shuffled["confidence"] = np.arange(5, dtype=np.uint8)
    shuffled["weight"] = np.linspace(0, 1, 5)  # float64 extra
    little = tmp_path / "little.ply"
    big = tmp_path / "big.ply"
    _write_raw_ply(little, shuffled)
    _write_raw_ply(big, shuffled, fmt="binary_big_endian")
    a, b = read_ply(little), read_ply(big)
    assert np.array_equal(a.means[:, 1].numpy(), fields["y"])
    assert np.array_equal(a.quats[:, 2].numpy(), fields["rot_2"])
    for name, tensor in a.tensors().items():
        assert torch.equal(tensor, b.tensors()[name])


def test_empty_model_round_trips(tmp_path):
    path = tmp_path / "empty.ply"
    write_ply(Gaussians.empty(sh_degree=2), path)
    g = read_ply(path)
    assert len(g) == 0 and g.sh_degree == 2


def test_write_is_atomic_on_failure(tmp_path):
    path = tmp_path / "keep.ply"
    path.write_bytes(b"previous")

    class Broken(Gaussians):
        def numpy(self):
            raise RuntimeError("boom")

    g = Gaussians.empty()
    broken = Broken(**g.tensors())
    with pytest.raises(RuntimeError):
        write_ply(broken, path)
    assert path.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.ply"]


def _valid_file(tmp_path, n=4, degree=0):
    path = tmp_path / "ok.ply"
    _write_raw_ply(path, _standard_fields(n, degree))
    return path


@pytest.mark.parametrize("problem, match", [
    ("truncated", "truncated PLY"),
    ("no_end_header", "no end_header"),
    ("not_ply", "not a PLY"),
    ("ascii_truncated", "truncated ASCII PLY"),
    ("nan", "NaN/Inf"),
    ("inf", "NaN/Inf"),
    ("bad_rest_count", "f_rest fields"),
    ("missing_field", "lacks 3DGS field"),
    ("missing", "does not exist"),
    ("list_property", "list property"),
])
def test_bad_ply_raises_one_line_input_error(tmp_path, problem, match):
    path = tmp_path / "bad.ply"
    if problem == "truncated":
        data = _valid_file(tmp_path).read_bytes()
        path.write_bytes(data[:-10])
    elif problem == "no_end_header":
        path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n")
    elif problem == "not_ply":
        path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 64)
    elif problem == "ascii_truncated":
        names = ply_field_names(0)
        path.write_text("ply\nformat ascii 1.0\nelement vertex 2\n" + "".join(f"property float {n}\n" for n in names)
                        + "end_header\n" + " ".join(["0.5"] * len(names)) + "\n")
    elif problem in ("nan", "inf"):
        fields = _standard_fields(4, 0)
        fields["scale_1"][2] = np.nan if problem == "nan" else np.inf
        _write_raw_ply(path, fields)
    elif problem == "bad_rest_count":
        fields = _standard_fields(3, 0)
        fields.update({f"f_rest_{i}": np.zeros(3, np.float32) for i in range(10)})
        _write_raw_ply(path, fields)
    elif problem == "missing_field":
        fields = _standard_fields(3, 0)
        del fields["rot_3"]
        _write_raw_ply(path, fields)
    elif problem == "missing":
        path = tmp_path / "nope.ply"
    elif problem == "list_property":
        path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
                         b"property list uchar int vertex_indices\nend_header\n\x00")
    with pytest.raises(InputError, match=match) as info:
        read_ply(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(path))
