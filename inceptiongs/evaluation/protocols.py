"""Evaluation protocols: which views train and which are held out, written into the run folder
(RUN/split.json) so every method is judged on the same views.

- ``llff``: every 8th view is held out (index % 8 == 0), the usual LLFF/mip-NeRF convention.
- ``unstructured`` (the paper's): the views are clustered by farthest-point sampling over a
  distance mixing camera position and orientation; one random cluster becomes *scarce*
  (90% of it held out, its centroid view is the stage-II target view j*), and 5% of every
  other cluster is held out as *covered* test views.
- ``none``: every view trains; nothing is held out.

Rules of the unstructured protocol (decided here, documented in docs/evaluation.md):

- Distance: ``pose_distance(a, b, rotation_weight)`` = |c_a - c_b| + w * angle(R_a, R_b), with
  w = the mean distance of the camera centres from their centroid (scene units per radian),
  so that turning by one radian weighs as much as crossing the rig's radius whatever the
  scene's scale. If all centres coincide (a panorama) w = 1.
- Cluster count K = min(6, N // 2): every cluster then averages at least two views, so some
  cluster can lose views to the test set and still train. Fewer than 2 views is an error.
- Farthest-point sampling: the first centre is a seeded random view; each next centre is the
  view farthest (max over views of the min distance to the chosen centres; ties -> lowest
  index). Sampling stops early when every view coincides with a centre (duplicate poses),
  so no cluster is empty. Every view joins its nearest centre (ties -> earlier centre); a
  centre always belongs to its own cluster.
- Declared scarce views (``scarce_views``, e.g. a demo scene's thin-region cameras): they form
  the scarce cluster; the other views are clustered as above into at most K - 1 clusters.
- Scarce cluster: a seeded random choice among the clusters with at least 2 views. Its
  centroid view (the member minimising the summed distance to the other members; ties ->
  lowest index) is the target view j*. It holds out round(0.9 n) views, at least 1 (j*) and
  at most n - 1 (one view always trains); j* plus a seeded random choice of the others.
- Covered clusters: each holds out max(1, round(0.05 n)) views if it has at least 2 views,
  none if it is a single view (never leave a cluster with no training view). The "at least
  one" keeps the covered score measurable on small captures (at 5% a 4-view cluster would
  otherwise hold out nothing).
- round() is round-half-up (floor(x + 0.5)), not Python's banker's rounding.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..io.atomic import atomic_write_text
from ..camera import Camera, pose_distance
from ..errors import InputError
from ..io.paths import read_small_text

PROTOCOLS = ("llff", "unstructured", "none")
LLFF_HOLDOUT_EVERY = 8
UNSTRUCTURED_CLUSTERS = 6
SCARCE_HOLDOUT_FRACTION = 0.9
COVERED_HOLDOUT_FRACTION = 0.05


@dataclass
class Split:
    """Train/test view indices into the scene's camera list.

    train, test: sorted, disjoint, together every view not excluded. scarce_test: held-out views
    of the scarce cluster; covered_test: the other held-out views (scarce_test + covered_test =
    test). target_view: j* (held out) or None; clusters: view indices per cluster (a partition of
    the views not excluded for ``unstructured``, empty otherwise). view_names: the cameras'
    names, to check that a split file belongs to the scene it is used with. excluded: photos the
    user left out (``make_split(exclude=...)``): neither trained on nor held out.
    """

    protocol: str
    seed: int
    train: list[int]
    test: list[int]
    scarce_test: list[int] = field(default_factory=list)
    covered_test: list[int] = field(default_factory=list)
    target_view: int | None = None
    clusters: list[list[int]] = field(default_factory=list)
    view_names: list[str] = field(default_factory=list)
    excluded: list[int] = field(default_factory=list)

    @property
    def num_views(self) -> int:
        return len(self.train) + len(self.test) + len(self.excluded)

    @property
    def scarce_cluster(self) -> list[int]:
        """All views (train and test) of the scarce cluster; empty when there is none."""
        for cluster in self.clusters:
            if self.target_view in cluster:
                return list(cluster)
        return []

    def to_json(self) -> dict:
        return asdict(self)

    def save(self, path: str | Path) -> None:
        atomic_write_text(path, json.dumps(self.to_json(), indent=1) + "\n")

    @staticmethod
    def from_json(data: dict, source: str = "<split json>") -> "Split":
        try:
            split = Split(
                protocol=str(data["protocol"]), seed=int(data["seed"]),
                train=[int(i) for i in data["train"]], test=[int(i) for i in data["test"]],
                scarce_test=[int(i) for i in data.get("scarce_test", [])],
                covered_test=[int(i) for i in data.get("covered_test", [])],
                target_view=None if data.get("target_view") is None else int(data["target_view"]),
                clusters=[[int(i) for i in c] for c in data.get("clusters", [])],
                view_names=[str(n) for n in data.get("view_names", [])],
                excluded=[int(i) for i in data.get("excluded", [])],
            )
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise InputError(f"{source}: malformed split ({type(exc).__name__}: {exc})") from None
        problem = split.problem()
        if problem:
            raise InputError(f"{source}: {problem}")
        return split

    @staticmethod
    def load(path: str | Path, cameras: Sequence[Camera] | None = None) -> "Split":
        """Read a split file; with ``cameras`` also check it belongs to those views."""
        path = Path(path)
        try:
            data = json.loads(read_small_text(path, "split JSON"))
        except FileNotFoundError:
            raise InputError(f"{path}: split file does not exist") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: not a readable split JSON ({exc})") from None
        if not isinstance(data, dict):
            raise InputError(f"{path}: split JSON must be an object")
        split = Split.from_json(data, str(path))
        if cameras is not None:
            names = [camera.name for camera in cameras]
            if split.num_views != len(names) or (split.view_names and split.view_names != names):
                raise InputError(f"{path}: split was made for other views "
                                 f"({split.num_views} views, the scene has {len(names)})")
        return split

    def restricted(self, views) -> "Split":
        """The split among ``views`` only (scene indices): the same held-out views where they are
        among them, every other view excluded (a block of a larger run, inceptiongs.train.blocks)."""
        keep = set(int(i) for i in views)
        inside = lambda indices: [i for i in indices if i in keep]  # noqa: E731
        excluded = sorted(set(range(self.num_views)) - (keep & set(self.train + self.test)))
        return Split(self.protocol, self.seed, inside(self.train), inside(self.test), inside(self.scarce_test),
                     inside(self.covered_test), self.target_view if self.target_view in keep else None,
                     [kept for kept in (inside(cluster) for cluster in self.clusters) if kept],
                     list(self.view_names), excluded)

    def scored_during_training(self, per_group: int) -> "Split":
        """The split with at most ``per_group`` held-out views in each group (scarce, covered),
        evenly spaced over the group's sorted views, j* kept among the scarce ones: what training
        and the bootstrap score on their cadence (a large capture holds out hundreds of views, each
        a full render). The dropped views are neither trained on nor scored; `inceptiongs eval`
        scores every held-out view of the run's own split."""
        def thin(group: list[int]) -> list[int]:
            if len(group) <= per_group:
                return list(group)
            positions = [round(i * (len(group) - 1) / max(per_group - 1, 1)) for i in range(per_group)]
            if self.target_view in group:     # j* stays scored, in place of the pick nearest to it
                target = group.index(self.target_view)
                positions[min(range(per_group), key=lambda k: abs(positions[k] - target))] = target
            return sorted({group[position] for position in positions})

        scarce, covered = thin(self.scarce_test), thin(self.covered_test)
        if len(scarce) == len(self.scarce_test) and len(covered) == len(self.covered_test):
            return self
        test = sorted(scarce + covered)
        return Split(self.protocol, self.seed, list(self.train), test, scarce, covered, self.target_view,
                     [], list(self.view_names), sorted(set(range(self.num_views)) - set(self.train) - set(test)))

    def problem(self) -> str | None:
        """Why this split is inconsistent, or None."""
        if self.protocol not in PROTOCOLS:
            return f"unknown protocol {self.protocol!r}"
        everything = sorted(self.train + self.test + self.excluded)
        if everything != list(range(len(everything))):
            return "train, test and excluded views must be disjoint and cover 0..N-1"
        if sorted(self.scarce_test + self.covered_test) != sorted(self.test):
            return "scarce_test and covered_test must partition the test views"
        if self.target_view is not None and self.target_view not in self.test:
            return f"target view {self.target_view} is not held out"
        if self.clusters and sorted(i for c in self.clusters for i in c) != sorted(self.train + self.test):
            return "clusters must partition the views that are not excluded"
        if self.view_names and len(self.view_names) != len(everything):
            return "view_names does not match the number of views"
        return None


