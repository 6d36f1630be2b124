"""The one home of the rasterization constants.

The torch rasterizer reads them from here and the GLSL shaders get them injected as
``#define`` lines by :func:`glsl_defines`, so the two renderers can never disagree on a
number that was typed twice.
"""

from __future__ import annotations

import math

# --- projection ------------------------------------------------------------------------
# Low-pass filter added to the diagonal of every 2-D covariance (pixels^2). It keeps
# sub-pixel Gaussians at least ~one pixel wide, so they cannot alias into needles.
DILATION_PX = 0.3
# A projected covariance whose determinant falls below this (pixels^4) is culled: its
# conic (the inverse) would be numerically meaningless.
DET_MIN = 1e-12
# The EWA Jacobian is evaluated at the mean clamped to the view frustum widened by this
# factor: beyond it the linearisation of the perspective divide explodes for Gaussians at
# grazing angles and near the image border.
FRUSTUM_CLAMP_MARGIN = 1.3
# Gaussians whose centre is closer than this (camera z, scene units after normalisation)
# are culled; a covariance projected from nearer than this is unbounded.
# One rule in both renderers: keep iff NEAR_PLANE <= float32(z) <= FAR_PLANE. Both planes are
# float32 numbers exactly (0.01 is not: float32(0.01) is used), so the GLSL comparison in
# float32 and the torch comparison of z rounded to float32 see the same threshold: at
# z = NEAR_PLANE and one float32 ulp either side both renderers draw or both cull.
NEAR_PLANE = 0.009999999776482582   # float32(0.01)
FAR_PLANE = 1.0e6                   # exactly representable in float32

# --- compositing -----------------------------------------------------------------------
# alpha = min(ALPHA_MAX, opacity * exp(-power)); capping below 1 keeps the transmittance
# strictly positive, so the backward pass can divide by (1 - alpha).
ALPHA_MAX = 0.99
# A Gaussian contributes to a pixel only where alpha >= ALPHA_MIN. This rule is also the
# footprint rule: the contributing region is the ellipse power <= log(opacity / ALPHA_MIN),
# so quads and tile ranges are opacity-aware and both renderers cut at the same place.
ALPHA_MIN = 1.0 / 255.0
# Front-to-back compositing stops before a Gaussian that would push the transmittance
# below this. (The GL renderer blends back to front and cannot stop early; the
# difference is bounded by this value times the colour range.)
TRANSMITTANCE_MIN = 1e-4
# Footprint half-extent in standard deviations never exceeds this (it is
# sqrt(2 * log(ALPHA_MAX / ALPHA_MIN)) ~= 3.33 for the brightest Gaussian, i.e. "3 sigma or
# more"); kept as a named bound for buffers and tests.
SIGMA_EXTENT_MAX = math.sqrt(2.0 * math.log(ALPHA_MAX / ALPHA_MIN))
# Tile edge in pixels for the tile-binned rasterizers.
TILE_SIZE = 16
# CPU compositors: up to this conic x-coefficient (1 / px^2) exp(-power) is stepped along a
# pixel row by two multiplications (power is quadratic in x, so neighbour ratios are
# geometric with factor exp(-a)); beyond, footprints are a few pixels wide and each pixel
# takes exp(). Within a footprint's span the stepped factors stay far from float64
# over/underflow, and the drift over n pixels is ~n^2 * 1e-16 relative.
RECURRENCE_CONIC_MAX = 4.0

# --- numerical guards ------------------------------------------------------------------
# Smallest quaternion norm we normalise by; below it the rotation is taken as identity.
QUAT_NORM_MIN = 1e-12
# log-scale clamp applied before exp(): exp(-30) ~ 1e-13 and exp(12) ~ 1.6e5 scene units
# keep squared scales inside float32 range.
LOG_SCALE_MIN = -30.0
LOG_SCALE_MAX = 12.0
# Clamp on opacity logits before the sigmoid (sigmoid saturates long before this anyway;
# the clamp keeps exp() in the backward pass finite).
OPACITY_LOGIT_ABS_MAX = 30.0
# Accumulated alpha below this is treated as "no surface" when normalising depth/normals.
ALPHA_EPS = 1e-6

# --- spherical harmonics (real SH, the standard 3DGS basis and sign convention) ---------
SH_MAX_DEGREE = 3
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
# Colour = SH value + SH_OFFSET, clamped at 0 (the standard 3DGS convention).
SH_OFFSET = 0.5


def sh_coeff_count(degree: int) -> int:
    """Number of SH coefficients per colour channel for a degree 0..3."""
    return (degree + 1) ** 2


def sh_degree_from_count(count: int) -> int:
    """Inverse of :func:`sh_coeff_count`; raises ValueError for counts that are not (d+1)^2."""
    for degree in range(SH_MAX_DEGREE + 1):
        if sh_coeff_count(degree) == count:
            return degree
    raise ValueError(f"{count} SH coefficients per channel is not (d+1)^2 for d in 0..3")


def glsl_defines() -> str:
    """The constants as GLSL ``#define`` lines, inserted after the ``#version`` line."""
    scalars = {
        "DILATION_PX": DILATION_PX,
        "DET_MIN": DET_MIN,
        "FRUSTUM_CLAMP_MARGIN": FRUSTUM_CLAMP_MARGIN,
        "NEAR_PLANE": NEAR_PLANE,
        "FAR_PLANE": FAR_PLANE,
        "ALPHA_MAX": ALPHA_MAX,
        "ALPHA_MIN": ALPHA_MIN,
        "TRANSMITTANCE_MIN": TRANSMITTANCE_MIN,
        "SIGMA_EXTENT_MAX": SIGMA_EXTENT_MAX,
        "QUAT_NORM_MIN": QUAT_NORM_MIN,
        "LOG_SCALE_MIN": LOG_SCALE_MIN,
        "LOG_SCALE_MAX": LOG_SCALE_MAX,
        "OPACITY_LOGIT_ABS_MAX": OPACITY_LOGIT_ABS_MAX,
        "ALPHA_EPS": ALPHA_EPS,
        "SH_C0": SH_C0,
        "SH_C1": SH_C1,
        "SH_OFFSET": SH_OFFSET,
    }
    lines = [f"#define {name} {float(value)!r}" for name, value in scalars.items()]
    lines += [f"#define SH_C2_{i} {v!r}" for i, v in enumerate(SH_C2)]
    lines += [f"#define SH_C3_{i} {v!r}" for i, v in enumerate(SH_C3)]
    lines.append(f"#define TILE_SIZE {TILE_SIZE}")
    lines.append(f"#define SH_MAX_DEGREE {SH_MAX_DEGREE}")
    # GLSL has no 'e' without a digit before it and needs float literals; repr() gives
    # e.g. 1e-12 which GLSL accepts as a float literal.
    return "\n".join(lines) + "\n"

# --- output image limits -----------------------------------------------------------------
# The one size check before any image or framebuffer is allocated (inceptiongs.io.limits):
# no side longer than this (the common GL maximum texture / renderbuffer size) ...
IMAGE_SIDE_MAX = 16384
# ... and the estimated working memory, this many bytes per pixel (float32 colour, depth,
# normal, alpha and transmittance planes with the rasterizer's per-pixel temporaries, and the
# 8-bit copy written out), must fit in the memory the system reports as available.
RENDER_BYTES_PER_PIXEL = 256

# Where a command runs (--device; inceptiongs.rasterizer.interface.resolve_device, the one device rule).
DEVICES = ("auto", "cpu", "cuda")
