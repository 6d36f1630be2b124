"""The window's level-of-detail rules without a window (app/detail.py): the splat budget's
control, the preview, the memory estimate and its refusal, the worker's cuts."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from inceptiongs.app import detail
from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.io.ply import write_ply
from inceptiongs.lod.cut import cut_nodes


def test_the_budget_follows_the_frame_cost_within_bounded_steps():
    assert detail.next_budget(100_000, 400.0, 80.0) == int(100_000 / detail.BUDGET_STEP_MAX)  # one step at most
    assert detail.next_budget(100_000, 100.0, 80.0) == 80_000          # proportional inside the step
    assert detail.next_budget(100_000, 10.0, 80.0) == int(100_000 * detail.BUDGET_STEP_MAX)
    assert detail.next_budget(detail.BUDGET_MIN, 1e6) == detail.BUDGET_MIN
    assert detail.next_budget(detail.BUDGET_MAX, 1e-3) == detail.BUDGET_MAX
    for cost in (0.0, -5.0, math.nan, math.inf):
        assert detail.next_budget(123_456, cost) == 123_456              # nothing measured: unchanged


def test_the_preview_is_a_fixed_subset_in_model_order():
    arrays = {"means": np.arange(30, dtype=np.float32).reshape(10, 3), "opacity_logits": np.arange(10.0)}
    small = detail.preview_arrays(arrays, 4)
    assert len(small["means"]) == 4 and np.all(np.diff(small["opacity_logits"]) > 0)
    assert np.array_equal(small["means"][:, 0] / 3, small["opacity_logits"])   # rows stay together
    assert np.array_equal(detail.preview_arrays(arrays, 4)["means"], small["means"])
    assert detail.preview_arrays(arrays, 20) is arrays


def test_memory_estimate_and_the_refusal_name_the_file_and_what_to_do(tmp_path):
    degree0, degree3 = 1, 16
    assert detail.gl_bytes_per_gaussian(degree0) == 16 * 4 + detail.GL_SPLAT_BYTES
    assert detail.gl_bytes_per_gaussian(degree3) == 16 * 15 + detail.GL_SPLAT_BYTES
    small = detail.window_bytes(1000, degree0)
    assert small == 1000 * detail.gl_bytes_per_gaussian(degree0)            # no tree below the threshold
    large = detail.window_bytes(5_000_000, degree0)
    assert large > 5_000_000 * (detail.gl_bytes_per_gaussian(degree0) + detail.model_bytes_per_gaussian(degree0))
    detail.check_window_memory(tmp_path / "m.ply", 5_000_000, degree0, available=large + 1)
    with pytest.raises(Exception) as refused:
        detail.check_window_memory(tmp_path / "m.ply", 5_000_000, degree0, available=large // 2)
    line = str(refused.value)
    assert "\n" not in line and str(tmp_path / "m.ply") in line and "5,000,000 Gaussians" in line
    assert "--lod-budget" in line


def test_the_viewer_refuses_a_model_too_large_for_memory_in_one_line(tmp_path, monkeypatch, capsys):
    from inceptiongs.app import main as viewer_main
    from inceptiongs.io import limits

    arrays = {"means": np.zeros((50, 3), np.float32), "log_scales": np.full((50, 3), -3.0, np.float32),
              "quats": np.tile(np.float32([1, 0, 0, 0]), (50, 1)), "opacity_logits": np.zeros(50, np.float32),
              "sh": np.zeros((50, 1, 3), np.float32)}
    path = tmp_path / "model.ply"
    write_ply(Gaussians.from_numpy(arrays), path)
    window = detail.window_bytes(50, 1)
    assert window > 3 * 50 * 14 * 4   # more than the reading of the file itself needs
    monkeypatch.setattr(limits, "available_memory_bytes", lambda: window - 1)   # the file reads, the window does not fit
    assert viewer_main.main([str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "50 Gaussians" in err[0]


def _camera(centre=(0.0, 0.0, 0.0)) -> Camera:
    centre = np.asarray(centre, np.float64)
    pose = look_at(centre + [0.0, 0.0, -3.0], centre, np.array([0.0, -1.0, 0.0]))
    return Camera("c", 160, 120, 150.0, 150.0, 80.0, 60.0, pose)


def _cloud(n: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return {"means": rng.normal(0, 1, (n, 3)).astype(np.float32),
            "log_scales": np.full((n, 3), -4.0, np.float32),
            "quats": np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
            "opacity_logits": np.full(n, 1.0, np.float32),
            "sh": rng.normal(0, 0.5, (n, 1, 3)).astype(np.float32)}


def _wait(condition, seconds: float = 30.0) -> None:
    deadline = time.perf_counter() + seconds
    while not condition():
        assert time.perf_counter() < deadline
        time.sleep(0.01)


def test_the_worker_builds_once_and_cuts_for_the_newest_request(tmp_path, monkeypatch):
    builds = []
    real_build = detail.DetailWorker._build
    monkeypatch.setattr(detail.DetailWorker, "_build",
                        lambda self, version, arrays: (builds.append(version), real_build(self, version, arrays)))
    worker = detail.DetailWorker()
    try:
        arrays = _cloud(3000)
        for _ in range(5):
            worker.set_model("first", arrays)   # offered every frame while it builds
        _wait(lambda: worker.ready)
        assert builds == ["first"] and worker.latest("first") is None
        camera = _camera()
        worker.request("first", camera, True, 0)
        _wait(lambda: worker.latest("first") is not None)
        cut = worker.latest("first")
        assert cut.settled and cut.total == 3000
        assert cut.count == len(cut_nodes(worker.hierarchy, camera, detail.SETTLED_GRANULARITY_PX))
        texels, anchor, degree = cut.packed
        assert texels.shape[0] == cut.count and degree == 0 and np.all(np.isfinite(anchor))
        worker.request("first", camera, False, 50)
        _wait(lambda: worker.latest("first").serial > cut.serial)
        assert 0 < worker.latest("first").count <= 50 and worker.latest("first").budget == 50
        worker.set_model("second", _cloud(2000, seed=1))   # a new model: nothing of the old one is shown
        assert worker.latest("second") is None and worker.latest("first") is None
        _wait(lambda: worker.ready)
        assert worker.hierarchy.leaf_count == 2000 and builds == ["first", "second"]
        worker.request("first", camera, True, 0)   # a request for a model no longer shown
        _wait(lambda: not worker.busy)
        assert worker.latest("second") is None
    finally:
        worker.close()


def test_packing_a_cut_in_chunks_equals_packing_it_whole():
    from inceptiongs.lod.hierarchy import build_hierarchy
    from inceptiongs.renderer.splats import pack_gaussians

    arrays = _cloud(1000)
    far = np.float32([1e4, -2e4, 3e4])   # far from the origin
    arrays["means"] = arrays["means"] + far
    arrays["sh"] = np.random.default_rng(2).normal(0, 0.5, (1000, 16, 3)).astype(np.float32)   # degree 3
    tree = build_hierarchy(Gaussians.from_numpy(arrays))
    camera = _camera(far)
    nodes = cut_nodes(tree, camera, 30.0)
    assert (tree.child_count[nodes] > 0).any() and (tree.child_count[nodes] == 0).any()   # merged nodes and leaves
    whole = pack_gaussians(tree.node_arrays(nodes))
    chunked = detail.pack_nodes(tree, nodes, chunk=37)
    assert chunked[2] == whole[2] == 3
    np.testing.assert_allclose(chunked[1], whole[1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(chunked[0], whole[0], rtol=0, atol=2e-3)   # means relative to anchors 1e-9 apart
    assert np.array_equal(chunked[0][:, 1:], whole[0][:, 1:])   # scales, rotations, colours exactly
    empty = detail.pack_nodes(tree, nodes[:0])
    assert empty[0].shape == (0, whole[0].shape[1], 4) and np.all(empty[1] == 0)
    # Blended: each chunk's nodes take their sibling counts from the whole cut, not the chunk.
    from inceptiongs.lod.blend import blend_weights, blended_arrays

    weights = blend_weights(tree, camera, nodes, 30.0)
    assert 0 < (weights < 1).sum() < len(nodes)
    blended_whole = pack_gaussians(blended_arrays(tree, nodes, weights))
    blended_chunked = detail.pack_nodes(tree, nodes, chunk=37, weights=weights)
    np.testing.assert_allclose(blended_chunked[0], blended_whole[0], rtol=0, atol=2e-3)
    assert np.array_equal(blended_chunked[0][:, 1:], blended_whole[0][:, 1:])
    assert not np.array_equal(blended_chunked[0][:, 1:], chunked[0][:, 1:])


def test_only_an_unedited_model_is_replaced_by_the_tree_leaves():
    from types import SimpleNamespace

    from inceptiongs.app.editing import EditState
    from inceptiongs.app.detail import share_tree_leaves
    from inceptiongs.lod.hierarchy import build_hierarchy

    arrays = _cloud(500)
    tree = build_hierarchy(Gaussians.from_numpy(arrays))
    edited = EditState(arrays)
    edited.select(np.arange(500) < 10)
    edited.delete_selected()
    for edit in (edited, EditState(arrays, selected=np.arange(500) < 3)):
        holder = SimpleNamespace(edit=edit, source=SimpleNamespace(gaussians=arrays))
        assert share_tree_leaves(holder, tree) is False and holder.edit is edit
    holder = SimpleNamespace(edit=EditState(arrays), source=SimpleNamespace(gaussians=arrays))
    assert share_tree_leaves(holder, tree) is True
    assert np.shares_memory(holder.edit.base["sh"], tree.sh) and holder.source.gaussians is holder.edit.base
    assert holder.edit.count == 500
    assert share_tree_leaves(holder, tree) is False   # once