def round_half_up(x: float) -> int:
    return int(math.floor(x + 0.5))


def _cameras_of(scene) -> list[Camera]:
    """A Scene (anything with ``.cameras``) or a plain list of cameras."""
    return list(getattr(scene, "cameras", scene))


def pose_distance_matrix(cameras: Sequence[Camera]) -> np.ndarray:
    """[N, N] pairwise pose distances (see module doc for the rotation weight)."""
    centers = np.array([camera.center for camera in cameras], dtype=np.float64).reshape(-1, 3)
    radius = float(np.mean(np.linalg.norm(centers - centers.mean(axis=0), axis=1))) if len(centers) else 0.0
    # A rig with all centres at one point has no length scale; radians then count as units.
    rotation_weight = radius if radius > 1e-12 else 1.0
    n = len(cameras)
    distances = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            d = pose_distance(cameras[i].world_to_camera, cameras[j].world_to_camera, rotation_weight)
            distances[i, j] = distances[j, i] = d
    return distances


def farthest_point_clusters(distances: np.ndarray, count: int, rng: np.random.Generator) -> list[list[int]]:
    """Cluster N items into at most ``count`` groups around farthest-point-sampled centres.

    distances: [N, N] symmetric, zero diagonal. Returns clusters (sorted member lists) in the
    order their centres were chosen; none is empty.
    """
    n = distances.shape[0]
    centers = [int(rng.integers(n))]
    nearest = distances[centers[0]].copy()
    while len(centers) < count:
        candidate = int(np.argmax(nearest))  # argmax: ties -> lowest index
        if nearest[candidate] <= 0.0:
            break  # every view coincides with a centre: more clusters would be empty
        centers.append(candidate)
        nearest = np.minimum(nearest, distances[candidate])
    owner = np.argmin(distances[:, centers], axis=1)  # ties -> earlier centre
    owner[centers] = np.arange(len(centers))
    return [sorted(int(i) for i in np.flatnonzero(owner == k)) for k in range(len(centers))]


