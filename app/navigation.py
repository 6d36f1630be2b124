"""Camera controllers: fly (WASD + mouse look) and orbit around a pivot. Pure numpy.

The controller keeps a camera centre and a world-to-camera rotation (OpenCV axes: x right,
y down, z forward) plus the world direction that counts as "up" for yaw, so mouse look never
rolls the horizon. :meth:`NavigationState.camera` turns the state into a :class:`Camera`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from inceptiongs.camera import Camera, look_at, pose_distance

# Pitch stops this far (radians) short of looking straight along +-up: beyond it yaw about
# `up` and pitch about the camera's x axis become the same rotation and the view would flip.
_PITCH_LIMIT_MARGIN = 0.02
# Field of view limits (degrees) of the FOV control; outside them tan() explodes or the
# image collapses to a point.
FOV_MIN_DEG = 5.0
FOV_MAX_DEG = 150.0
# Closest the orbit zoom may bring the camera to the pivot (scene units), so the distance
# stays positive and the look direction defined.
_ORBIT_MIN_DISTANCE = 1e-3


def axis_angle_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation [3, 3] by ``angle`` radians about ``axis`` [3] (Rodrigues). A zero axis
    gives the identity: there is no rotation to make."""
    axis = np.asarray(axis, np.float64)
    norm = np.linalg.norm(axis)
    if norm < 1e-12:
        return np.eye(3)
    x, y, z = axis / norm
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def orthonormalize(rotation: np.ndarray) -> np.ndarray:
    """Nearest proper rotation to ``rotation`` [3, 3] (SVD), to stop drift after many small
    incremental rotations."""
    u, _, vt = np.linalg.svd(rotation)
    out = u @ vt
    if np.linalg.det(out) < 0:
        u[:, -1] *= -1
        out = u @ vt
    return out


# The up choices the View panel offers.
UP_AXES = {"+X": (1.0, 0.0, 0.0), "-X": (-1.0, 0.0, 0.0), "+Y": (0.0, 1.0, 0.0), "-Y": (0.0, -1.0, 0.0),
           "+Z": (0.0, 0.0, 1.0), "-Z": (0.0, 0.0, -1.0)}
# A plane normal within this angle of a world axis is taken as that axis: models are mostly
# exported axis-aligned, and an exact axis keeps the horizon level.
UP_SNAP_DEG = 30.0
# Which sign of a model's up axis to take when nothing else tells: +X, -Y (COLMAP/OpenCV worlds
# have y down), +Z (z-up tools). Ties of a tilted normal go to its largest component.
UP_SIGN_PREFERENCE = np.array([1.0, -1.0, 1.0])
# A camera-derived up within this angle of a world axis is that axis (rounding of the poses;
# a rig a degree off level): the horizon is then exactly level in the world's own frame.
UP_CAMERA_SNAP_DEG = 1.0
# The cameras' right axes span a plane (the horizontal one) when their second-largest spread,
# the mean square of the component off the dominant right axis, is at least this: yaws spread
# over about +-20 deg, well above a hand-held roll of a degree or two (fern, forward-facing:
# 0.010, whose plane normal came out 3 deg off its cameras' mean up; bonsai 0.37).
RIGHT_AXES_MIN_SPREAD = 0.05


# The model's statistics (its up, centre and extent) are read from at most this many of its
# Gaussians, evenly strided: on a model of millions the full percentiles took seconds before
# the window opened, and the estimates of a plane or a box do not need every point.
STATISTICS_SAMPLE = 250_000


