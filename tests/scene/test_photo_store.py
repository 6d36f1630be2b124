"""The photo store: decoded photos cached bit for bit, rebuilt when a photo changes, held
within the photo budget, prefetched by a thread that stops cleanly."""

from __future__ import annotations

import os
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from inceptiongs.errors import InputError
from inceptiongs.io.photo_memory import parse_memory, set_photo_memory
from inceptiongs.scene.loader import load_scene
from inceptiongs.scene.photo_store import PhotoStore, cache_file, photo_bytes, photo_tensor


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    from demo_cases import copy_of_demo_scene
    return copy_of_demo_scene(tmp_path_factory.mktemp("photos") / "scene")


@pytest.mark.parametrize("downscale", [1, 4])
def test_the_cache_gives_the_decoded_photos_bit_for_bit(demo, downscale):
    scene = load_scene(str(demo), downscale=downscale)
    for index in range(0, len(scene.cameras), 5):
        decoded = torch.from_numpy(np.ascontiguousarray(scene.load_image(index), dtype=np.float32))
        first = photo_tensor(scene, index)                 # decodes and writes the cache file
        path = cache_file(scene, index)
        assert path.is_file() and demo.resolve() not in path.resolve().parents   # never in the scene folder
        assert np.load(path).dtype == np.uint8
        again = photo_tensor(scene, index)                 # read back from the memory map
        assert first.dtype == again.dtype == torch.float32
        assert torch.equal(first, decoded) and torch.equal(again, decoded)


