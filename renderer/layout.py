"""The packed layouts the renderer's passes share: the Gaussians as texels (pack_gaussians,
pack_numba, the preprocess shader and its numba twin) and the preprocess output."""

# Width of the packed data textures (texels); height grows with the Gaussian count.
TEXTURE_WIDTH = 4096
# Texels per Gaussian before the SH: mean - anchor & opacity logit, log-scales, quaternion.
BASE_TEXELS = 3
# The preprocess pass writes this many vec4 per Gaussian.
SPLAT_TEXELS = 4
# Render modes as the preprocess pass numbers them.
MODES = {"rgb": 0, "depth": 1, "normal": 2, "alpha": 3}


def sh_texels(sh_coefficients: int) -> int:
    """Texels holding K SH coefficients per channel (3 K floats, 4 a texel)."""
    return -(-3 * sh_coefficients // 4)


def texels_per_gaussian(sh_coefficients: int) -> int:
    """Texels one packed Gaussian takes: BASE_TEXELS and its SH."""
    return BASE_TEXELS + sh_texels(sh_coefficients)
