"""Stage II's supervision ingredients: lumigraph weights, exposure correction, and I* on an
analytic textured plane (refined depth beats the stage-I depth it starts from)."""

from __future__ import annotations

import math

import pytest
import torch

from inceptiongs.bootstrap.experimental.exposure import apply_affine_colour, fit_affine_colour
from inceptiongs.bootstrap.experimental.lumigraph import lumigraph_weights, ray_angles
from inceptiongs.bootstrap.experimental.photo_depth import DEFAULT_CONFIDENCE_MIN
from inceptiongs.bootstrap.experimental.inpaint import inpaint
from inceptiongs.bootstrap.experimental.photo_supervision import FILLS, Source, match_exposures, supervise
from inceptiongs.evaluation.metrics import psnr

from test_bootstrap_photo_depth import HEIGHT, PLANE_Z, WIDTH, camera_at, photo_of_plane


def test_lumigraph_favours_the_smaller_ray_angle_and_sums_to_one():
    points = torch.zeros(2, 3, 3, dtype=torch.float64)
    virtual = torch.tensor([0.0, 0.0, -5.0], dtype=torch.float64)
    sources = torch.tensor([[0.5, 0.0, -5.0], [2.0, 0.0, -5.0], [-1.0, 0.0, -5.0]], dtype=torch.float64)
    valid = torch.ones(3, 2, 3, dtype=torch.bool)
    weights, best = lumigraph_weights(points, valid, virtual, sources)
    w = weights[:, 0, 0, 0]
    assert float(w[0]) > float(w[2]) > float(w[1])
    assert torch.allclose(weights.sum(0), torch.ones(2, 3, 1, dtype=torch.float64))
    assert 0.0 < float(best.min()) <= 1.0
    angle = ray_angles(points[:1, :1], virtual, sources[:1])
    assert float(angle) == pytest.approx(math.atan2(0.5, 5.0))


def test_lumigraph_ignores_invalid_sources_and_penalises_far_ones():
    points = torch.zeros(1, 2, 3, dtype=torch.float64)
    virtual = torch.tensor([0.0, 0.0, -2.0], dtype=torch.float64)
    # Same direction, one source twice as far: the near one wins.
    sources = torch.tensor([[0.0, 0.0, -2.2], [0.0, 0.0, -4.4]], dtype=torch.float64)
    valid = torch.tensor([[[True, False]], [[True, False]]])
    weights, best = lumigraph_weights(points, valid, virtual, sources)
    assert float(weights[0, 0, 0]) > float(weights[1, 0, 0])
    assert float(weights[:, 0, 1].abs().sum()) == 0.0 and float(best[0, 1]) == 0.0


def test_exposure_fit_recovers_a_known_affine_colour_change():
    g = torch.Generator().manual_seed(1)
    colours = torch.rand(2000, 3, generator=g, dtype=torch.float64) * 0.8 + 0.1
    matrix = torch.tensor([[1.2, 0.05, 0.0], [0.0, 0.9, 0.03], [0.02, 0.0, 1.1]], dtype=torch.float64)
    offset = torch.tensor([0.02, -0.03, 0.01], dtype=torch.float64)
    changed = colours @ matrix.T + offset
    fitted_matrix, fitted_offset = fit_affine_colour(changed, colours, torch.ones(2000))
    # The fit maps the changed colours back: the inverse map.
    back = apply_affine_colour(changed, fitted_matrix, fitted_offset)
    assert float((back - colours).abs().max()) < 2e-3
    inverse = torch.linalg.inv(matrix)
    assert torch.allclose(fitted_matrix, inverse, atol=5e-3)


def test_exposure_fit_with_too_few_pixels_is_the_identity():
    matrix, offset = fit_affine_colour(torch.rand(10, 3), torch.rand(10, 3), torch.ones(10))
    assert torch.equal(matrix, torch.eye(3, dtype=torch.float64)) and torch.equal(offset, torch.zeros(3, dtype=torch.float64))


