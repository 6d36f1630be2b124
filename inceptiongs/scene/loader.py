"""One Scene type for every capture format: cameras, lazily loaded images, sparse points.

Formats are detected from the folder (COLMAP binary/text, transforms.json, LLFF). At load
the scene is normalised (recentred on the camera centres and scaled to a unit-ish extent,
so float32 stays accurate far from the origin); the transform is kept for export.
Distorted cameras are replaced by pinhole ones and their images undistorted on first use;
downscaled and undistorted images are cached in the scene's work folder.
"""

from __future__ import annotations

import errno
import hashlib
import math
import os
import stat
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from ..io.atomic import atomic_write_bytes
from ..camera import Camera
from ..constants import IMAGE_SIDE_MAX
from ..errors import InputError
from ..io.paths import link_problem, stays_inside
from ..gaussians import Gaussians
from .raw import RawScene
from .undistort import distortion_key, undistort_image, undistorted_camera

# A camera extent below this (scene units) means "all cameras at one spot" (e.g. a single
# camera): the scale then falls back to the points' extent or 1 instead of dividing by ~0.
_EXTENT_MIN = 1e-9


@dataclass(frozen=True)
class SceneNormalization:
    """x_norm = (x_orig - center) * scale. center: [3] float64, scale > 0."""

    center: np.ndarray
    scale: float

    def to_normalized(self, points: np.ndarray) -> np.ndarray:
        """points: [..., 3] original frame -> normalised frame."""
        return (np.asarray(points, np.float64) - self.center) * self.scale

    def to_original(self, points: np.ndarray) -> np.ndarray:
        """points: [..., 3] normalised frame -> original frame."""
        return np.asarray(points, np.float64) / self.scale + self.center

    def camera_to_normalized(self, camera: Camera) -> Camera:
        """Same camera in the normalised frame: camera-space coordinates scale by ``scale``
        too, so depths are in normalised units: t' = scale * (R center + t)."""
        pose = camera.world_to_camera.copy()
        pose[:3, 3] = self.scale * (pose[:3, :3] @ self.center + pose[:3, 3])
        return camera.with_pose(pose)

    def camera_to_original(self, camera: Camera) -> Camera:
        """Inverse of :meth:`camera_to_normalized`: t = t' / scale - R center."""
        pose = camera.world_to_camera.copy()
        pose[:3, 3] = pose[:3, 3] / self.scale - pose[:3, :3] @ self.center
        return camera.with_pose(pose)

    def _transform_gaussians(self, gaussians: Gaussians, scale: float, before: np.ndarray,
                             after: np.ndarray) -> Gaussians:
        import torch

        def tensor(values: np.ndarray):
            return torch.as_tensor(values, dtype=gaussians.dtype, device=gaussians.device)

        means = (gaussians.means - tensor(before)) * scale + tensor(after)
        log_scales = gaussians.log_scales + math.log(scale)
        return replace(gaussians, means=means, log_scales=log_scales)

    def gaussians_to_original(self, gaussians: Gaussians) -> Gaussians:
        """Means and log scales to the original frame; rotations, opacity and SH unchanged."""
        return self._transform_gaussians(gaussians, 1.0 / self.scale, np.zeros(3), self.center)

    def gaussians_to_normalized(self, gaussians: Gaussians) -> Gaussians:
        return self._transform_gaussians(gaussians, self.scale, self.center, np.zeros(3))


def compute_normalization(centers: np.ndarray, points: np.ndarray | None = None) -> SceneNormalization:
    """centers: [C, 3] camera centres; points: [P, 3] optional fallback for the extent.

    Centre = mean of the camera centres; scale = 1 / max distance of a camera to it.
    """
    center = centers.mean(axis=0)
    extent = float(np.max(np.linalg.norm(centers - center, axis=1)))
    if extent < _EXTENT_MIN and points is not None and len(points):
        extent = float(np.max(np.linalg.norm(points - center, axis=1)))
    if extent < _EXTENT_MIN:
        extent = 1.0
    return SceneNormalization(center, 1.0 / extent)


# The folder older versions kept caches, runs and flags in, inside the scene. It is never
# written any more; caches found there are still read (read-only) so old runs stay fast.
LEGACY_WORK_DIR_NAME = ".inceptiongs"


