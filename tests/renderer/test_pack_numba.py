"""renderer/pack_numba.pack_rows: the texels of chosen rows, bit-equal to pack_gaussians of the
gathered rows (SH degrees 0 and 3, far from the origin, repeated rows, none)."""

from __future__ import annotations

import numpy as np
import pytest

from inceptiongs.renderer.pack_numba import pack_rows
from inceptiongs.renderer.splats import pack_gaussians


def _arrays(n: int, degree: int, offset: float, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    f = lambda *shape: rng.normal(size=shape).astype(np.float32)  # noqa: E731
    return {"means": f(n, 3) + np.float32(offset), "log_scales": f(n, 3) - 3.0, "quats": f(n, 4),
            "opacity_logits": f(n) * 20.0, "sh": f(n, (degree + 1) ** 2, 3)}


@pytest.mark.parametrize("degree, offset", [(0, 0.0), (3, 3e4), (1, -1e5)])
def test_pack_rows_equals_packing_the_gathered_rows(degree, offset):
    arrays = _arrays(500, degree, offset)
    rows = np.random.default_rng(1).integers(0, 500, 300)   # repeats and any order
    gathered = {name: values[rows] for name, values in arrays.items()}
    expected, anchor, _ = pack_gaussians(gathered)
    np.testing.assert_array_equal(pack_rows(arrays, rows, anchor), expected)
    # Into a slice of a larger array whose padding held garbage.
    out = np.full((400, *expected.shape[1:]), np.nan, np.float32)
    pack_rows(arrays, rows, anchor, out=out[50:350])
    np.testing.assert_array_equal(out[50:350], expected)
    assert np.isnan(out[:50]).all() and np.isnan(out[350:]).all()


def test_pack_rows_of_nothing_and_a_wrong_out():
    arrays = _arrays(10, 0, 0.0)
    assert pack_rows(arrays, np.zeros(0, np.int64), np.zeros(3)).shape == (0, 4, 4)
    with pytest.raises(ValueError, match="out has shape"):
        pack_rows(arrays, np.arange(5), np.zeros(3), out=np.empty((4, 4, 4), np.float32))
