"""COLMAP models (binary or text, in ``sparse/0/``, ``sparse/`` or the folder itself) via pycolmap.

pycolmap trusts the counts inside the binary files, so a truncated or corrupt file can make it
fail with an unrelated message (or allocate for a garbage count). The binary files are
therefore walked once first (a cheap record-by-record size check) and the file at fault is
named in the error.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..io.limits import check_allocation
from ..io.paths import contained_path
from .undistort import Fisheye
from .raw import RawScene, check_finite_pose, check_intrinsics, finite_points

# COLMAP camera model id -> (name, number of parameters), from COLMAP's camera model table.
_MODELS = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
    4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16), 12: ("SIMPLE_DIVISION", 4), 13: ("DIVISION", 5),
    14: ("SIMPLE_FISHEYE", 3), 15: ("FISHEYE", 4), 16: ("EUCM", 6), 17: ("EQUIRECTANGULAR", 2),
}
SUPPORTED_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV",
                    "OPENCV_FISHEYE")


def find_model_dir(root: Path) -> tuple[Path, str] | None:
    """(model folder, "colmap-binary" | "colmap-text") or None if root holds no COLMAP model."""
    for folder in (root / "sparse" / "0", root / "sparse", root):
        for ext, fmt in ((".bin", "colmap-binary"), (".txt", "colmap-text")):
            if (folder / f"cameras{ext}").is_file() and (folder / f"images{ext}").is_file():
                return folder, fmt
    return None


class _Reader:
    """Bounds-checked struct reads over one file's bytes."""

    def __init__(self, path: Path):
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def read(self, fmt: str) -> tuple:
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise InputError(f"{self.path}: truncated COLMAP binary file (ends at byte {len(self.data)})")
        values = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return values

    def skip(self, count: int, item_size: int) -> None:
        if count < 0 or self.pos + count * item_size > len(self.data):
            raise InputError(f"{self.path}: truncated or corrupt COLMAP binary file "
                             f"(a record claims {count} entries past the end of the file)")
        self.pos += count * item_size

    def read_name(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise InputError(f"{self.path}: truncated COLMAP binary file (unterminated image name)")
        try:
            name = self.data[self.pos:end].decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(f"{self.path}: image name at byte {self.pos} is not UTF-8 text (corrupt file?)") from None
        self.pos = end + 1
        return name

    def finish(self) -> None:
        if self.pos != len(self.data):
            raise InputError(f"{self.path}: corrupt COLMAP binary file "
                             f"({len(self.data) - self.pos} unexpected bytes after the last record)")


# pycolmap's in-memory model takes several times the bytes of its files (ids, tracks, maps).
MODEL_MEMORY_FACTOR = 8


def check_model_file_sizes(folder: Path) -> None:
    """InputError when the model files (cameras, images, points3D; .bin or .txt) are too large
    to read into the memory available: a sparse file of a huge declared size is refused before
    it is read, not with a MemoryError."""
    total = 0
    for name in ("cameras", "images", "points3D"):
        for suffix in (".bin", ".txt"):
            path = folder / f"{name}{suffix}"
            if path.is_file():
                total += path.stat().st_size
                check_allocation(MODEL_MEMORY_FACTOR * total, str(path), f"the COLMAP model ({total} bytes)")


def check_binary_model(folder: Path) -> None:
    """Walk cameras.bin, images.bin and points3D.bin record by record; InputError naming the
    file for truncation, trailing garbage or an unknown camera model."""
    cameras = _Reader(folder / "cameras.bin")
    (count,) = cameras.read("<Q")
    for _ in range(count):
        _, model_id, _, _ = cameras.read("<iiQQ")
        if model_id not in _MODELS:
            raise InputError(f"{cameras.path}: unknown COLMAP camera model id {model_id} (corrupt file?)")
        cameras.skip(_MODELS[model_id][1], 8)
    cameras.finish()

    images = _Reader(folder / "images.bin")
    (count,) = images.read("<Q")
    for _ in range(count):
        images.read("<i7di")
        images.read_name()
        (num_points,) = images.read("<Q")
        images.skip(num_points, 24)  # x, y (double) + point3D id (int64)
    images.finish()

    points_path = folder / "points3D.bin"
    if points_path.is_file():
        points = _Reader(points_path)
        (count,) = points.read("<Q")
        for _ in range(count):
            points.read("<Q3d3Bd")
            (track,) = points.read("<Q")
            points.skip(track, 8)  # image id + point2D index (int32 each)
        points.finish()


def _distortion(model: str, params: np.ndarray):
    """OpenCV distortion coefficients for a supported COLMAP model (None for pinhole models)."""
    if model in ("SIMPLE_PINHOLE", "PINHOLE"):
        return None
    if model == "SIMPLE_RADIAL":
        return np.array([params[3], 0.0, 0.0, 0.0])
    if model == "RADIAL":
        return np.array([params[3], params[4], 0.0, 0.0])
    if model == "OPENCV":
        return np.array(params[4:8], dtype=np.float64)
    if model == "FULL_OPENCV":
        return np.array(params[4:12], dtype=np.float64)
    if model == "OPENCV_FISHEYE":  # fx, fy, cx, cy, k1, k2, k3, k4: OpenCV's fisheye model
        return Fisheye(params[4:8])
    raise AssertionError(model)


def load_colmap(root: Path) -> RawScene:
    import pycolmap  # heavy; only needed for COLMAP scenes

    found = find_model_dir(root)
    if found is None:
        raise InputError(f"{root}: no COLMAP model (cameras/images .bin or .txt) found")
    folder, fmt = found
    check_model_file_sizes(folder)
    if fmt == "colmap-binary":
        check_binary_model(folder)
    try:
        recon = pycolmap.Reconstruction(str(folder))
    except Exception as exc:  # pycolmap raises ValueError/IndexError/RuntimeError for bad files
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{folder}: cannot read COLMAP model ({message})") from None

    image_dir = root / "images"
    cameras, paths, models, distortion, warnings = [], [], [], [], []
    try:
        images = sorted(recon.images.values(), key=lambda im: im.name)
    except UnicodeDecodeError:
        raise InputError(f"{folder}: an image name in the COLMAP model is not UTF-8 text (corrupt file?)") from None
    for image in images:
        source = f"{folder} image {image.name!r}"
        if not image.has_pose:
            warnings.append(f"image {image.name} is not registered (no pose); skipped")
            continue
        cam = recon.cameras[image.camera_id]
        model = cam.model.name
        if model not in SUPPORTED_MODELS:
            raise InputError(f"{folder}: camera {cam.camera_id} uses the {model} model, which is not "
                             f"supported (supported: {', '.join(SUPPORTED_MODELS)})")
        params = np.asarray(cam.params, dtype=np.float64)
        if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
            fx = fy = params[0]
            cx, cy = params[1], params[2]
        else:
            fx, fy, cx, cy = params[:4]
        check_intrinsics(cam.width, cam.height, [fx, fy, cx, cy, *params], f"{folder} camera {cam.camera_id}")
        pose = np.eye(4)
        pose[:3, :] = image.cam_from_world().matrix()
        check_finite_pose(pose, source)
        cameras.append(Camera(image.name, int(cam.width), int(cam.height), float(fx), float(fy),
                              float(cx), float(cy), pose))
        paths.append(contained_path(image_dir, image.name, source))
        models.append(model)
        distortion.append(_distortion(model, params))
    if not cameras:
        raise InputError(f"{folder}: COLMAP model has no registered images")

    if recon.num_points3D() > 0:
        point_list = [point for _, point in sorted(recon.points3D.items())]  # by point id
        points = np.array([p.xyz for p in point_list], dtype=np.float64)
        colors = np.array([p.color for p in point_list], dtype=np.uint8)
        points, colors = finite_points(points, colors, warnings)
    else:
        points, colors = np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    return RawScene(root, fmt, cameras, paths, models, distortion, points, colors, warnings)


_MODEL_IDS = {name: model_id for model_id, (name, _) in _MODELS.items()}


def write_colmap_binary(folder: Path, cameras: list[tuple[Camera, str, list[float]]],
                        points: np.ndarray | None = None, colors: np.ndarray | None = None) -> None:
    """Write cameras.bin, images.bin and points3D.bin (COLMAP's binary layout) atomically.

    cameras: (camera, COLMAP model name, model parameters) per image, one COLMAP camera each;
    points: [P, 3] float64 with colors [P, 3] uint8 (tracks left empty: the points carry no
    observations). Used by the demo scene and by tests that need COLMAP models with known
    intrinsics and distortion.
    """
    from ..io.atomic import atomic_write_bytes
    from ..camera import rotation_to_quat

    folder = Path(folder)
    camera_bytes = [struct.pack("<Q", len(cameras))]
    image_bytes = [struct.pack("<Q", len(cameras))]
    for index, (camera, model, params) in enumerate(cameras, start=1):
        if model not in _MODEL_IDS or len(params) != _MODELS[_MODEL_IDS[model]][1]:
            raise ValueError(f"COLMAP model {model} with {len(params)} parameters")
        camera_bytes.append(struct.pack("<iiQQ", index, _MODEL_IDS[model], camera.width, camera.height))
        camera_bytes.append(struct.pack(f"<{len(params)}d", *params))
        quat = rotation_to_quat(camera.world_to_camera[:3, :3])
        image_bytes.append(struct.pack("<i7di", index, *quat, *camera.world_to_camera[:3, 3], index))
        image_bytes.append(camera.name.encode("utf-8") + b"\0")
        image_bytes.append(struct.pack("<Q", 0))
    points = np.zeros((0, 3)) if points is None else np.asarray(points, np.float64)
    colors = np.zeros((len(points), 3), np.uint8) if colors is None else np.asarray(colors, np.uint8)
    record = np.zeros(len(points), np.dtype([("id", "<u8"), ("xyz", "<f8", 3), ("rgb", "u1", 3),
                                              ("error", "<f8"), ("track", "<u8")]))
    record["id"] = np.arange(1, len(points) + 1)
    record["xyz"] = points
    record["rgb"] = colors
    atomic_write_bytes(folder / "cameras.bin", b"".join(camera_bytes))
    atomic_write_bytes(folder / "images.bin", b"".join(image_bytes))
    atomic_write_bytes(folder / "points3D.bin", struct.pack("<Q", len(points)) + record.tobytes())