def centroid_view(cluster: Sequence[int], distances: np.ndarray) -> int:
    """The member minimising the summed distance to the cluster's other members."""
    members = np.asarray(cluster)
    totals = distances[np.ix_(members, members)].sum(axis=1)
    return int(members[int(np.argmin(totals))])


def _declared_clusters(cameras: list[Camera], scarce_names: Sequence[str], distances: np.ndarray,
                       rng: np.random.Generator, source: str) -> list[list[int]]:
    """Clusters with the named views as the first one (the scarce cluster) and the other views
    clustered by farthest-point sampling as usual (K - 1 clusters)."""
    index = {camera.name: i for i, camera in enumerate(cameras)}
    unknown = [name for name in scarce_names if name not in index]
    if unknown:
        raise InputError(f"{source}: scarce views {', '.join(unknown[:3])} are not views of the scene")
    scarce = sorted({index[name] for name in scarce_names})
    if len(scarce) < 2:
        raise InputError(f"{source}: a declared scarce cluster needs at least 2 views, got {len(scarce)}")
    others = [i for i in range(len(cameras)) if i not in set(scarce)]
    if len(others) < 2:
        raise InputError(f"{source}: the views outside the declared scarce cluster are too few to train on")
    count = max(1, min(UNSTRUCTURED_CLUSTERS - 1, len(others) // 2))
    sub = farthest_point_clusters(distances[np.ix_(others, others)], count, rng)
    return [scarce] + [[others[i] for i in cluster] for cluster in sub]


def _unstructured(cameras: list[Camera], seed: int, scarce_names: Sequence[str] = (),
                  source: str = "<scene>") -> Split:
    n = len(cameras)
    rng = np.random.default_rng(seed)
    distances = pose_distance_matrix(cameras)
    if scarce_names:
        clusters = _declared_clusters(cameras, scarce_names, distances, rng, source)
        scarce = 0
    else:
        clusters = farthest_point_clusters(distances, min(UNSTRUCTURED_CLUSTERS, n // 2), rng)
        eligible = [k for k, cluster in enumerate(clusters) if len(cluster) >= 2]
        scarce = eligible[int(rng.integers(len(eligible)))]  # non-empty: K <= N/2 (pigeonhole)
    scarce_test: list[int] = []
    covered_test: list[int] = []
    target = centroid_view(clusters[scarce], distances)
    for k, cluster in enumerate(clusters):
        size = len(cluster)
        if k == scarce:
            holdout = min(size - 1, max(1, round_half_up(SCARCE_HOLDOUT_FRACTION * size)))
            others = [i for i in cluster if i != target]
            chosen = rng.choice(others, size=holdout - 1, replace=False) if holdout > 1 else []
            scarce_test.extend([target, *(int(i) for i in chosen)])
        elif size >= 2:
            holdout = min(size - 1, max(1, round_half_up(COVERED_HOLDOUT_FRACTION * size)))
            covered_test.extend(int(i) for i in rng.choice(cluster, size=holdout, replace=False))
    test = sorted(scarce_test + covered_test)
    train = sorted(set(range(n)) - set(test))
    return Split("unstructured", seed, train, test, sorted(scarce_test), sorted(covered_test),
                 target, clusters, [c.name for c in cameras])


def make_split(scene, protocol: str, seed: int = 0, scarce_views: Sequence[str] = (),
               exclude: Sequence[str] = ()) -> Split:
    """Train/test split of ``scene``'s views (a Scene or a list of Camera) under ``protocol``.

    scarce_views (unstructured only): names of views that form the scarce cluster instead of a
    seeded random cluster, e.g. the views a demo scene was built to see its thin region from.
    exclude: names of photos to leave out entirely (e.g. those a run fitted poorly,
    inceptiongs.train.view_fit): the protocol splits the other views, as if these were absent,
    and the split lists them as ``excluded``; indices stay those of the whole scene.

    Raises InputError for an unknown protocol, a name to exclude the scene does not have, or too
    few views to hold any out.
    """
    cameras = _cameras_of(scene)
    names = [camera.name for camera in cameras]
    source = str(getattr(scene, "root", "<scene>"))
    if not exclude:
        return _split_views(cameras, protocol, seed, scarce_views, source)
    leave_out = set(exclude)
    unknown = sorted(leave_out - set(names))
    if unknown:
        raise InputError(f"{source}: no photo named {unknown[0]!r} to exclude"
                         + (f" (and {len(unknown) - 1} more)" if len(unknown) > 1 else ""))
    both = leave_out & set(scarce_views)
    if both:
        raise InputError(f"{source}: {sorted(both)[0]!r} is both a declared scarce view and excluded")
    kept = [i for i, name in enumerate(names) if name not in leave_out]
    inner = _split_views([cameras[i] for i in kept], protocol, seed, scarce_views, source)
    whole = lambda indices: [kept[i] for i in indices]  # noqa: E731 - the kept views' scene indices
    return Split(inner.protocol, inner.seed, whole(inner.train), whole(inner.test), whole(inner.scarce_test),
                 whole(inner.covered_test), None if inner.target_view is None else kept[inner.target_view],
                 [whole(cluster) for cluster in inner.clusters], names,
                 [i for i, name in enumerate(names) if name in leave_out])


def _split_views(cameras: list[Camera], protocol: str, seed: int, scarce_views: Sequence[str], source: str) -> Split:
    """make_split without exclusions."""
    n = len(cameras)
    names = [camera.name for camera in cameras]
    if protocol not in PROTOCOLS:
        raise InputError(f"{source}: unknown protocol {protocol!r} (choose from {', '.join(PROTOCOLS)})")
    if n == 0:
        raise InputError(f"{source}: the scene has no views")
    if scarce_views and protocol != "unstructured":
        raise InputError(f"{source}: declared scarce views need the unstructured protocol, not {protocol!r}")
    if protocol == "none":
        return Split("none", seed, list(range(n)), [], view_names=names)
    if n < 2:
        raise InputError(f"{source}: the {protocol} protocol needs at least 2 views, the scene has {n}")
    if protocol == "llff":
        test = [i for i in range(n) if i % LLFF_HOLDOUT_EVERY == 0]
        train = [i for i in range(n) if i % LLFF_HOLDOUT_EVERY != 0]
        return Split("llff", seed, train, test, [], list(test), view_names=names)
    return _unstructured(cameras, seed, scarce_views, source)