def description_files(root: Path) -> list[Path]:
    """The files that describe the scene at ``root`` (cameras, poses, points), whose content
    keys its cache folder."""
    from .colmap import find_model_dir
    from .transforms import find_transforms

    root = Path(root)
    if root.is_file():
        return [root]
    files = []
    found = find_model_dir(root)
    if found is not None:
        files += [p for p in found[0].iterdir() if p.is_file() and p.suffix in (".bin", ".txt")]
    transforms = find_transforms(root)
    if transforms is not None:
        files.append(transforms)
    if (root / "poses_bounds.npy").is_file():
        files.append(root / "poses_bounds.npy")
    return files


@dataclass
class Scene:
    """cameras are in the normalised frame with intrinsics at the chosen downscale."""

    root: Path
    format: str
    cameras: list[Camera]
    image_paths: list[Path]
    points: np.ndarray
    point_colors: np.ndarray | None
    normalization: SceneNormalization
    camera_models: list[str]
    warnings: list[str]
    # Per camera: the camera of the image file as stored (original intrinsics, file size) and
    # its OpenCV distortion or None; load_image maps the file to ``cameras[i]`` through them.
    source_cameras: list[Camera] = field(default_factory=list, repr=False)
    distortion: list = field(default_factory=list, repr=False)
    _work_dir: Path | None = field(default=None, repr=False, compare=False)

    @property
    def work_dir(self) -> Path:
        """This scene's folder in the cache directory (inceptiongs.io.cache: keyed by the
        scene's path and content), created on demand; never inside the scene folder.
        OutputError (one line) when it cannot be created."""
        if self._work_dir is None:
            from ..io.atomic import ensure_dir
            from ..io.cache import scene_cache_dir

            self._work_dir = ensure_dir(scene_cache_dir(self.root, description_files(self.root)))
        return self._work_dir

    @property
    def legacy_work_dir(self) -> Path:
        """SCENE/.inceptiongs, where older versions wrote; only ever read."""
        return self.root / LEGACY_WORK_DIR_NAME

    def camera_by_name(self, name: str) -> Camera:
        for camera in self.cameras:
            if camera.name == name:
                return camera
        stems = [c for c in self.cameras if Path(c.name).stem == name]
        if len(stems) == 1:
            return stems[0]
        raise InputError(f"{self.root}: no camera named {name!r} in this scene")

    def load_image(self, index: int) -> np.ndarray:
        """Image of camera ``index``: [H, W, 3] float32 in [0, 1] at the scene's downscale,
        undistorted when the camera was. Resized/undistorted images are cached."""
        return float_rgb(self.load_stored_rgb(index))

    def resolution_key(self, index: int) -> str:
        """Names the training resolution (and lens model) photo ``index`` is prepared at:
        "WxH", with a hash of the lens when the camera is undistorted."""
        camera, source, dist = self.cameras[index], self.source_cameras[index], self.distortion[index]
        key = f"{camera.width}x{camera.height}"
        if dist is not None:
            # Undistorted images depend on the lens model too: a re-calibrated model must not
            # reuse images undistorted with the old one.
            lens = np.array([source.fx, source.fy, source.cx, source.cy], "<f8").tobytes() + distortion_key(dist)
            key += "-" + hashlib.sha1(lens).hexdigest()[:10]
        return key

    def load_stored_rgb(self, index: int) -> np.ndarray:
        """Image of camera ``index`` as :meth:`load_image` converts it: [H, W, 3] RGB in the
        file's own type (uint8, uint16 or float32), contiguous; float_rgb() of it is load_image."""
        camera, source = self.cameras[index], self.source_cameras[index]
        dist = self.distortion[index]
        path = self.image_paths[index]
        if dist is None and (camera.width, camera.height) == (source.width, source.height):
            return stored_rgb(_read_image(path), path)
        cache_name = camera.name.replace("/", "__").replace("\\", "__")
        key = self.resolution_key(index)
        relative = Path("images") / key / f"{cache_name}.png"
        try:
            cache = self.work_dir / relative
        except InputError:  # no usable cache directory: work without one
            cache = None
        legacy = self.legacy_work_dir / relative
        # Older versions' cache inside the scene is read only where it really lies inside the scene:
        # a symlink planted there would make every command read (and `eval` copy) any image on the disk.
        for cached in (cache, legacy if stays_inside(legacy, self.root) else None):
            if cached is not None and cached.is_file() and cached.stat().st_mtime >= path.stat().st_mtime:
                return stored_rgb(_read_image(cached), cached)
        image = _read_image(path)
        if image.shape[1] != source.width or image.shape[0] != source.height:
            raise InputError(f"{path}: image is {image.shape[1]}x{image.shape[0]} but its camera "
                             f"expects {source.width}x{source.height}")
        if dist is not None:
            pinhole = undistorted_camera(source, dist)
            image = undistort_image(image, source, dist, pinhole)
        if (camera.width, camera.height) != (image.shape[1], image.shape[0]):
            image = cv2.resize(image, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
        ok, encoded = cv2.imencode(".png", image)
        if ok and cache is not None:
            try:
                atomic_write_bytes(cache, encoded.tobytes())
            except InputError:  # a full or read-only cache only costs speed
                pass
        return stored_rgb(image, path)


def image_file_problem(path: Path) -> str | None:
    """None when ``path`` is a regular file; else what keeps it from being an image file, in
    words: missing, a symlink loop (the file or a folder above it), a name too long for the file
    system, a FIFO, a device or a folder."""
    problem = link_problem(path)
    if problem is not None:
        return problem
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "symlink loop on the way to the image file"
        if exc.errno == errno.ENAMETOOLONG:
            return "image name is too long for the file system"
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            return "image file does not exist"
        return f"cannot read image file ({exc.strerror or exc})"
    if stat.S_ISREG(mode):
        return None
    kind = "a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "a device or socket"
    return f"image path is {kind}, not a regular file"


def _read_image(path: Path) -> np.ndarray:
    """BGR(A) image as stored (uint8 or uint16), or InputError."""
    problem = image_file_problem(path)
    if problem is not None:
        raise InputError(f"{path}: {problem}")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: cannot decode image (corrupt or unsupported format)")
    if image.ndim == 2:
        image = image[:, :, None]
    return image


def stored_rgb(image: np.ndarray, path: Path) -> np.ndarray:
    """BGR(A)/grey as stored -> RGB [H, W, 3] in the stored type, contiguous (alpha dropped)."""
    if image.ndim == 2:
        image = image[:, :, None]
    channels = image.shape[2]
    if channels == 1:
        rgb = np.repeat(image, 3, axis=2)
    elif channels in (3, 4):
        rgb = image[:, :, 2::-1]
    else:
        raise InputError(f"{path}: image has {channels} channels, expected 1, 3 or 4")
    return np.ascontiguousarray(rgb)


def float_rgb(rgb: np.ndarray) -> np.ndarray:
    """RGB [H, W, 3] uint8|uint16|float -> float32 in [0, 1]."""
    if rgb.dtype == np.uint8:
        return rgb.astype(np.float32) / 255.0
    if rgb.dtype == np.uint16:
        return rgb.astype(np.float32) / 65535.0
    return np.clip(rgb.astype(np.float32), 0.0, 1.0)


def _image_size(path: Path) -> tuple[int, int] | str:
    """(width, height) from the file header, or what keeps it from being read, in words."""
    from PIL import Image

    try:
        with Image.open(path) as image:
            return image.size
    except Image.DecompressionBombError as exc:
        return (f"image is too large ({exc}); at most {2 * Image.MAX_IMAGE_PIXELS} pixels "
                f"(and {IMAGE_SIDE_MAX} a side) are read")
    except Exception:  # PIL raises many types for unreadable files; treat all as "unreadable"
        return "cannot read image header (corrupt or unsupported format)"


def detect_format(root: Path) -> str:
    """The format name of the scene at ``root`` (a folder, or a transforms.json file)."""
    from .colmap import find_model_dir
    from .transforms import find_transforms

    if root.is_file():
        if root.suffix == ".json":
            return "transforms"
        raise InputError(f"{root}: not a scene folder (expected a folder or a transforms.json)")
    found = find_model_dir(root)
    if found is not None:
        return found[1]
    if find_transforms(root) is not None:
        return "transforms"
    if (root / "poses_bounds.npy").is_file():
        return "llff"
    for name in ("bundle.out", "bundle/bundle.out"):
        if (root / name).is_file():
            raise InputError(f"{root / name}: Bundler scenes are not supported (convert them to COLMAP, "
                             "e.g. with colmap model_converter, or to transforms.json)")
    raise InputError(f"{root}: no recognisable scene (expected sparse/0/, sparse/, transforms.json "
                     "or poses_bounds.npy)")


def read_raw_scene(path: str | Path, downscale: float = 1) -> RawScene:
    """Read the scene files at ``path`` without normalising or resizing."""
    root = Path(path)
    if not root.exists():
        raise InputError(f"{root}: path does not exist")
    fmt = detect_format(root)
    if fmt.startswith("colmap"):
        from .colmap import load_colmap
        return load_colmap(root)
    if fmt == "transforms":
        from .transforms import load_transforms
        return load_transforms(root)
    from .llff import load_llff
    return load_llff(root, downscale)


def _check_images(raw: RawScene, require_images: bool) -> list[str]:
    """Missing/unreadable/mis-sized images and duplicate names: InputError or warnings."""
    problems: list[str] = []
    seen: set[str] = set()
    for camera, path in zip(raw.cameras, raw.image_paths):
        if camera.name in seen:
            problems.append(f"{path}: duplicate image name {camera.name} (more than one camera uses it)")
        seen.add(camera.name)
        problem = image_file_problem(path)
        if problem is not None:
            problems.append(f"{path}: {problem}")
            continue
        size = _image_size(path)
        if isinstance(size, str):
            problems.append(f"{path}: {size}")
        elif size != (camera.width, camera.height):
            problems.append(f"{path}: image is {size[0]}x{size[1]} but its camera expects "
                            f"{camera.width}x{camera.height}")
    if problems and require_images:
        extra = f" (and {len(problems) - 1} more problem(s))" if len(problems) > 1 else ""
        raise InputError(problems[0] + extra)
    return problems


# The smallest image side the losses and metrics work on (the SSIM window is 11 pixels).
MIN_IMAGE_SIDE = 11


def load_scene(path: str | Path, downscale: int = 1, max_width: int | None = None,
               require_images: bool = True) -> Scene:
    """Load any supported scene. ``downscale`` divides the image size (1, 2, 4, 8, ...);
    ``max_width`` additionally caps the widest image. With ``require_images=False`` missing
    or mismatched images become warnings instead of errors (for ``inceptiongs info``)."""
    if int(downscale) != downscale or downscale < 1:
        raise InputError(f"{path}: downscale must be a positive integer, got {downscale}")
    if max_width is not None and max_width < 1:
        raise InputError(f"{path}: max_width must be positive, got {max_width}")
    raw = read_raw_scene(path, downscale)
    warnings = list(raw.warnings) + _check_images(raw, require_images)

    # Distorted cameras become pinhole ones; their images are undistorted in load_image.
    pinhole = [c if d is None else undistorted_camera(c, d) for c, d in zip(raw.cameras, raw.distortion)]

    factor = max(1.0, downscale / raw.source_downscale)
    if max_width is not None:
        factor = max(factor, max(c.width for c in pinhole) / max_width)
    centers = np.array([c.center for c in raw.cameras])
    normalization = compute_normalization(centers, raw.points)
    cameras = [normalization.camera_to_normalized(c.scaled(factor) if factor != 1 else c) for c in pinhole]
    small = next((c for c in cameras if min(c.width, c.height) < MIN_IMAGE_SIDE), None)
    if small is not None:
        problem = (f"{path}: downscale {downscale} leaves image {small.name} at {small.width}x{small.height} "
                   f"pixels; training and evaluation need at least {MIN_IMAGE_SIDE} a side")
        if require_images:
            raise InputError(problem)
        warnings.append(problem)
    points = normalization.to_normalized(raw.points) if len(raw.points) else np.zeros((0, 3))
    return Scene(root=raw.root, format=raw.format, cameras=cameras, image_paths=list(raw.image_paths),
                 points=points, point_colors=raw.point_colors, normalization=normalization,
                 camera_models=list(raw.camera_models), warnings=warnings,
                 source_cameras=list(raw.cameras), distortion=list(raw.distortion))


def add_scene_arguments(parser) -> None:
    """The scene-resolution options every command that loads a scene shares."""
    parser.add_argument("--downscale", type=int, choices=(1, 2, 4, 8), default=1,
                        help="load images this many times smaller (default 1)")
    parser.add_argument("--max-width", type=int, default=None, metavar="PIXELS",
                        help="further downscale so no image is wider than this")


def load_scene_from_args(path: str | Path, args) -> Scene:
    """load_scene with the options added by :func:`add_scene_arguments`."""
    return load_scene(path, downscale=args.downscale, max_width=args.max_width)