def test_a_changed_photo_is_decoded_again(demo, tmp_path):
    import shutil
    root = tmp_path / "scene"
    shutil.copytree(demo, root)
    scene = load_scene(str(root), downscale=4)
    old = photo_tensor(scene, 0)
    old_file = cache_file(scene, 0)
    image_path = scene.image_paths[0]
    image = cv2.imread(str(image_path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(image_path), 255 - image)
    later = time.time() + 5
    os.utime(image_path, (later, later))
    new = photo_tensor(scene, 0)
    assert cache_file(scene, 0) != old_file and not old_file.exists()
    assert not torch.equal(new, old)
    assert torch.equal(new, torch.from_numpy(scene.load_image(0)))


def test_a_cache_folder_is_listed_once_however_many_photos_are_written(demo, tmp_path, monkeypatch):
    """A stale file (the photo before it changed, left by an earlier process) is removed when the
    photo is cached again, from one listing of the folder: listing it once per photo written made
    a 3,000-photo capture's cold start read 9 million names."""
    import shutil

    from inceptiongs.scene import photo_store

    root = tmp_path / "scene"
    shutil.copytree(demo, root)
    scene = load_scene(str(root), downscale=4)
    path = cache_file(scene, 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    stale = path.with_name(path.name.replace(path.name.split(".")[-2], "1-2"))
    np.save(stale, np.zeros((1, 1, 3), np.uint8))
    listed = []
    real_scandir = os.scandir
    monkeypatch.setattr(photo_store.os, "scandir", lambda folder: listed.append(folder) or real_scandir(folder))
    monkeypatch.setattr(photo_store, "_FOLDER_NAMES", {})
    for index in range(10):
        photo_tensor(scene, index)
    assert len(listed) == 1
    assert not stale.exists() and path.is_file()


def test_the_store_holds_at_most_its_budget_and_prefetches(demo):
    scene = load_scene(str(demo), downscale=4)
    views = list(range(len(scene.cameras)))
    one = photo_bytes(scene, 0)
    store = PhotoStore(scene, views, budget=3 * one)
    try:
        for view in views * 2:
            store.prefetch(views[view + 1:view + 4])
            assert torch.equal(store[view], torch.from_numpy(scene.load_image(view)))
            assert store.held_bytes <= store.budget
        assert 0 < store.peak_bytes <= 3 * one
    finally:
        store.close()
    assert store._held.thread is None


def test_a_budget_smaller_than_one_photo_is_one_line(demo):
    scene = load_scene(str(demo), downscale=4)
    with pytest.raises(InputError, match="--photo-memory: .* smaller than one photo"):
        PhotoStore(scene, [0, 1], budget=photo_bytes(scene, 0) - 1)


@pytest.mark.parametrize("text, nbytes", [("1G", 1 << 30), ("512M", 512 << 20), ("1.5k", 1536), ("800", 800)])
def test_sizes_are_read_with_their_units(text, nbytes):
    assert parse_memory(text) == nbytes


@pytest.mark.parametrize("text", ["lots", "-1G", "0", "1X"])
def test_a_size_that_is_not_one_is_one_line(text):
    with pytest.raises(InputError, match="--photo-memory"):
        parse_memory(text)


def test_train_with_a_budget_smaller_than_one_photo_exits_2_with_one_line(demo, tmp_path, capsys):
    from inceptiongs.cli import main
    out = tmp_path / "run"
    status = main(["train", str(demo), "--out", str(out), "--iterations", "2", "--downscale", "4",
                   "--photo-memory", "1K"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "--photo-memory" in err[0] and "one photo" in err[0]
    assert not out.exists()


def test_training_under_a_tiny_budget_never_holds_more_than_it(demo, tmp_path, monkeypatch):
    from inceptiongs.train import step
    from tests.train_cases import tiny_demo_run

    stores = []

    class Counted(PhotoStore):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            stores.append(self)

    monkeypatch.setattr(step, "PhotoStore", Counted)
    scene = load_scene(str(demo), downscale=4)
    budget = 2 * photo_bytes(scene, 0) + 1
    set_photo_memory(budget)
    try:
        run = tiny_demo_run(tmp_path)
    finally:
        set_photo_memory(None)
    assert (run / "model.ply").is_file()
    assert stores and all(0 < s.peak_bytes <= budget for s in stores)
    assert len(stores[0]) * photo_bytes(scene, 0) > 4 * budget   # the photos would not fit
    assert all(s._held.thread is None for s in stores)         # the prefetch thread ended with the run


def test_a_photo_deleted_mid_run_is_one_line_naming_it_and_the_thread_stops(demo, tmp_path):
    import shutil
    root = tmp_path / "scene"
    shutil.copytree(demo, root)
    scene = load_scene(str(root), downscale=4)
    store = PhotoStore(scene, range(len(scene.cameras)), budget=2 * photo_bytes(scene, 0))
    try:
        store[0]
        victim = scene.image_paths[3]
        victim.unlink()
        store.prefetch([3])             # the thread meets the missing file and goes on
        time.sleep(0.2)
        assert store._held.thread.is_alive()
        with pytest.raises(InputError, match=str(victim.name)) as caught:
            store[3]
        assert "\n" not in str(caught.value)
    finally:
        store.close()
    assert store._held.thread is None


def test_a_stopped_store_prefetches_nothing(demo):
    scene = load_scene(str(demo), downscale=4)
    store = PhotoStore(scene, range(4), budget=4 * photo_bytes(scene, 0))
    store.prefetch([1, 2])
    store.close()
    store.prefetch([3])
    assert store._held.thread is None
    assert torch.equal(store[3], photo_tensor(scene, 3))   # reads still work, in the caller's thread



def test_a_store_on_a_device_uploads_one_photo_per_read(demo):
    scene = load_scene(str(demo), downscale=4)
    store = PhotoStore(scene, range(3), budget=3 * photo_bytes(scene, 0))
    moved = store.on("meta")
    assert moved[1].device.type == "meta" and moved[1].shape == store[1].shape
    assert store[1].device.type == "cpu" and store.held_bytes == photo_bytes(scene, 1)   # one host copy


def test_the_prefetched_views_are_the_ones_the_sampler_draws_next():
    from types import SimpleNamespace

    from inceptiongs.train.step import next_view, upcoming_views

    data = SimpleNamespace(train=[2, 5, 7, 9, 11], images={})
    state = SimpleNamespace(order=[], order_pos=0, view_rng=np.random.default_rng(3))
    for _ in range(12):   # across epoch boundaries
        ahead = upcoming_views(state, data, 7)
        drawn = [next_view(state, data) for _ in range(7)]
        assert drawn == ahead


def test_the_environment_sets_the_budget_of_every_command(monkeypatch):
    from inceptiongs.io.photo_memory import photo_memory
    monkeypatch.setenv("INCEPTIONGS_PHOTO_MEMORY", "2M")
    assert photo_memory() == 2 << 20
    monkeypatch.setenv("INCEPTIONGS_PHOTO_MEMORY", "plenty")
    with pytest.raises(InputError, match=r"\$INCEPTIONGS_PHOTO_MEMORY: 'plenty'"):
        photo_memory()