def statistics_sample(means: np.ndarray) -> np.ndarray:
    """``means`` [N, 3], or every ceil(N / STATISTICS_SAMPLE)-th row of it when larger."""
    step = -(-len(means) // STATISTICS_SAMPLE)
    return means if step <= 1 else means[::step]


def model_up(means: np.ndarray) -> np.ndarray:
    """World up [3] of a model without cameras: the normal of its dominant plane (the axis of
    least spread of the central 5-95 % of ``means`` [N, 3]: a ground, a table top, a flat
    object), snapped to a world axis within UP_SNAP_DEG, signed by UP_SIGN_PREFERENCE. -Y for
    fewer than 3 points (no plane to fit)."""
    means = np.asarray(statistics_sample(means), np.float64)
    if len(means) >= 3:
        lo, hi = np.percentile(means, [5, 95], axis=0)
        central = means[np.all((means >= lo) & (means <= hi), axis=1)]
        if len(central) >= 3:
            centred = central - central.mean(axis=0)
            _, vectors = np.linalg.eigh(centred.T @ centred)  # eigenvalues ascending
            normal = vectors[:, 0]
            axis = int(np.argmax(np.abs(normal)))
            if abs(normal[axis]) >= math.cos(math.radians(UP_SNAP_DEG)):
                normal = np.eye(3)[axis] * np.sign(normal[axis])
            return normal if normal @ UP_SIGN_PREFERENCE >= 0 else -normal
    return np.array([0.0, -1.0, 0.0])


def up_axis_name(up: np.ndarray) -> str | None:
    """"+Z" etc. when ``up`` is a world axis, else None."""
    for name, axis in UP_AXES.items():
        if np.allclose(up, axis, atol=1e-9):
            return name
    return None


def estimate_up(cameras: list[Camera]) -> np.ndarray:
    """World up [3] of a capture: cameras are held level (no roll), so each camera's right axis
    is horizontal and up is the direction perpendicular to all of them (the least-spread axis
    of the right axes, [3] unit), signed like the cameras' mean up (-y camera axis). The mean up
    alone leans towards whatever the cameras look down at (13 deg on the demo scene, whose
    cameras cover part of a circle). Cameras that all face one way (forward-facing, their right
    axes nearly parallel) do not fix that plane: there the mean up made perpendicular to the
    common right axis. Within UP_CAMERA_SNAP_DEG of a world axis: that axis, exactly. -y of the
    world when there are no cameras or their ups cancel out."""
    if not cameras:
        return np.array([0.0, -1.0, 0.0])
    rights = np.stack([c.rotation[0] for c in cameras]).astype(np.float64)
    mean_up = np.stack([-c.rotation[1] for c in cameras]).astype(np.float64).mean(axis=0)
    values, vectors = np.linalg.eigh(rights.T @ rights / len(rights))  # eigenvalues ascending
    if values[1] >= RIGHT_AXES_MIN_SPREAD:  # the right axes span a plane: its normal is up
        up = vectors[:, 0]
    else:
        common_right = vectors[:, 2]
        up = mean_up - (mean_up @ common_right) * common_right
    norm = float(np.linalg.norm(up))
    if norm < 1e-6 or np.linalg.norm(mean_up) < 1e-6:
        return np.array([0.0, -1.0, 0.0])  # nothing to go by (ups that cancel out)
    up = up / norm  # norm >= 1e-6: safe
    if up @ mean_up < 0:
        up = -up
    axis = int(np.argmax(np.abs(up)))
    if abs(up[axis]) >= math.cos(math.radians(UP_CAMERA_SNAP_DEG)):
        up = np.eye(3)[axis] * np.sign(up[axis])
    return up


def up_label(up: np.ndarray) -> str:
    """What the View panel's up control shows: "+Z" etc. for a world axis, else how far up is
    from the nearest one ("tilted 14 deg from +Z"), so a user sees which axis to pick."""
    name = up_axis_name(up)
    if name is not None:
        return name
    up = np.asarray(up, np.float64)
    nearest = max(UP_AXES, key=lambda axis: float(up @ UP_AXES[axis]))
    cosine = float(np.clip(up @ UP_AXES[nearest] / max(np.linalg.norm(up), 1e-12), -1.0, 1.0))
    return f"tilted {math.degrees(math.acos(cosine)):.0f} deg from {nearest}"


@dataclass
class NavigationState:
    """center: [3] camera centre; rotation: [3, 3] world-to-camera; up: [3] unit world up;
    pivot: [3] orbit centre; fov_y_deg: vertical field of view; speed: scene units / second."""

    center: np.ndarray
    rotation: np.ndarray
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))
    pivot: np.ndarray = field(default_factory=lambda: np.zeros(3))
    fov_y_deg: float = 60.0
    speed: float = 1.0

    @staticmethod
    def from_camera(camera: Camera, up: np.ndarray | None = None, speed: float = 1.0,
                    pivot: np.ndarray | None = None) -> "NavigationState":
        """Adopt ``camera``'s pose and vertical field of view."""
        fov = math.degrees(2.0 * math.atan(0.5 * camera.height / camera.fy))
        up = -camera.rotation[1] if up is None else np.asarray(up, np.float64)
        if pivot is None:
            pivot = camera.center + camera.rotation[2] * max(speed, _ORBIT_MIN_DISTANCE)
        return NavigationState(camera.center.copy(), camera.rotation.copy(), up / np.linalg.norm(up),
                               np.asarray(pivot, np.float64), float(np.clip(fov, FOV_MIN_DEG, FOV_MAX_DEG)),
                               speed)

    def copy(self) -> "NavigationState":
        return replace(self, center=self.center.copy(), rotation=self.rotation.copy(),
                       up=self.up.copy(), pivot=self.pivot.copy())

    @property
    def world_to_camera(self) -> np.ndarray:
        """[4, 4] float64."""
        out = np.eye(4)
        out[:3, :3] = self.rotation
        out[:3, 3] = -self.rotation @ self.center
        return out

    def camera(self, width: int, height: int, name: str = "viewer") -> Camera:
        """A centred pinhole camera of this pose at ``width`` x ``height`` pixels."""
        focal = 0.5 * height / math.tan(math.radians(self.fov_y_deg) * 0.5)
        return Camera(name, int(width), int(height), focal, focal, 0.5 * width, 0.5 * height,
                      self.world_to_camera)

    # --- fly -------------------------------------------------------------------------------
    def fly(self, direction: np.ndarray, seconds: float, boost: float = 1.0) -> None:
        """Move along ``direction`` [3] given in camera axes (x right, y down, z forward) for
        ``seconds`` at ``speed * boost``. The direction is normalised so diagonals are not faster."""
        direction = np.asarray(direction, np.float64)
        norm = np.linalg.norm(direction)
        if norm < 1e-12:
            return
        step = self.rotation.T @ (direction / norm) * (self.speed * boost * seconds)
        self.center = self.center + step
        self.pivot = self.pivot + step

    def pan(self, dx: float, dy: float, depth: float, focal: float) -> None:
        """Slide the camera sideways so a point at camera depth ``depth`` follows the cursor: a
        drag of (dx, dy) pixels moves it by (dx, dy) on the screen (``focal``: pixels per unit of
        depth-normalised image plane). The pivot slides with the camera."""
        step = self.rotation.T @ np.array([-dx, -dy, 0.0]) * (max(depth, _ORBIT_MIN_DISTANCE) / max(focal, 1e-6))
        self.center = self.center + step
        self.pivot = self.pivot + step

    def pivot_depth(self) -> float:
        """The pivot's camera depth (its distance along the viewing direction)."""
        return float(self.rotation[2] @ (self.pivot - self.center))

    def look(self, dx: float, dy: float, radians_per_pixel: float = 0.004) -> None:
        """Mouse look: dx > 0 turns right (yaw about world up), dy < 0 looks up (pitch)."""
        self.rotation = self._turned(self.rotation, dx * radians_per_pixel, -dy * radians_per_pixel)

    def _turned(self, rotation: np.ndarray, yaw: float, pitch: float) -> np.ndarray:
        """World-to-camera rotation after yawing right by ``yaw`` about ``up`` and pitching up by
        ``pitch`` about the camera's x axis (right x forward = up, so +pitch looks up); the pitch is limited so the forward axis never reaches +-up."""
        camera_to_world = rotation.T
        forward = camera_to_world[:, 2]
        elevation = math.asin(float(np.clip(forward @ self.up, -1.0, 1.0)))
        limit = 0.5 * math.pi - _PITCH_LIMIT_MARGIN
        pitch = float(np.clip(elevation + pitch, -limit, limit)) - elevation
        right = camera_to_world[:, 0]
        # Rotating by +a about up swings forward towards -right (up x forward = -right), so a
        # turn to the right is a rotation by -yaw.
        turned = axis_angle_matrix(self.up, -yaw) @ axis_angle_matrix(right, pitch) @ camera_to_world
        return orthonormalize(turned).T

    # --- orbit -----------------------------------------------------------------------------
    def orbit(self, dx: float, dy: float, radians_per_pixel: float = 0.005) -> None:
        """Rotate the camera about ``pivot``: dragging right swings the camera to the left
        around the pivot (the scene turns with the mouse, so the view turns right), dragging
        down lifts it (the view tilts down). The pivot keeps its place in the image."""
        old = self.rotation
        new = self._turned(old, dx * radians_per_pixel, -dy * radians_per_pixel)
        # The same world rotation that took the old orientation to the new one moves the centre.
        world_rotation = new.T @ old
        self.center = self.pivot + world_rotation @ (self.center - self.pivot)
        self.rotation = new

    def zoom(self, steps: float, factor_per_step: float = 0.85) -> None:
        """Move towards (steps > 0) or away from the pivot by a constant ratio per step."""
        offset = self.center - self.pivot
        distance = np.linalg.norm(offset)
        if distance < 1e-12:
            return
        new_distance = max(distance * factor_per_step ** steps, _ORBIT_MIN_DISTANCE)
        self.center = self.pivot + offset * (new_distance / distance)

    def set_fov(self, fov_y_deg: float) -> None:
        self.fov_y_deg = float(np.clip(fov_y_deg, FOV_MIN_DEG, FOV_MAX_DEG))

    def scale_speed(self, scroll_steps: float, factor_per_step: float = 1.2) -> None:
        self.speed = float(np.clip(self.speed * factor_per_step ** scroll_steps, 1e-4, 1e4))