def test_inpaint_fills_a_hole_from_its_border():
    image = torch.full((20, 20, 3), 0.6)
    known = torch.ones(20, 20, dtype=torch.bool)
    known[8:12, 8:12] = False
    image[~known] = 0.0
    filled = inpaint(image, known)
    assert float((filled[8:12, 8:12] - 0.6).abs().max()) < 0.02


def plane_sources(brightness_b: float = 1.0, depth_scale: float = 1.08):
    """Three photos of the plane, stage-I depth ``depth_scale`` times too far in every view;
    photo b ``brightness_b`` times brighter (another exposure)."""
    cameras = [camera_at("a", (-1.2, 0.0, 0.0)), camera_at("b", (1.2, 0.1, 0.0)), camera_at("c", (0.0, 1.0, 0.0))]
    depth = torch.full((HEIGHT, WIDTH, 1), PLANE_Z * depth_scale)
    photos = [photo_of_plane(cameras[0]), (photo_of_plane(cameras[1]) * brightness_b).clamp(0, 1),
              photo_of_plane(cameras[2])]
    return [Source(p, c, depth) for p, c in zip(photos, cameras)], depth


@pytest.fixture(scope="module")
def plane_views():
    sources, depth = plane_sources()
    virtual = camera_at("v", (0.08, 0.1, 0.0))
    truth = photo_of_plane(virtual)
    render = torch.full_like(truth, 0.5)  # stage I rendered a blur
    return virtual, sources, truth, render, depth


