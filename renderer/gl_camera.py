"""The one conversion from an OpenCV :class:`~inceptiongs.camera.Camera` to GL matrices.

The splat shaders project in pixels with the OpenCV pose and intrinsics directly (that is
what the torch rasterizer does), so the only GL-specific part is the mapping of pixel
coordinates to clip space; :func:`gl_view_projection` gives the classic view/projection
pair for everything else the app draws (frustums, gizmos) so it lines up with the splats.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from inceptiongs.camera import Camera

# OpenCV camera axes (x right, y down, z forward) -> OpenGL eye axes (x right, y up, z back).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class ShaderCamera:
    """Camera uniforms for the splat shaders, relative to an ``anchor`` point.

    Means are uploaded minus the anchor (computed in float64 on the CPU), and the camera is
    expressed in the same shifted frame, so a scene 1e6 units from the origin projects with
    the precision of one next to it. rotation: [3, 3] world->camera; translation: [3] so that
    t = rotation @ (mean - anchor) + translation; center: [3] camera centre minus anchor.
    """

    rotation: np.ndarray
    translation: np.ndarray
    center: np.ndarray
    intrinsics: tuple[float, float, float, float]
    size: tuple[int, int]


def shader_camera(camera: Camera, anchor: np.ndarray) -> ShaderCamera:
    """camera: the OpenCV camera; anchor: [3] float64 point the uploaded means are relative to."""
    rotation = camera.world_to_camera[:3, :3]
    anchor = np.asarray(anchor, np.float64)
    translation = rotation @ anchor + camera.world_to_camera[:3, 3]
    return ShaderCamera(rotation, translation, camera.center - anchor,
                        (camera.fx, camera.fy, camera.cx, camera.cy), (camera.width, camera.height))


def pixel_to_ndc_scale(width: int, height: int, flip_y: bool) -> tuple[float, float, float, float]:
    """(sx, sy, ox, oy) with ndc = pixel * (sx, sy) + (ox, oy).

    flip_y False: pixel row 0 lands on framebuffer row 0 (GL's bottom row), so a read-back
    has row 0 = image top without a numpy flip. flip_y True: upright in a window.
    """
    sx, ox = 2.0 / width, -1.0
    if flip_y:
        return sx, -2.0 / height, ox, 1.0
    return sx, 2.0 / height, ox, -1.0


def gl_view_projection(camera: Camera, near: float, far: float) -> tuple[np.ndarray, np.ndarray]:
    """(view [4, 4], projection [4, 4]) float32, column vectors, GL eye space and clip space.

    The projection reproduces the pinhole fx, fy, cx, cy exactly (off-centre principal point
    included), with the image top at NDC y = +1, i.e. upright in a window.
    """
    if not 0.0 < near < far:
        raise ValueError(f"gl_view_projection: need 0 < near < far, got {near}, {far}")
    view = _CV_TO_GL @ camera.world_to_camera
    w, h = camera.width, camera.height
    projection = np.zeros((4, 4))
    projection[0, 0] = 2.0 * camera.fx / w
    projection[0, 2] = 1.0 - 2.0 * camera.cx / w
    projection[1, 1] = 2.0 * camera.fy / h
    projection[1, 2] = 2.0 * camera.cy / h - 1.0
    projection[2, 2] = -(far + near) / (far - near)
    projection[2, 3] = -2.0 * far * near / (far - near)
    projection[3, 2] = -1.0
    return view.astype(np.float32), projection.astype(np.float32)