def robust_bounds(means: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre [3], radius) of the model's robust extent: the median, and half the diagonal of
    the 2-98 % box (a few far floaters do not shrink the model to a dot). (0, 1) when empty."""
    if len(means) == 0:
        return np.zeros(3), 1.0
    means = statistics_sample(means)
    lo, hi = np.percentile(np.asarray(means, np.float64), [2, 98], axis=0)
    return np.median(means, axis=0), float(max(0.5 * np.linalg.norm(hi - lo), 1e-3))


# Home frames the scene, not everything in the model: the Gaussians inside the view of at least
# one training camera (the sky shell behind the scene is seen too, but it and far floaters lie
# many times farther from the scene's middle than the scene's own Gaussians), those within
# FRAME_OUTLIER_FACTOR x the median distance from the median of them. The test runs on at most
# FRAME_MAX_POINTS Gaussians and FRAME_MAX_CAMERAS cameras (evenly strided): enough for bounds.
FRAME_OUTLIER_FACTOR = 3.0
FRAME_MAX_POINTS = 50_000
FRAME_MAX_CAMERAS = 32
# With training cameras, Home looks down at the scene from this many degrees above its horizon
# (keeping the current heading): a capture's cameras stand level inside it, and a level view
# from outside shows its ground edge-on, a thin band under the sky.
FRAME_ELEVATION_DEG = 35.0


# Cameras whose viewing directions' mean is at least this long (1: all the same way) face one
# way, as a forward-facing (LLFF) capture's: the scene is in front of each of them.
FORWARD_FACING_MIN_MEAN = 0.9


def forward_facing(cameras: list[Camera]) -> bool:
    """Whether ``cameras`` all look roughly the same way (FORWARD_FACING_MIN_MEAN): fern's
    do, a capture around an object or a room's (bonsai's, the demo courtyard's) do not."""
    if not cameras:
        return False
    directions = np.stack([camera.rotation[2] for camera in cameras])   # unit rows: the mean is <= 1
    return float(np.linalg.norm(directions.mean(axis=0))) >= FORWARD_FACING_MIN_MEAN


