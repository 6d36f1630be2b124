"""Which views stage II repairs: flagged views, a named view, or the split's j*.

Targets are poses only (no photo is used): a flag is the viewer's camera in the scene's
normalised frame (docs/viewer.md), a named view is a scene camera (held-out views allowed,
their photos stay unseen), j* is the unstructured protocol's target view.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..camera import Camera, camera_from_json_dict, pose_distance
from ..errors import InputError
from ..io.flags import read_flag_cameras

@dataclass(frozen=True)
class Target:
    name: str
    camera: Camera          # normalised frame, training resolution
    origin: str             # "flag" | "view" | "j*"


def at_training_resolution(camera: Camera, train_cameras: Sequence[Camera]) -> Camera:
    """A flag made in a viewer window of any size, rescaled (same field of view and aspect) so
    its width is the training photos' median width: generation and rendering then cost what
    a training view costs."""
    width = float(np.median([c.width for c in train_cameras]))
    if width <= 0 or camera.width <= 0:
        raise InputError(f"{camera.name}: camera has no pixels")
    return camera.scaled(camera.width / width)


def flag_targets(flags_file: Path, train_cameras: Sequence[Camera]) -> list[Target]:
    cameras = read_flag_cameras(flags_file)
    if not cameras:
        raise InputError(f"{flags_file}: no flagged views in the file")
    return [Target(c.name, at_training_resolution(c, train_cameras), "flag") for c in cameras]


def named_target(scene, name: str) -> Target:
    matches = [i for i, c in enumerate(scene.cameras) if c.name == name or Path(c.name).stem == name]
    if not matches:
        raise InputError(f"--target-view {name!r}: no such view in {scene.root} "
                         f"(views are named like {scene.cameras[0].name!r})")
    return Target(scene.cameras[matches[0]].name, scene.cameras[matches[0]], "view")


def split_targets(split, scene, rounds: int) -> list[Target]:
    """j* for one round; with more rounds the other scarce held-out views follow, nearest first
    (each round gets new targets in the same badly observed region)."""
    if split.target_view is None:
        raise InputError(f"the run's split (protocol {split.protocol!r}) has no target view j*: "
                         "give --targets FLAGS.json or --target-view NAME")
    target = scene.cameras[split.target_view]
    others = sorted((i for i in split.scarce_test if i != split.target_view),
                    key=lambda i: (pose_distance(target.world_to_camera, scene.cameras[i].world_to_camera), i))
    chosen = [split.target_view] + (others[:max(rounds - 1, 0)] if rounds > 1 else [])
    return [Target(scene.cameras[i].name, scene.cameras[i], "j*" if i == split.target_view else "view")
            for i in chosen]


def round_targets(targets: Sequence[Target], rounds: int) -> list[list[Target]]:
    """Targets per round: dealt round-robin when there are at least as many as rounds, else
    every round repairs all of them again (from the previous round's Gaussians)."""
    if not targets:
        raise InputError("no target views")
    if len(targets) >= rounds:
        return [list(targets[r::rounds]) for r in range(rounds)]
    return [list(targets) for _ in range(rounds)]


def targets_to_json(targets: Sequence[Target]) -> list[dict]:
    """What a bootstrap repairs, as RUN2/bootstrap/targets.json holds it (so --resume needs no flags)."""
    return [{"name": t.name, "origin": t.origin, "camera": t.camera.to_json_dict()} for t in targets]


def targets_from_json(data, source: str) -> list[Target]:
    """The inverse of :func:`targets_to_json`; InputError naming ``source`` when malformed."""
    if not isinstance(data, list) or not data:
        raise InputError(f"{source}: expected a non-empty list of targets")
    targets = []
    for number, item in enumerate(data):
        if not isinstance(item, dict) or not isinstance(item.get("camera"), dict):
            raise InputError(f"{source}: target {number} is not an object with a camera")
        camera = camera_from_json_dict(item["camera"], f"{source} target {number}")
        targets.append(Target(str(item.get("name", camera.name)), camera, str(item.get("origin", "flag"))))
    return targets
