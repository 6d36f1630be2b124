"""Making flags in the viewer: names, the current view, a view aimed at a clicked point, and
:class:`FlagBook`, the source's flags as the Flags panel edits them (kept in its flags.json).
The flags.json format itself is the library's (:mod:`inceptiongs.io.flags`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from inceptiongs.camera import Camera, look_at
from inceptiongs.constants import NEAR_PLANE
from inceptiongs.errors import InputError
from inceptiongs.io import flags as flag_io
from inceptiongs.io.flags import Flag, now_iso

from .coverage_mode import SUGGESTED_FLAGS

# A right-click flag without training cameras comes this share of the way's length from the spot.
FLAG_APPROACH = 0.25
# Nearest a right-click flag stands to its spot (scene units): well past the near plane.
FLAG_MIN_DISTANCE = 10 * NEAR_PLANE


def unique_flag_name(flags: list[Flag], prefix: str = "flag") -> str:
    """The first "prefix N" (N = 1, 2, ...) not used by any flag."""
    used = {f.name for f in flags}
    n = 1
    while f"{prefix} {n}" in used:
        n += 1
    return f"{prefix} {n}"


def flag_camera(camera: Camera, name: str) -> Flag:
    """A flag for the current view as it is."""
    return Flag(name, replace(camera, name=name), now_iso())


def unproject_pixel(camera: Camera, x: float, y: float, depth: float) -> np.ndarray:
    """World point [3] at camera-space z ``depth`` on the ray through pixel (x, y), where
    (x, y) are pixel indices (the ray goes through the pixel centre, x + 0.5, y + 0.5)."""
    ray = np.array([(x + 0.5 - camera.cx) / camera.fx, (y + 0.5 - camera.cy) / camera.fy, 1.0])
    point_camera = ray * depth
    return camera.rotation.T @ (point_camera - camera.world_to_camera[:3, 3])


def flag_aimed_at(camera: Camera, target: np.ndarray, name: str) -> Flag:
    """A flag at ``camera``'s position and intrinsics, turned to look straight at ``target``
    [3] (keeping the camera's own up direction so the horizon does not jump)."""
    up = -camera.rotation[1]
    pose = look_at(camera.center, target, up)
    return Flag(name, camera.with_pose(pose, name=name), now_iso())


def approach_distance(eye: np.ndarray, target: np.ndarray, cameras: list[Camera]) -> float:
    """How far from ``target`` [3] a right-click flag stands: as near as the nearest training
    camera's centre is to it (the spot at the scale a photo shows it), never farther than the
    eye [3] already is; without cameras, FLAG_APPROACH of the eye's distance. A flag kept at the
    far eye showed the whole scene in its before/after thumbnails, not the spot clicked."""
    current = float(np.linalg.norm(np.asarray(eye, np.float64) - target))
    if cameras:
        nearest = min(float(np.linalg.norm(c.center - target)) for c in cameras)
        return max(min(current, nearest), FLAG_MIN_DISTANCE)
    return max(current * FLAG_APPROACH, FLAG_MIN_DISTANCE)


def flag_approaching(camera: Camera, target: np.ndarray, distance: float, name: str) -> Flag:
    """flag_aimed_at from the point ``distance`` from ``target`` [3] on the line to ``camera``'s
    eye: the same side, the clicked spot nearer. An eye on the target keeps its place."""
    offset = camera.center - np.asarray(target, np.float64)
    length = float(np.linalg.norm(offset))
    if length < 1e-9:   # no direction to come from: aim from where the camera is
        return flag_aimed_at(camera, target, name)
    eye = target + offset * (distance / length)
    moved = camera.with_pose(look_at(eye, target, -camera.rotation[1]))
    return flag_aimed_at(moved, target, name)


class FlagBook:
    """The open source's flags (items, saved to ``file`` after every change) and the one selected
    in the Flags panel (-1: none). ``view``: the view.View whose camera flags are made from and
    jumped to; ``status``: the status line."""

    def __init__(self, file: Path, view, status, earlier: Path | None = None) -> None:
        """``earlier``: where older viewers kept this source's flags (the cache), read when
        ``file`` does not exist yet; every change is saved to ``file``."""
        self.file, self.view, self.status = Path(file), view, status
        self.selected = -1
        source = self.file if self.file.exists() or earlier is None else Path(earlier)
        try:
            self.items: list[Flag] = flag_io.load_flags(source)
        except InputError as exc:
            self.items, status.text = [], f"flags not loaded: {exc}"

    def save(self) -> None:
        flag_io.save_flags(self.file, self.items)

    def flag_current_view(self) -> None:
        name = unique_flag_name(self.items)
        self.items.append(flag_camera(self.view.current_camera(), name))
        self.save()
        self.status.text = f"flagged the current view as {name!r}"

    def flag_view_at_pixel(self, x: float, y: float) -> None:
        point = self.view.pick_point(x, y)
        if point is None:
            self.status.text = "right-click: no surface under the cursor, nothing flagged"
            return
        name = unique_flag_name(self.items)
        camera = self.view.current_camera()
        distance = approach_distance(camera.center, point, self.view.cameras)
        self.items.append(flag_approaching(camera, point, distance, name))
        self.save()
        self.status.text = f"flagged a view aimed at {np.round(point, 3).tolist()} as {name!r}"

    def suggest(self, drawing, k: int | None = None) -> list[str]:
        """Flag the k cameras whose content the other cameras see least (the coverage mode's
        suggestion, drawing.FrameDrawer's coverage); returns the new flags' names."""
        view = self.view
        view.settings.mode, previous = "rgb", view.settings.mode
        drawing.upload_model(view)  # depth of the model itself, not of its coverage colours
        indices = drawing.coverage.suggest(view.edit.visible_arrays(), view.cameras, drawing.depth_of,
                                           SUGGESTED_FLAGS if k is None else k)
        view.settings.mode = previous
        names = []
        for index in indices:
            name = unique_flag_name(self.items, prefix="scarce")
            self.items.append(flag_camera(view.cameras[index], name))
            names.append(name)
        if names:
            self.save()
        self.status.text = (f"flagged the scarcest views: {', '.join(view.cameras[i].name for i in indices)}"
                            if names else "no cameras to suggest flags from")
        return names

    def rename(self, index: int, name: str) -> None:
        """Rename flag ``index``, unless another flag has that name (the bootstrap names its
        targets and their files after the flags: two of one name would mix up)."""
        if any(other.name == name for number, other in enumerate(self.items) if number != index):
            self.status.text = f"not renamed: a flag named {name!r} exists"
            return
        flag = self.items[index]
        self.items[index] = Flag(name, flag.camera.with_pose(flag.camera.world_to_camera, name), flag.created)
        self.save()
        self.status.text = f"renamed flag {flag.name!r} to {name!r}"

    def delete(self, index: int) -> None:
        """Delete flag ``index``; the selection stays on the flag it was on (none if deleted). The
        status says so: a message naming the deleted flag would be stale."""
        del self.items[index]
        if self.selected == index:
            self.selected = -1
        elif self.selected > index:
            self.selected -= 1  # the selected flag moved up one row
        self.save()
        left = len(self.items)
        self.status.text = f"flag deleted; {left} flag{'s' if left != 1 else ''} left"

    def jump_to(self, index: int) -> None:
        """Stand at flag ``index``'s view; the message says so while the camera stays there."""
        view = self.view
        view.look_from(self.items[index].camera)
        pose = view.nav.world_to_camera.copy()
        self.status.say(f"looking from flag {self.items[index].name!r}",
                        holds=lambda: bool(np.allclose(view.nav.world_to_camera, pose)))
