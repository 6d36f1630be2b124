"""The hierarchy cache: keyed by content, invalidated by any change, atomic, never beside the input."""

from __future__ import annotations

import os

import numpy as np

from inceptiongs.io.cache import cache_root
from inceptiongs.io.ply import write_ply
from inceptiongs.lod.cache import hierarchy_cache_path, load_hierarchy, load_or_build, model_key, ply_key

from lod_cases import random_gaussians


def assert_same_tree(a, b):
    for name, array in a.arrays().items():
        np.testing.assert_array_equal(array, b.arrays()[name], err_msg=name)


def test_second_load_comes_from_the_cache_and_equals_the_build():
    g = random_gaussians(120, seed=31)
    built, cached_first = load_or_build(g)
    loaded, cached_second = load_or_build(g)
    assert (cached_first, cached_second) == (False, True)
    assert_same_tree(built, loaded)
    path = hierarchy_cache_path(model_key(g))
    assert path.is_file() and path.parent == cache_root() / "lod"
    assert not [p for p in path.parent.iterdir() if p.name.endswith(".tmp")]   # no temporary left


def test_a_changed_model_misses_the_cache():
    g = random_gaussians(120, seed=32)
    first, _ = load_or_build(g)
    g.opacity_logits[7] += 0.25
    second, cached = load_or_build(g)
    assert not cached and model_key(g) != model_key(random_gaussians(120, seed=32))
    assert not np.array_equal(first.opacity_logits, second.opacity_logits)
    assert model_key(g, branching=4) != model_key(g, branching=8)


def test_ply_key_follows_the_file_bytes_and_the_cache_stays_out_of_the_input_folder(tmp_path):
    g = random_gaussians(50, seed=33)
    ply = tmp_path / "scene" / "model.ply"
    write_ply(g, ply)
    copy = tmp_path / "copy.ply"
    copy.write_bytes(ply.read_bytes())
    assert ply_key(ply) == ply_key(copy)
    before = sorted(os.listdir(ply.parent))
    load_or_build(g, key=ply_key(ply))
    assert sorted(os.listdir(ply.parent)) == before
    g.means[0, 0] += 1.0
    write_ply(g, ply)
    assert ply_key(ply) != ply_key(copy)


def test_a_corrupt_cache_file_is_rebuilt():
    g = random_gaussians(60, seed=34)
    built, _ = load_or_build(g)
    path = hierarchy_cache_path(model_key(g))
    path.write_bytes(path.read_bytes()[:200])
    assert load_hierarchy(path) is None
    rebuilt, cached = load_or_build(g)
    assert not cached
    assert_same_tree(built, rebuilt)
    assert load_hierarchy(path) is not None


def test_a_cache_file_with_broken_links_is_refused(tmp_path):
    from inceptiongs.lod.cache import save_hierarchy

    tree, _ = load_or_build(random_gaussians(40, seed=35))
    tree.child_start[-1] = len(tree)   # the root's children would run past the arrays
    save_hierarchy(tree, tmp_path / "broken.npz")
    assert load_hierarchy(tmp_path / "broken.npz") is None


def test_an_unwritable_cache_still_gives_the_hierarchy(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("INCEPTIONGS_CACHE_DIR", str(blocker / "cache"))   # below a file: ENOTDIR
    g = random_gaussians(30, seed=36)
    tree, cached = load_or_build(g)
    assert not cached and tree.leaf_count == 30
    assert load_or_build(g)[1] is False
