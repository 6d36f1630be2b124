"""The gizmo's pure transforms and the visible rectangle's depth test (no GL)."""

from __future__ import annotations

import numpy as np
import pytest

from inceptiongs.app.editing import EditState, select_visible
from inceptiongs.app.gizmo import (axis_angle_quaternion, drag_amount, quaternion_matrix, rotate, scale,
                                   transform_rows, translate)


def _random_quats(n, rng):
    q = rng.normal(size=(n, 4))
    return (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)


def test_rotation_turns_means_about_the_pivot_and_orientations_with_them():
    rng = np.random.default_rng(0)
    means = rng.normal(size=(20, 3)).astype(np.float32)
    quats = _random_quats(20, rng)
    pivot = np.array([0.5, -1.0, 2.0])
    q = axis_angle_quaternion([0, 0, 2.0], np.pi / 2)  # 90 degrees about z
    new_means, new_quats = rotate(means, quats, pivot, q)
    assert new_means.shape == (20, 3) and new_quats.shape == (20, 4) and new_means.dtype == np.float32
    offset = means - pivot
    expected = np.stack([-offset[:, 1], offset[:, 0], offset[:, 2]], 1) + pivot
    np.testing.assert_allclose(new_means, expected, atol=1e-5)
    turn = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], float)
    for old, new in zip(quats, new_quats):
        np.testing.assert_allclose(quaternion_matrix(new), turn @ quaternion_matrix(old), atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(new_quats, axis=1), 1.0, atol=1e-6)


def test_scale_multiplies_offsets_and_sizes_alike():
    rng = np.random.default_rng(1)
    means = rng.normal(size=(10, 3)).astype(np.float32)
    log_scales = rng.normal(size=(10, 3)).astype(np.float32) - 3
    pivot = means.mean(axis=0)
    new_means, new_logs = scale(means, log_scales, pivot, 2.0)
    np.testing.assert_allclose(new_means - pivot, 2.0 * (means - pivot), atol=1e-5)
    np.testing.assert_allclose(np.exp(new_logs), 2.0 * np.exp(log_scales), rtol=1e-5)
    # a factor of zero or less is clamped, never a log of zero
    _, clamped = scale(means, log_scales, pivot, 0.0)
    assert np.isfinite(clamped).all()


def test_translate_and_drag_amount():
    means = np.zeros((3, 3), np.float32)
    np.testing.assert_array_equal(translate(means, [1, 2, 3]), np.tile([1, 2, 3], (3, 1)))
    assert drag_amount(np.array([100.0, 0.0]), np.array([50.0, 20.0])) == pytest.approx(0.5)
    assert drag_amount(np.array([0.0, 0.0]), np.array([50.0, 20.0])) == 0.0  # axis at the eye


def test_transform_rows_changes_only_the_keys_a_mode_needs():
    rng = np.random.default_rng(2)
    arrays = {"means": rng.normal(size=(5, 3)).astype(np.float32), "quats": _random_quats(5, rng),
              "log_scales": np.zeros((5, 3), np.float32)}
    rows = np.array([1, 3])
    assert set(transform_rows(arrays, rows, "translate", 0, 1.0, np.zeros(3), 1.0)) == {"means"}
    assert set(transform_rows(arrays, rows, "rotate", 1, 1.0, np.zeros(3), 1.0)) == {"means", "quats"}
    out = transform_rows(arrays, rows, "scale", 2, 1.0, np.zeros(3), 1.0)
    np.testing.assert_allclose(out["log_scales"], 1.0, atol=1e-6)  # one handle length: x e
    with pytest.raises(ValueError, match="gizmo mode"):
        transform_rows(arrays, rows, "shear", 0, 1.0, np.zeros(3), 1.0)


def test_select_visible_leaves_out_what_is_behind_the_surface():
    pixels = np.array([[1.5, 1.5], [1.5, 1.5], [3.5, 0.5], [9.0, 9.0], [np.nan, np.nan]])
    depth = np.array([2.0, 5.0, 3.0, 2.0, 1.0])
    extent = np.full(5, 0.01)
    surface = np.zeros((4, 4))
    surface[1, 1] = 2.0   # a surface at depth 2 where the first two project
    surface[0, 3] = 0.0   # nothing drawn where the third projects
    selected = select_visible(pixels, depth, extent, surface, (0, 0))
    np.testing.assert_array_equal(selected, [True, False, False, False, False])
    # the window's origin shifts the lookup
    np.testing.assert_array_equal(select_visible(pixels + 10, depth, extent, surface, (10, 10)), selected)


def test_row_edits_undo_to_the_bytes_and_leave_the_loaded_arrays_alone():
    base = {"means": np.arange(12, dtype=np.float32).reshape(4, 3)}
    loaded = base["means"]
    edit = EditState(base)
    rows = np.array([0, 2])
    assert edit.transform_selected({"means": np.ones((2, 3), np.float32)}, rows)
    assert loaded[0, 0] == 0  # copied, never written in place
    np.testing.assert_array_equal(edit.base["means"][[0, 2]], 1.0)
    assert edit.undo() and edit.base["means"].tobytes() == loaded.tobytes()
    assert edit.redo()
    np.testing.assert_array_equal(edit.base["means"][[0, 2]], 1.0)