def looked_at(means: np.ndarray, cameras: list[Camera]) -> np.ndarray:
    """[N] bool: which of ``means`` [N, 3] lie in front of and inside the image of at least one
    of ``cameras`` (all True without cameras)."""
    means = np.asarray(means, np.float64)
    seen = np.zeros(len(means), bool) if cameras else np.ones(len(means), bool)
    for camera in cameras[:: max(len(cameras) // FRAME_MAX_CAMERAS, 1)]:
        local = means @ camera.rotation.T + camera.world_to_camera[:3, 3]
        z = local[:, 2]
        in_front = z > 1e-6
        safe_z = np.where(in_front, z, 1.0)
        u = camera.fx * local[:, 0] / safe_z + camera.cx
        v = camera.fy * local[:, 1] / safe_z + camera.cy
        seen |= in_front & (u >= 0) & (u <= camera.width) & (v >= 0) & (v <= camera.height)
    return seen


# A model file without its capture (no cameras, no sparse points) may still carry stage I's sky
# shell: Gaussians all around the scene, far outside it, with next to nothing in between (the
# demo's courtyard: 7.7 % of its Gaussians 30-50 units from its middle, 0.1 % between 18 and 30,
# the scene within 18). Seen from the model's mean, the shell begins beyond the innermost empty
# band of radii [a, SHELL_GAP * a) (holding under SHELL_GAP_SHARE of the Gaussians) that has
# between SHELL_OUTSIDE[0] and SHELL_OUTSIDE[1] of them beyond it and SHELL_MIN_INSIDE within it,
# and whose outer Gaussians surround the centre: at least SHELL_MIN_FACES of the six directions of
# a cube around it hold SHELL_FACE_SHARE of them each (a street's far end holds one or two). The
# courtyard saved alone opened with its camera in the shell, the scene a small square behind
# a ring of blurred sky.
SHELL_GAP = 1.3
SHELL_GAP_SHARE = 0.002
SHELL_OUTSIDE = (0.01, 0.95)
SHELL_MIN_INSIDE = 0.05
SHELL_MIN_FACES = 4
SHELL_FACE_SHARE = 0.02
SHELL_MIN_POINTS = 100
SHELL_CANDIDATES = 64


def _surrounds(offsets: np.ndarray) -> bool:
    """Whether ``offsets`` [M, 3] from a centre point to at least SHELL_MIN_FACES cube faces."""
    axis = np.abs(offsets).argmax(axis=1)
    faces = 2 * axis + (offsets[np.arange(len(offsets)), axis] > 0)
    shares = np.bincount(faces, minlength=6) / max(len(offsets), 1)
    return int((shares >= SHELL_FACE_SHARE).sum()) >= SHELL_MIN_FACES


def model_shell(means: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(centre [3], radius): a sky shell around the model ``means`` [N, 3] is what lies farther
    than radius from centre (see SHELL_*); None when the model has none."""
    sample = np.asarray(statistics_sample(means), np.float64)
    sample = sample[np.isfinite(sample).all(axis=1)]
    if len(sample) < SHELL_MIN_POINTS:
        return None
    centre = sample.mean(axis=0)
    distance = np.linalg.norm(sample - centre, axis=1)
    ordered = np.sort(distance)
    low, high = float(np.percentile(distance, 100.0 * SHELL_MIN_INSIDE)), float(ordered[-1])
    if not (low > 0.0 and high > low * SHELL_GAP):
        return None
    count = len(ordered)
    for radius in np.geomspace(low, high / SHELL_GAP, SHELL_CANDIDATES):
        within, past = np.searchsorted(ordered, [radius, radius * SHELL_GAP])
        outside = (count - past) / count
        if (past - within) / count >= SHELL_GAP_SHARE or not SHELL_OUTSIDE[0] <= outside <= SHELL_OUTSIDE[1]:
            continue
        if within / count >= SHELL_MIN_INSIDE and _surrounds(sample[distance >= radius * SHELL_GAP] - centre):
            return centre, float(radius * math.sqrt(SHELL_GAP))
    return None


def inside_shell(means: np.ndarray, cameras: list[Camera], points: np.ndarray | None) -> np.ndarray:
    """[N] bool: which of ``means`` [N, 3] lie inside the sky shell stage I puts around a capture
    (sky.shell_geometry: a sphere around the cameras' centroid at SKY_RADIUS_FACTOR times the far
    extent of the scene's sparse ``points`` [P, 3] and the cameras), closer than the fraction of
    its radius that sky.in_background calls background. Without cameras or points, the shell is
    one found in the model itself (model_shell); all True when there is none."""
    import torch  # noqa: PLC0415 (torch: only here)

    from inceptiongs.train.sky import in_background, shell_geometry  # noqa: PLC0415

    if not len(cameras) or points is None or len(points) == 0:
        found = model_shell(means)
        if found is None:
            return np.ones(len(means), bool)
        return np.linalg.norm(np.asarray(means, np.float64) - found[0], axis=1) <= found[1]
    centre, radius = shell_geometry(list(cameras), points)
    sphere = torch.tensor([*centre, radius], dtype=torch.float64)
    return ~in_background(torch.from_numpy(np.asarray(means, np.float64)), sphere).numpy()


def scene_of_interest(means: np.ndarray, cameras: list[Camera], points: np.ndarray | None = None) -> np.ndarray:
    """The Gaussians [M, 3] Home frames, out of ``means`` [N, 3] (a strided sample of at most
    FRAME_MAX_POINTS): those the cameras look at (looked_at), far outliers and the sky shell
    left out (FRAME_OUTLIER_FACTOR). With the scene's sparse ``points`` [P, 3] the shell is left
    out first by where stage I puts it (inside_shell): on the statuette most Gaussians are
    shell, their median lay on it, and Home framed the shell with the statuette a dot inside.
    All of the sample when nothing would be left."""
    means = np.asarray(means, np.float64)
    means = means[:: max(len(means) // FRAME_MAX_POINTS, 1)]
    inside = means[inside_shell(means, cameras, points)]
    if len(inside) >= 3:
        means = inside
    seen = means[looked_at(means, cameras)]
    if len(seen) < 3:
        seen = means
    if len(seen) < 3:
        return seen
    distance = np.linalg.norm(seen - np.median(seen, axis=0), axis=1)
    near = seen[distance <= FRAME_OUTLIER_FACTOR * max(float(np.median(distance)), 1e-9)]
    return near if len(near) >= 3 else seen


def sphere_fit_distance(radius: float, fov_y_deg: float, width: float, height: float) -> float:
    """How far from its centre a camera of ``fov_y_deg`` stands for a sphere of ``radius`` to
    touch the sides of a ``width`` x ``height`` view (the narrower pair of them)."""
    focal = 0.5 * height / math.tan(math.radians(fov_y_deg) * 0.5)
    half_y = math.radians(fov_y_deg) * 0.5
    half_x = math.atan(0.5 * width / focal)
    return radius / math.sin(min(half_x, half_y))


def framed(nav: NavigationState, means: np.ndarray, width: int, height: int, covered_left: float = 0.0,
           cameras: list[Camera] = (), points: np.ndarray | None = None) -> NavigationState:
    """``nav`` moved back along its viewing direction until the scene's robust bounds (the
    Gaussians of scene_of_interest; ``points``: the scene's sparse points) fit the part of the
    ``width`` x ``height`` image right of ``covered_left`` pixels (the panel over the window's
    left), centred there; the pivot at the scene's centre."""
    center, radius = robust_bounds(scene_of_interest(means, list(cameras), points))
    rotation = looking_down(nav.rotation, nav.up, FRAME_ELEVATION_DEG) if len(cameras) else nav.rotation
    covered_left = float(np.clip(covered_left, 0.0, 0.6 * width))  # a panel over most of it: frame anyway
    focal = 0.5 * height / math.tan(math.radians(nav.fov_y_deg) * 0.5)
    distance = sphere_fit_distance(radius, nav.fov_y_deg, width - covered_left, height)
    # The centre shows at the middle of the free part: the camera slides left of it by the
    # middle's offset from the image centre at that distance.
    offset_px = 0.5 * covered_left
    eye = center - rotation[2] * distance - rotation[0] * (offset_px / focal * distance)
    return NavigationState(eye, rotation.copy(), nav.up.copy(), center, nav.fov_y_deg,
                           speed=max(radius * 0.6, 1e-3))


def looking_down(rotation: np.ndarray, up: np.ndarray, elevation_deg: float) -> np.ndarray:
    """World-to-camera rotation [3, 3] with the heading of ``rotation`` that looks down
    ``elevation_deg`` below the horizon of ``up`` [3], level (no roll)."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    forward = rotation[2] - (rotation[2] @ up) * up
    if np.linalg.norm(forward) < 1e-6:  # looking straight up or down: the image's up is the heading
        forward = -rotation[1] - (-rotation[1] @ up) * up
    forward /= np.linalg.norm(forward)
    angle = math.radians(elevation_deg)
    forward = math.cos(angle) * forward - math.sin(angle) * up
    return look_at(np.zeros(3), forward, up)[:3, :3]


def leveled(nav: NavigationState, up: np.ndarray) -> NavigationState:
    """``nav`` with a new world ``up``: the same centre and (as nearly as it can be) viewing
    direction, the horizon level for ``up``."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    forward = nav.rotation[2]
    if abs(forward @ up) > 0.999:
        # Looking along the new up: tilt towards the image's own up (perpendicular to forward,
        # so the sum cannot vanish), ~73 degrees from up, so look_at has a horizon to level.
        forward = 0.3 * forward - nav.rotation[1]
    pose = look_at(nav.center, nav.center + forward, up)
    return replace(nav, rotation=pose[:3, :3], up=up)


def default_view(means: np.ndarray, width: int, height: int, fov_y_deg: float = 60.0,
                 up: np.ndarray | None = None) -> NavigationState:
    """A view of a point set without cameras: looking at the median of ``means`` [N, 3] from
    just far enough that the sphere around the robust extent (the 5-95 % box) fits the
    ``width`` x ``height`` view, as Home frames a scene (``framed``); a sky shell found in the
    model (model_shell) left out of both: the courtyard's opened with the camera in its shell."""
    up = np.array([0.0, -1.0, 0.0]) if up is None else np.asarray(up, np.float64)
    if len(means) == 0:
        center_of_interest, extent = np.zeros(3), 1.0
    else:
        means = statistics_sample(means)
        inside = means[inside_shell(means, [], None)]   # a sky shell saved with the model is not the scene
        means = inside if len(inside) >= 3 else means
        center_of_interest = np.median(means, axis=0)
        lo, hi = np.percentile(means, [5, 95], axis=0)
        extent = float(max(np.linalg.norm(hi - lo), 1e-3))
    distance = sphere_fit_distance(0.5 * extent, fov_y_deg, width, max(height, 1))
    # Look along the world axis most orthogonal to up, from the +z side like a default 3DGS view.
    forward = np.array([0.0, 0.0, 1.0])
    forward = forward - (forward @ up) * up
    if np.linalg.norm(forward) < 1e-6:
        forward = np.array([1.0, 0.0, 0.0]) - up[0] * up
    forward /= np.linalg.norm(forward)
    eye = center_of_interest - forward * distance
    pose = look_at(eye, center_of_interest, up)
    return NavigationState(eye, pose[:3, :3], up / np.linalg.norm(up), center_of_interest,
                           fov_y_deg, speed=max(extent * 0.3, 1e-3))


def opening_view(cameras: list[Camera], means: np.ndarray, up: np.ndarray, width: int, height: int,
                 covered_left: float = 0.0, saved: Camera | None = None,
                 points: np.ndarray | None = None) -> NavigationState:
    """Where a window of ``width`` x ``height`` framebuffer pixels (``covered_left`` of them hidden
    by the panel) opens on ``means`` [N, 3]: with ``cameras`` around the scene, framed on what they
    look at as Home frames it, seen from the first camera's heading (a capture's first camera may
    face away from the scene: bonsai's showed a black window); with cameras that all face one way
    (forward_facing: fern), or without a model yet, at the first camera, which looks at the scene
    as they all do; without cameras, at ``saved`` (the camera a saved edit was seen from), else
    default_view."""
    if cameras:
        first = cameras[0]
        centers = np.stack([c.center for c in cameras])
        spread = float(np.linalg.norm(centers.max(0) - centers.min(0))) if len(centers) > 1 else 1.0
        nav = NavigationState.from_camera(first, up=up, speed=max(spread * 0.5, 1e-3))
        if len(means) == 0 or forward_facing(cameras):
            return nav
        return framed(nav, means, width, height, covered_left, cameras, points)
    if saved is not None:   # a saved edit reopens where it was seen when saved
        pivot = saved.center + saved.rotation[2] * _saved_pivot_distance(saved.center, means)
        return NavigationState.from_camera(saved, up=up, speed=default_view(means, width, height).speed, pivot=pivot)
    return default_view(means, width, height, up=up)


def _saved_pivot_distance(center: np.ndarray, means: np.ndarray) -> float:
    """How far ahead of a saved camera its orbit centre lies: the distance to the model's median
    (centre [3], means [N, 3]); 1 without a model. Floored so the pivot is never at the eye."""
    if len(means) == 0:
        return 1.0
    return max(float(np.linalg.norm(np.median(statistics_sample(means), axis=0) - center)), 1e-3)


def nearest_camera_index(cameras: list[Camera], camera: Camera) -> int | None:
    """The index of the camera in ``cameras`` closest to ``camera`` (centre distance + viewing
    angle: camera.pose_distance), or None without cameras."""
    if not cameras:
        return None
    distances = [pose_distance(camera.world_to_camera, c.world_to_camera) for c in cameras]
    return int(np.argmin(distances))
