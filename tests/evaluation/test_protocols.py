"""Split properties of the llff / unstructured / none protocols."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from inceptiongs.camera import Camera, look_at, pose_distance
from inceptiongs.errors import InputError
from inceptiongs.evaluation.protocols import Split, make_split, pose_distance_matrix


def ring_cameras(n: int, radius: float = 3.0) -> list[Camera]:
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return [Camera(f"view{i:03d}", 64, 48, 50.0, 50.0, 32.0, 24.0,
                   look_at([radius * np.cos(a), 0.3 * np.sin(3 * a), radius * np.sin(a)], [0, 0, 0]))
            for i, a in enumerate(angles)]


def check_partition(split: Split, n: int) -> None:
    assert sorted(split.train + split.test) == list(range(n))
    assert not set(split.train) & set(split.test)
    assert sorted(split.scarce_test + split.covered_test) == split.test
    assert split.problem() is None


@pytest.mark.parametrize("n", [12, 23, 40])
@pytest.mark.parametrize("seed", [0, 1, 7])
def test_unstructured_cluster_properties(n, seed):
    cameras = ring_cameras(n)
    split = make_split(cameras, "unstructured", seed)
    check_partition(split, n)
    # 6 clusters partitioning the views
    assert len(split.clusters) == 6
    assert sorted(i for c in split.clusters for i in c) == list(range(n))
    # the target view is held out and is the centroid of the scarce cluster
    scarce = split.scarce_cluster
    assert split.target_view in split.test and split.target_view in scarce
    distances = pose_distance_matrix(cameras)
    sums = {i: sum(distances[i, j] for j in scarce) for i in scarce}
    assert sums[split.target_view] == pytest.approx(min(sums.values()))
    # 90% of the scarce cluster held out (round half up), one view always trains
    expected_scarce = min(len(scarce) - 1, max(1, math.floor(0.9 * len(scarce) + 0.5)))
    assert sorted(split.scarce_test) == sorted(i for i in scarce if i in split.test)
    assert len(split.scarce_test) == expected_scarce
    # 5% (at least one) of every other cluster, never all of it
    for cluster in split.clusters:
        if split.target_view in cluster:
            continue
        held = [i for i in cluster if i in split.test]
        assert all(i in split.covered_test for i in held)
        expected = min(len(cluster) - 1, max(1, math.floor(0.05 * len(cluster) + 0.5))) if len(cluster) > 1 else 0
        assert len(held) == expected
        assert len(held) < len(cluster)


def test_clusters_are_farthest_point_groups():
    # Views in 6 tight, well separated groups must come out as exactly those groups.
    rng = np.random.default_rng(0)
    cameras = []
    for g in range(6):
        angle = g * np.pi / 3
        for k in range(4):
            eye = np.array([10 * np.cos(angle), 0.0, 10 * np.sin(angle)]) + 0.05 * rng.standard_normal(3)
            cameras.append(Camera(f"g{g}_{k}", 32, 32, 30, 30, 16, 16, look_at(eye, [0, 0, 0])))
    split = make_split(cameras, "unstructured", 3)
    assert sorted(sorted(c) for c in split.clusters) == [list(range(4 * g, 4 * g + 4)) for g in range(6)]


def test_deterministic_per_seed_and_seeds_differ():
    cameras = ring_cameras(30)
    a, b = make_split(cameras, "unstructured", 5), make_split(cameras, "unstructured", 5)
    assert a == b
    others = [make_split(cameras, "unstructured", s) for s in range(6, 12)]
    assert any(o.test != a.test for o in others)


def test_llff_every_eighth_and_none():
    cameras = ring_cameras(20)
    split = make_split(cameras, "llff", 0)
    assert split.test == [0, 8, 16] and split.covered_test == [0, 8, 16]
    assert split.target_view is None and split.scarce_test == []
    check_partition(split, 20)
    everything = make_split(cameras, "none", 0)
    assert everything.train == list(range(20)) and everything.test == []


def test_few_views_rules():
    for n in range(2, 12):
        split = make_split(ring_cameras(n), "unstructured", 0)
        check_partition(split, n)
        assert len(split.clusters) == n // 2
        assert split.target_view in split.test and split.train  # something always trains
    with pytest.raises(InputError, match="at least 2 views"):
        make_split(ring_cameras(1), "unstructured", 0)
    with pytest.raises(InputError, match="unknown protocol"):
        make_split(ring_cameras(4), "random", 0)


def test_duplicate_poses_give_no_empty_cluster():
    base = ring_cameras(3)
    cameras = [Camera(f"d{i}", 32, 32, 30, 30, 16, 16, base[i % 3].world_to_camera) for i in range(14)]
    split = make_split(cameras, "unstructured", 0)
    assert len(split.clusters) == 3 and all(split.clusters)
    check_partition(split, 14)


def test_distance_mixes_position_and_orientation():
    cameras = ring_cameras(8)
    d = pose_distance_matrix(cameras)
    centers = np.array([c.center for c in cameras])
    weight = np.mean(np.linalg.norm(centers - centers.mean(0), axis=1))
    assert d[1, 5] == pytest.approx(pose_distance(cameras[1].world_to_camera, cameras[5].world_to_camera, weight))
    assert np.allclose(d, d.T) and np.all(np.diag(d) == 0)


def test_save_load_round_trip_and_validation(tmp_path):
    cameras = ring_cameras(16)
    split = make_split(cameras, "unstructured", 2)
    path = tmp_path / "split.json"
    split.save(path)
    assert Split.load(path, cameras) == split
    with pytest.raises(InputError, match="other views"):
        Split.load(path, cameras[:10])
    bad = split.to_json()
    bad["test"] = bad["test"] + [bad["train"][0]]
    (tmp_path / "bad.json").write_text(__import__("json").dumps(bad))
    with pytest.raises(InputError, match="bad.json"):
        Split.load(tmp_path / "bad.json")
    with pytest.raises(InputError, match="does not exist"):
        Split.load(tmp_path / "missing.json")


def test_real_scenes_split_properties():
    from conftest import require_data
    from inceptiongs.scene.loader import load_scene

    statuette = load_scene(require_data("statuette"), downscale=2)
    split = make_split(statuette, "unstructured", 0)
    check_partition(split, len(statuette.cameras))
    assert len(split.clusters) == 6 and split.target_view in split.scarce_test
    assert len(split.covered_test) == 5  # one per covered cluster (each has < 10 views)
    fern = load_scene(require_data("fern"))
    assert make_split(fern, "llff", 0).test == [0, 8, 16]


def test_declared_scarce_views_form_the_scarce_cluster():
    cameras = ring_cameras(20)
    declared = [cameras[i].name for i in (3, 4, 5, 6, 7)]
    for seed in range(4):
        split = make_split(cameras, "unstructured", seed, scarce_views=declared)
        check_partition(split, 20)
        assert split.scarce_cluster == [3, 4, 5, 6, 7]
        assert split.target_view == 5                       # the cluster's centroid view
        assert len(split.scarce_test) == 4 and set(split.scarce_test) < {3, 4, 5, 6, 7}
        assert not set(split.covered_test) & {3, 4, 5, 6, 7}
    with pytest.raises(InputError, match="not views of the scene"):
        make_split(cameras, "unstructured", 0, scarce_views=["nope.png", cameras[0].name])
    with pytest.raises(InputError, match="at least 2 views"):
        make_split(cameras, "unstructured", 0, scarce_views=[cameras[0].name])
    with pytest.raises(InputError, match="unstructured"):
        make_split(cameras, "llff", 0, scarce_views=declared)


@pytest.mark.parametrize("protocol", ["unstructured", "llff", "none"])
def test_excluded_photos_are_neither_trained_nor_held_out_and_the_rest_split_as_if_alone(protocol, tmp_path):
    cameras = ring_cameras(30)
    left_out = ["view003", "view004", "view017", "view029"]
    split = make_split(cameras, protocol, 2, exclude=left_out)
    excluded = [3, 4, 17, 29]
    assert split.excluded == excluded and split.problem() is None
    assert not set(excluded) & set(split.train + split.test)
    assert sorted(split.train + split.test + split.excluded) == list(range(30)) and split.num_views == 30
    # The protocol sees only the other 26 photos: the same split as those alone, in whole-scene indices.
    kept = [i for i in range(30) if i not in excluded]
    alone = make_split([cameras[i] for i in kept], protocol, 2)
    assert split.train == [kept[i] for i in alone.train] and split.test == [kept[i] for i in alone.test]
    assert split.scarce_test == [kept[i] for i in alone.scarce_test]
    assert split.target_view == (None if alone.target_view is None else kept[alone.target_view])
    assert [sorted(c) for c in split.clusters] == [sorted(kept[i] for i in c) for c in alone.clusters]
    # It round-trips through split.json and is recognised as the scene's.
    split.save(tmp_path / "split.json")
    assert Split.load(tmp_path / "split.json", cameras) == split


def test_excluding_an_unknown_or_a_declared_scarce_photo_is_refused():
    cameras = ring_cameras(12)
    with pytest.raises(InputError, match="no photo named 'nope.jpg' to exclude"):
        make_split(cameras, "unstructured", 0, exclude=["view001", "nope.jpg"])
    with pytest.raises(InputError, match="both a declared scarce view and excluded"):
        make_split(cameras, "unstructured", 0, scarce_views=["view002", "view003"], exclude=["view003"])
    # A split file whose excluded views overlap its training views is not a split.
    broken = make_split(cameras, "llff", 0, exclude=["view005"]).to_json()
    broken["excluded"] = [5, 6]
    with pytest.raises(InputError, match="disjoint"):
        Split.from_json(broken)


@functools.lru_cache(maxsize=None)
def large_split(protocol: str, n: int) -> Split:
    return make_split(ring_cameras(n), protocol, 0)


@pytest.mark.parametrize("protocol,n", [("unstructured", 400), ("llff", 800)])
@pytest.mark.parametrize("per_group", [1, 2, 5, 32])
def test_the_views_scored_during_training_are_a_few_per_group_evenly_spaced_with_j_star(protocol, n, per_group):
    """A capture that holds out hundreds of views scores at most ``per_group`` of each group on
    training's cadence: evenly spaced over the group, j* among them, a consistent split."""
    split = large_split(protocol, n)
    thinned = split.scored_during_training(per_group)
    assert thinned.problem() is None and thinned.train == split.train
    for group, full in (("scarce_test", split.scarce_test), ("covered_test", split.covered_test)):
        kept = getattr(thinned, group)
        assert set(kept) <= set(full) and len(kept) == min(len(full), per_group)
        if len(kept) >= 2 and split.target_view not in full:
            assert kept[0] == full[0] and kept[-1] == full[-1]          # the ends of the group
            gaps = np.diff([full.index(view) for view in kept])
            assert gaps.max() - gaps.min() <= 1                         # evenly spaced
    if split.target_view is not None:
        assert split.target_view in thinned.scarce_test
    assert sorted(thinned.test) == sorted(thinned.scarce_test + thinned.covered_test)
    assert set(split.test) - set(thinned.test) <= set(thinned.excluded)


def test_a_split_with_few_held_out_views_is_scored_whole():
    split = make_split(ring_cameras(40), "unstructured", 0)
    assert split.scored_during_training(len(split.test)) is split