def textured_inner() -> torch.Tensor:
    inner = torch.zeros(HEIGHT, WIDTH, 1, dtype=torch.bool)
    inner[6:-6, 6:WIDTH // 2] = True  # the textured half, away from the borders
    return inner


def test_refined_depth_places_the_photos_better_than_the_stage_one_depth(plane_views):
    virtual, sources, truth, render, prior_depth = plane_views
    plain = supervise(virtual, render, prior_depth, sources, fill="render", refine_depth=False,
                      lumigraph=False, exposure=False)
    refined = supervise(virtual, render, prior_depth, sources, fill="render", lumigraph=False, exposure=False)
    mask = textured_inner() & refined.covered & plain.covered
    assert float(mask.float().mean()) > 0.25
    # An 8 % depth error shifts the photos by about a pixel here; the sweep removes it.
    assert float(psnr(refined.blended, truth, mask)) > float(psnr(plain.blended, truth, mask)) + 3.0
    full = supervise(virtual, render, prior_depth, sources, fill="render")
    assert float(psnr(full.target, truth)) > float(psnr(render, truth)) + 2.0
    assert 0.0 <= float(full.mask.min()) and float(full.mask.max()) <= 1.0


def test_exposure_matching_makes_the_warps_agree():
    sources, depth = plane_sources(brightness_b=1.25)
    virtual = camera_at("v", (0.08, 0.1, 0.0))
    out = supervise(virtual, torch.full((HEIGHT, WIDTH, 3), 0.5), depth, sources, fill="render", exposure=False)
    images = [w.image.float() for w in out.warps]
    matched = match_exposures(images, [w.mask for w in out.warps], out.depth.confidence)
    common = textured_inner()[..., 0] & torch.stack([w.mask[..., 0] > 0 for w in out.warps]).all(0)
    assert int(common.sum()) > 100
    disagreement = lambda ims: float((ims[1] - ims[0])[common].abs().mean())  # noqa: E731  b (bright) vs a
    assert disagreement(matched) < 0.3 * disagreement(images)


@pytest.mark.parametrize("fill", FILLS)
def test_every_fill_keeps_the_target_in_range_and_the_mask_soft(plane_views, fill):
    virtual, sources, _, render, prior_depth = plane_views
    out = supervise(virtual, render, prior_depth, sources, generated=render * 0.9, fill=fill)
    assert out.target.shape == render.shape and bool(torch.isfinite(out.target).all())
    assert float(out.target.min()) >= 0.0 and float(out.target.max()) <= 1.0
    if fill == "render":
        uncovered = ~out.covered[..., 0]
        assert torch.allclose(out.target[uncovered], render[uncovered])


def test_no_sources_gives_the_fill_and_a_zero_mask(plane_views):
    virtual, _, _, render, prior_depth = plane_views
    out = supervise(virtual, render, prior_depth, [], generated=render * 0.5, fill="prior")
    assert float(out.mask.max()) == 0.0 and torch.allclose(out.target, render * 0.5)


def test_informative_pixels_are_where_the_photos_contradict_the_render(plane_views):
    virtual, sources, truth, blurred, prior_depth = plane_views
    wrong = supervise(virtual, blurred, prior_depth, sources, fill="render")
    right = supervise(virtual, truth, prior_depth, sources, fill="render")
    textured = textured_inner() & wrong.covered
    # A blurred render is contradicted by the photos on the textured half: most of it is
    # informative, and only where a photo is trusted and the depth confirmed.
    assert float(wrong.informative[textured].gt(0).float().mean()) > 0.5
    assert not bool(wrong.informative[~wrong.covered].any())
    assert not bool(wrong.informative[wrong.depth.confidence < DEFAULT_CONFIDENCE_MIN].any())
    # A render that already shows what the photos show has (almost) nothing to learn from them.
    assert float(right.informative.gt(0).float().mean()) < 0.02
    assert float(right.informative.gt(0).float().mean()) < 0.1 * float(wrong.informative.gt(0).float().mean())


def test_informative_mask_needs_confirmed_depth_and_a_residual_above_the_sources_spread():
    from inceptiongs.bootstrap.experimental.photo_supervision import RESIDUAL_FLOOR, informative_mask, source_spread

    render = torch.full((2, 3, 3), 0.5)
    blended = render.clone()
    blended[0, 0] += 0.2                                 # contradicted, sources agree
    blended[0, 1] += 0.2                                 # contradicted, but the sources disagree more
    blended[0, 2] += 0.5 * RESIDUAL_FLOOR                # within the noise floor
    blended[1, 0] += 0.2                                 # contradicted, depth not confirmed
    images = torch.stack([blended.clone(), blended.clone()])
    images[0, 0, 1] += 0.3
    images[1, 0, 1] -= 0.3
    weights = torch.full((2, 2, 3, 1), 0.5)
    spread = source_spread(images, weights, blended)      # given unfiltered images: judged per pixel
    assert float(spread[0, 0]) == pytest.approx(0.0) and float(spread[0, 1]) == pytest.approx(0.3)
    confirmed = torch.ones(2, 3, 1, dtype=torch.bool)
    confirmed[1, 0] = False
    covered = torch.ones(2, 3, 1, dtype=torch.bool)
    out = informative_mask(covered, confirmed, blended, render, spread)
    assert float(out[0, 0]) == 1.0 and float(out[1, 1]) == 0.0  # (1, 1): render agrees
    assert float(out[0, 1]) == 0.0 and float(out[0, 2]) == 0.0 and float(out[1, 0]) == 0.0


def test_informative_target_holds_the_blended_photos_where_the_mask_is_on(plane_views):
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.supervise import ViewContext, supervise_view

    virtual, sources, truth, blurred, prior_depth = plane_views
    cameras = [s.camera for s in sources] + [virtual]
    photos = {i: s.photo for i, s in enumerate(sources)}
    depth_of = lambda camera: prior_depth  # noqa: E731  (every view sees the plane at that depth)
    config = BootstrapConfig(fill="render", virtual_depth="render",
                             variants={"photo_supervision": {}, "informative": {}})
    out = supervise_view(ViewContext(config, virtual, blurred.numpy(), [0, 1, 2], cameras, photos, depth_of,
                                     lambda camera: blurred))
    target, mask = out.image, out.mask
    full = supervise(virtual, blurred, prior_depth, sources, fill="render")
    on = mask[..., 0] > 0
    assert torch.equal(mask, full.informative) and int(on.sum()) > 50
    assert torch.allclose(target[on], full.blended[on].clamp(0, 1)) and torch.allclose(target[~on], blurred[~on])
    # The informative target is closer to the truth than the blurred render where it is on.
    assert float(psnr(target, truth, on[..., None])) > float(psnr(blurred, truth, on[..., None])) + 3.0


def test_the_priors_fill_is_generated_on_its_device_and_returned_on_the_models(tmp_path):
    # "meta" stands in for a GPU prior beside a host model; the prior must be handed the model on
    # its own device, and the fill (read back from the host cache) must come back as a tensor
    # on the model's device, where the warps it is blended with live.
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.generation import GenerationCache
    from inceptiongs.bootstrap.view_targets import TargetMaker, TargetSetting

    from rasterize_cases import random_gaussians

    class MetaPrior:
        device = torch.device("meta")
        seen = []

        def generate(self, gaussians, camera, steps, seed):
            self.seen.append(gaussians.means.device.type)
            return torch.full((camera.height, camera.width, 3), 0.25), None

    camera = camera_at("v", (0.0, 0.0, 0.0))
    setting = TargetSetting([camera], [0], {}, GenerationCache(tmp_path), tmp_path, rasterizer=None,
                            prior=MetaPrior(), prior_hash="p")
    config = BootstrapConfig(fill="prior")
    current = random_gaussians(n=20, degree=0, seed=1)
    fill, hit = TargetMaker(setting, current, sky=None).fill(camera, config)
    assert MetaPrior.seen == ["meta"] and not hit
    assert isinstance(fill, torch.Tensor) and fill.device == current.means.device
    assert fill.shape == (camera.height, camera.width, 3) and float(fill.mean()) == 0.25
    again, hit = TargetMaker(setting, current, sky=None).fill(camera, config)
    assert hit and torch.equal(again, fill) and MetaPrior.seen == ["meta"]   # the cache, not the prior


def test_makers_sharing_the_pools_depths_render_each_cameras_depth_once(tmp_path):
    """A view made again when chosen reads the surface depths rendered since the last
    regeneration (ViewPool.depths); a maker without the dict renders its own; forgetting clears it."""
    from inceptiongs.bootstrap.generation import GenerationCache
    from inceptiongs.bootstrap.view_targets import TargetMaker, TargetSetting

    from rasterize_cases import random_gaussians

    calls = []

    def rasterizer(gaussians, camera, outputs=("rgb",), **kwargs):
        calls.append(camera.name)
        shape = (camera.height, camera.width)
        return {"depth": torch.ones(*shape, 1), "alpha": torch.ones(*shape, 1), "rgb": torch.zeros(*shape, 3)}

    cameras = [camera_at("a", (0.0, 0.0, 0.0)), camera_at("b", (0.5, 0.0, 0.0))]
    setting = TargetSetting(cameras, [0, 1], {}, GenerationCache(tmp_path), tmp_path, rasterizer=rasterizer)
    current, depths = random_gaussians(n=20, degree=0, seed=1), {}
    first = TargetMaker(setting, current, sky=None, depths=depths)
    for camera in cameras:
        first.renders.depth(camera)
    assert calls == ["a", "b"] and len(depths) == 2
    second = TargetMaker(setting, current, sky=None, depths=depths)
    assert torch.equal(second.renders.depth(cameras[1]), depths[next(k for k in depths if k[0].startswith("b"))])
    assert calls == ["a", "b"]                                   # kept, not rendered again
    TargetMaker(setting, current, sky=None).renders.depth(cameras[0])
    assert calls == ["a", "b", "a"]                              # its own cache
    second.renders.forget()
    assert depths == {}
