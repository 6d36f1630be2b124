"""Shared helpers for the torch rasterizer tests: small scenes and an independent
brute-force float64 renderer that loops over pixels and Gaussians one at a time.

The brute force shares no code with inceptiongs.rasterizer.projection/composite/sh: it evaluates every
Gaussian at every pixel (no tiles, no footprint boxes, no culling except the near/far rule),
so it also checks that binning and footprints never drop a contribution.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from inceptiongs import constants as K
from inceptiongs.camera import Camera, look_at, quat_to_rotation
from inceptiongs.gaussians import Gaussians


def make_camera(width=32, height=24, eye=(0.0, 0.0, -3.0), target=(0.0, 0.0, 0.0), focal=None) -> Camera:
    focal = 1.1 * width if focal is None else focal
    return Camera("test", width, height, focal, focal * 1.05, width * 0.47, height * 0.52,
                  look_at(np.array(eye), np.array(target)))


def random_gaussians(n=24, degree=1, seed=0, dtype=torch.float64, spread=1.0, log_scale=-2.0) -> Gaussians:
    """n Gaussians around the origin, mixed sizes, moderate opacities (alpha far from the cap)."""
    gen = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return Gaussians(
        means=(torch.rand(n, 3, generator=gen, dtype=torch.float64) - 0.5) * 2 * spread,
        log_scales=log_scale + 0.6 * torch.randn(n, 3, generator=gen, dtype=torch.float64),
        quats=torch.randn(n, 4, generator=gen, dtype=torch.float64),
        opacity_logits=torch.randn(n, generator=gen, dtype=torch.float64),
        sh=0.4 * torch.randn(n, k, 3, generator=gen, dtype=torch.float64),
    ).to(dtype=dtype)


def _sh_colour(coeffs: np.ndarray, d: np.ndarray, degree: int) -> np.ndarray:
    """coeffs [K, 3], unit direction d [3] -> colour [3], written out term by term."""
    x, y, z = d
    basis = [K.SH_C0]
    if degree >= 1:
        basis += [-K.SH_C1 * y, K.SH_C1 * z, -K.SH_C1 * x]
    if degree >= 2:
        basis += [K.SH_C2[0] * x * y, K.SH_C2[1] * y * z, K.SH_C2[2] * (2 * z * z - x * x - y * y),
                  K.SH_C2[3] * x * z, K.SH_C2[4] * (x * x - y * y)]
    if degree >= 3:
        basis += [K.SH_C3[0] * y * (3 * x * x - y * y), K.SH_C3[1] * x * y * z,
                  K.SH_C3[2] * y * (4 * z * z - x * x - y * y),
                  K.SH_C3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y),
                  K.SH_C3[4] * x * (4 * z * z - x * x - y * y), K.SH_C3[5] * z * (x * x - y * y),
                  K.SH_C3[6] * x * (x * x - 3 * y * y)]
    total = sum(b * coeffs[i] for i, b in enumerate(basis))
    return np.maximum(total + K.SH_OFFSET, 0.0)


def brute_force_render(g: Gaussians, camera: Camera, degree: int | None = None,
                       features: np.ndarray | None = None, background=(0.0, 0.0, 0.0)) -> dict[str, np.ndarray]:
    """float64 per-pixel reference of render(): rgb, alpha, depth, normal, plane_depth, features."""
    arr = {k: v.detach().to(torch.float64).numpy() for k, v in g.tensors().items()}
    degree = g.sh_degree if degree is None else degree
    rot_w, trans_w = camera.world_to_camera[:3, :3], camera.world_to_camera[:3, 3]
    centre = camera.center
    splats = []
    for i in range(len(g)):
        t = rot_w @ arr["means"][i] + trans_w
        if not K.NEAR_PLANE <= np.float32(t[2]) <= K.FAR_PLANE:  # the renderers' float32 rule
            continue
        q = arr["quats"][i]
        rot = np.eye(3) if np.linalg.norm(q) < K.QUAT_NORM_MIN else quat_to_rotation(q)
        scales = np.exp(np.clip(arr["log_scales"][i], K.LOG_SCALE_MIN, K.LOG_SCALE_MAX))
        sigma_cam = rot_w @ rot @ np.diag(scales ** 2) @ rot.T @ rot_w.T
        half_w = (K.FRUSTUM_CLAMP_MARGIN - 1) * 0.5
        rx = np.clip(t[0] / t[2], -camera.cx / camera.fx - half_w * camera.width / camera.fx,
                     (camera.width - camera.cx) / camera.fx + half_w * camera.width / camera.fx)
        ry = np.clip(t[1] / t[2], -camera.cy / camera.fy - half_w * camera.height / camera.fy,
                     (camera.height - camera.cy) / camera.fy + half_w * camera.height / camera.fy)
        jac = np.array([[camera.fx / t[2], 0, -camera.fx * rx / t[2]],
                        [0, camera.fy / t[2], -camera.fy * ry / t[2]]])
        cov = jac @ sigma_cam @ jac.T + K.DILATION_PX * np.eye(2)
        conic = np.linalg.inv(cov)
        logit = np.clip(arr["opacity_logits"][i], -K.OPACITY_LOGIT_ABS_MAX, K.OPACITY_LOGIT_ABS_MAX)
        opacity = 1.0 / (1.0 + math.exp(-logit))
        direction = arr["means"][i] - centre
        colour = _sh_colour(arr["sh"][i], direction / np.linalg.norm(direction), degree)
        normal = rot_w @ rot[:, int(np.argmin(arr["log_scales"][i]))]
        if normal @ t > 0:
            normal = -normal
        mean2d = np.array([camera.fx * t[0] / t[2] + camera.cx, camera.fy * t[1] / t[2] + camera.cy])
        feat = features[i] if features is not None else np.zeros(0)
        splats.append((t[2], i, mean2d, conic, opacity, colour, normal, normal @ t, feat))
    splats.sort(key=lambda s: (s[0], s[1]))

    h, w = camera.height, camera.width
    c_feat = 0 if features is None else features.shape[1]
    out = {name: np.zeros((h, w, c)) for name, c in
           [("rgb", 3), ("alpha", 1), ("depth", 1), ("normal", 3), ("plane_depth", 1), ("features", c_feat)]}
    kinv = np.linalg.inv(camera.intrinsics)
    for row in range(h):
        for col in range(w):
            p = np.array([col + 0.5, row + 0.5])
            trans = 1.0
            rgb, depth, normal, offset = np.zeros(3), 0.0, np.zeros(3), 0.0
            feat = np.zeros(c_feat)
            for z, _, mean2d, conic, opacity, colour, n, off, f in splats:
                d = p - mean2d
                power = 0.5 * d @ conic @ d
                if power < 0:
                    continue
                alpha = min(K.ALPHA_MAX, opacity * math.exp(-power))
                if alpha < K.ALPHA_MIN:
                    continue
                if trans * (1 - alpha) < K.TRANSMITTANCE_MIN:
                    break
                weight = trans * alpha
                rgb += weight * colour
                depth += weight * z
                normal += weight * n
                offset += weight * off
                feat += weight * f
                trans *= 1 - alpha
            a = 1 - trans
            out["rgb"][row, col] = rgb + (1 - a) * np.asarray(background)
            out["alpha"][row, col] = a
            out["depth"][row, col] = depth / a if a >= K.ALPHA_EPS else 0.0
            out["normal"][row, col] = normal
            denominator = normal @ (kinv @ np.array([col + 0.5, row + 0.5, 1.0]))
            ok = a >= K.ALPHA_EPS and denominator <= -K.ALPHA_EPS
            out["plane_depth"][row, col] = offset / denominator if ok else 0.0
            out["features"][row, col] = feat
    return out
