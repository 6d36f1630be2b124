"""The leave-one-source-out evidence (validation.py) and the placement by it (placement.py) on an
analytic textured plane: a held-out photo's neighbours see one region truly, show an occluder the
model's depth lacks over another, and do not see a third at all."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inceptiongs.bootstrap.config import BootstrapConfig
from inceptiongs.bootstrap.experimental.placement import candidate_views, place_by_evidence, score_view
from inceptiongs.bootstrap.experimental.validation import (PhotoEvidence, evidence_grid, evidence_weights,
                                                           margin_db, measure_evidence, photo_evidence,
                                                           validation_photos, view_margins)
from inceptiongs.bootstrap.virtual_views import VirtualView
from plane_cases import HEIGHT, PLANE_Z, WIDTH, camera_at

HELD_OUT = 0
# World x ranges on the plane: seen truly by the neighbours, hidden by an occluder in their photos
# (absent from the model's depth), and outside every neighbour's frustum.
SEEN = (0.5, 1.5)
OCCLUDED = (-2.0, -0.3)
UNSEEN_X = -2.5
OCCLUDER_GREY = 0.95
RENDER_NOISE = 0.05


def texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Smooth colour [..., 3] on the plane (periods of ~2 units, ~20+ px): warps resample it well."""
    return np.stack([0.5 + 0.3 * np.sin(3.0 * x) * np.cos(2.5 * y), 0.5 + 0.25 * np.cos(2.0 * x + 1.5 * y),
                     0.45 + 0.2 * np.sin(2.5 * (x - y))], -1)


def plane_x(camera) -> tuple[np.ndarray, np.ndarray]:
    """[H, W] world x, y where each pixel's ray meets the plane (axis-aligned cameras)."""
    u, v = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
    t = PLANE_Z - camera.center[2]
    return camera.center[0] + (u - camera.cx) / camera.fx * t, camera.center[1] + (v - camera.cy) / camera.fy * t


def photo(camera, occluded: bool) -> torch.Tensor:
    x, y = plane_x(camera)
    image = texture(x, y)
    if occluded:
        image[(x >= OCCLUDED[0]) & (x <= OCCLUDED[1])] = OCCLUDER_GREY
    return torch.as_tensor(image, dtype=torch.float32)


def depth(camera) -> torch.Tensor:
    return torch.full((camera.height, camera.width, 1), PLANE_Z - camera.center[2], dtype=torch.float32)


def noisy_render(camera) -> torch.Tensor:
    """The model's render: the true plane with a fixed noise (the same quality everywhere)."""
    g = torch.Generator().manual_seed(int(abs(camera.center[0]) * 1000) + 7)
    return (photo(camera, False) + RENDER_NOISE * torch.randn(camera.height, camera.width, 3, generator=g)).clamp(0, 1)


def scene():
    """Held-out photo 0 at x = 0; its neighbours right of it (they miss x < -2.27)."""
    cameras = [camera_at(f"p{i}", (x, 0.0, 0.0)) for i, x in enumerate((0.0, 0.4, 0.8, 1.2, 1.6))]
    photos = {i: photo(c, occluded=i != HELD_OUT) for i, c in enumerate(cameras)}
    return cameras, photos


@pytest.fixture(scope="module")
def grid():
    cameras, photos = scene()
    return measure_evidence([HELD_OUT], cameras, list(range(len(cameras))), photos, BootstrapConfig(), depth,
                            noisy_render)


def at(x: float) -> torch.Tensor:
    return torch.tensor([[x, 0.0, PLANE_Z]], dtype=torch.float64)


def test_a_region_the_neighbours_see_gains_more_than_one_they_do_not(grid):
    seen = float(grid.lookup(at(sum(SEEN) / 2)))
    occluded = float(grid.lookup(at(sum(OCCLUDED) / 2)))
    # The blend is the true plane where the neighbours see it: it beats the noisy render.
    assert seen > 3.0
    assert occluded < 0.0 and occluded < seen - 10.0
    assert math.isnan(float(grid.lookup(at(UNSEEN_X))))       # no neighbour sees it: no evidence
    assert math.isnan(float(grid.lookup(torch.tensor([[0.0, 0.0, 40.0]], dtype=torch.float64))))
    assert grid.photos[0]["view"] == HELD_OUT and grid.photos[0]["pixels"] > 0
    assert HELD_OUT not in grid.photos[0]["sources"]


def test_the_held_out_photo_is_never_its_own_source():
    cameras, photos = scene()
    evidence = photo_evidence(HELD_OUT, cameras, list(range(5)), photos, BootstrapConfig(), depth, noisy_render)
    assert HELD_OUT not in evidence.sources and len(evidence.sources) == 3
    # With the photo itself among the sources the occluded region would look fine; without it, it does not.
    x = evidence.points[:, 0].numpy()
    inside = (x > OCCLUDED[0] + 0.2) & (x < OCCLUDED[1] - 0.2)
    assert inside.any() and float(evidence.blend_se[torch.as_tensor(inside)].mean()) > 0.05


def near_camera(name: str, x: float):
    return camera_at(name, (x, 0.0, 3.0))


def test_placement_keeps_only_poses_on_positive_evidence(grid):
    on_seen, on_occluded = near_camera("seen", 1.0), near_camera("occluded", -1.2)
    candidates = [VirtualView(c, -1, 0.0, c.name) for c in (on_occluded, on_seen)]
    placement = place_by_evidence(candidates, grid, depth)
    assert [v.name for v in placement.views] == ["seen"] and placement.reason is None
    scores = {s.name: s for s in placement.scores}
    assert scores["seen"].positive > 0.8 and scores["seen"].mean_margin_db > 0
    assert scores["occluded"].mean_margin_db < 0
    for view in placement.views:
        margins = view_margins(grid, view.camera, depth(view.camera))
        assert float(margins[~torch.isnan(margins)].mean()) > 0


def test_loss_weights_cover_only_positive_evidence(grid):
    camera = near_camera("half", -0.3)        # sees both the validated region and the occluded one
    margins = view_margins(grid, camera, depth(camera))
    weights = evidence_weights(margins)
    x, _ = plane_x(camera)
    assert weights.shape == (HEIGHT, WIDTH, 1)
    assert float(weights[..., 0][torch.as_tensor(x > 0.3)].mean()) > 0.9
    assert float(weights[..., 0][torch.as_tensor((x > OCCLUDED[0] + 0.3) & (x < OCCLUDED[1] - 0.3))].max()) == 0.0
    nothing = view_margins(grid, camera, torch.zeros(HEIGHT, WIDTH, 1))
    assert bool(torch.isnan(nothing).all()) and float(evidence_weights(nothing).sum()) == 0.0


def test_no_evidence_places_nothing_and_says_why():
    target = camera_at("t", (0.0, 0.0, 0.0))
    cameras, _ = scene()
    candidates = candidate_views(target, cameras, [1, 2, 3], k=1, l=2)
    assert candidates[0].name == "target" and len(candidates) == 1 + 2 * 2
    placement = place_by_evidence(candidates, None, depth)
    assert placement.views == [] and "no evidence" in placement.reason
    # A grid whose every cell is negative: candidates scored, none kept, a reason.
    cameras, photos = scene()
    bad = measure_evidence([HELD_OUT], cameras, list(range(5)), photos, BootstrapConfig(), depth,
                           lambda c: photo(c, False))     # a perfect render: the blend never beats it
    placement = place_by_evidence(candidates, bad, depth)
    assert placement.views == [] and placement.reason and len(placement.scores) == len(candidates)


def test_a_photo_without_neighbours_or_trusted_pixels_gives_no_evidence():
    cameras, photos = scene()
    alone = photo_evidence(HELD_OUT, cameras, [HELD_OUT], photos, BootstrapConfig(), depth, noisy_render)
    assert alone.pixels == 0 and "no other training photo" in alone.reason and alone.margin_db() is None
    no_depth = lambda c: torch.zeros(c.height, c.width, 1)       # noqa: E731: every warp is empty
    empty = photo_evidence(HELD_OUT, cameras, list(range(5)), photos, BootstrapConfig(), no_depth, noisy_render)
    assert empty.pixels == 0 and "trusted" in empty.reason
    assert evidence_grid([alone, empty]) is None
    assert measure_evidence([HELD_OUT], cameras, [HELD_OUT], photos, BootstrapConfig(), depth, noisy_render) is None


def test_nan_pixels_are_left_out_and_every_margin_is_finite():
    cameras, photos = scene()

    def render_with_nans(camera):
        image = noisy_render(camera)
        image[:, : WIDTH // 2] = float("nan")
        return image

    evidence = photo_evidence(HELD_OUT, cameras, list(range(5)), photos, BootstrapConfig(), depth, render_with_nans)
    assert evidence.pixels > 0
    assert bool(torch.isfinite(evidence.render_se).all()) and bool(torch.isfinite(evidence.blend_se).all())
    assert float(evidence.points[:, 0].min()) > -0.05        # the left half (x < 0) carried the NaNs
    grid = evidence_grid([evidence])
    known = grid.margin_db[~torch.isnan(grid.margin_db)]
    assert known.numel() > 0 and bool(torch.isfinite(known).all())
    assert math.isnan(float(grid.lookup(torch.tensor([[float("nan"), 0.0, PLANE_Z]], dtype=torch.float64))))


def test_margin_and_grid_edge_cases():
    assert margin_db(0.0, 0.0, 0) == 0.0 and math.isfinite(margin_db(1.0, 0.0, 10))
    assert margin_db(0.4, 0.04, 10) == pytest.approx(10.0)
    # Coincident points: a grid of one cell of positive size.
    points = torch.ones(30, 3, dtype=torch.float64)
    one = evidence_grid([PhotoEvidence(0, [1], points, torch.full((30,), 0.01, dtype=torch.float64),
                                       torch.full((30,), 0.1, dtype=torch.float64))])
    assert one.dims == (1, 1, 1) and one.voxel > 0
    assert float(one.lookup(torch.ones(1, 3, dtype=torch.float64))) == pytest.approx(10.0)
    # Too few pixels in a cell: no evidence there.
    few = evidence_grid([PhotoEvidence(0, [1], points[:5], torch.zeros(5, dtype=torch.float64),
                                       torch.ones(5, dtype=torch.float64))])
    assert math.isnan(float(few.margin_db[0])) and few.summary()["voxels_with_evidence"] == 0
    with pytest.raises(ValueError):
        evidence_grid([], voxels_per_side=0)
    with pytest.raises(ValueError):
        place_by_evidence([], one, depth, min_fraction=0.0)
    assert score_view("x", torch.zeros(0, dtype=torch.float64)).mean_margin_db is None


def test_validation_photos_are_the_sources_and_their_neighbours():
    cameras = [camera_at(f"p{i}", (0.3 * i, 0.0, 0.0)) for i in range(8)]
    target = camera_at("t", (-0.1, 0.0, 0.0))
    chosen = validation_photos(target, cameras, list(range(8)), k=2)
    assert chosen[:2] == [0, 1] and set(chosen) == {0, 1, 2}
    assert validation_photos(target, cameras, [5], k=3) == [5]
    assert validation_photos(target, cameras, list(range(8)), k=3, limit=2) == [0, 1]


def test_pixels_without_evidence_carry_no_virtual_gradient():
    from types import SimpleNamespace

    from inceptiongs.bootstrap.generation import VirtualTarget
    from inceptiongs.bootstrap.refine import ViewChoice, render_l1, virtual_loss
    from inceptiongs.runs.config import TrainConfig

    size = (16, 16)
    target = torch.full((*size, 3), 0.8)
    params = {"means": torch.zeros(1, 3, requires_grad=True), "log_scales": torch.zeros(1, 3, requires_grad=True),
              "quats": torch.tensor([[1.0, 0, 0, 0]], requires_grad=True),
              "opacity_logits": torch.zeros(1, requires_grad=True),
              "sh_dc": torch.full((1, 1, 3), 0.1, requires_grad=True)}

    def render_fn(gaussians, camera, outputs, sh_degree, world_to_camera=None):   # flat: the one colour
        return {"rgb": gaussians.sh[0, 0].expand(*size, 3)}

    def gradient(evidence):
        view = VirtualTarget("v", None, target, torch.ones(*size, 1), target, False, 1, evidence=evidence)
        loss, _, _ = virtual_loss(10, SimpleNamespace(params=params), TrainConfig(scene="unused"), 0, view,
                                  ViewChoice(0, weighted=False), BootstrapConfig(tau=-1.0), render_fn)
        return torch.autograd.grad(loss, params["sh_dc"])[0], view

    unweighted, _ = gradient(None)
    everywhere, _ = gradient(torch.ones(*size, 1))
    nowhere, view = gradient(torch.zeros(*size, 1))
    assert float(unweighted.abs().sum()) > 0 and torch.allclose(everywhere, unweighted)
    assert float(nowhere.abs().sum()) == 0.0
    gaussians = SimpleNamespace(sh=params["sh_dc"].detach())
    assert float(render_l1(render_fn, gaussians, view, 0, None)) == 0.0


def test_the_tau_test_judges_structure_only_where_the_loss_is():
    from inceptiongs.bootstrap.refine import virtual_view_loss

    g = torch.Generator().manual_seed(3)
    target = torch.rand(32, 32, 3, generator=g)
    render = torch.rand(32, 32, 3, generator=g)          # no structure in common
    weights = torch.zeros(32, 32, 1)
    weights[:8] = 1.0                                    # a quarter of the pixels carry loss
    config = BootstrapConfig(tau=0.2)
    _, diluted = virtual_view_loss(render, target, config, 0.2, weights=weights)
    _, judged = virtual_view_loss(render, target, config, 0.2, weights=weights, weighted_share=0.25)
    # The zero-weight pixels equal I* and dilute the SSIM loss below tau; divided by their share it is not.
    assert diluted["virtual_ssim_loss"] <= config.tau < diluted["virtual_ssim_loss"] / 0.25
    assert diluted["virtual_branch"] == "perceptual" and judged["virtual_branch"] == "l1_ssim"


def test_without_lpips_weights_the_default_never_takes_the_weight_free_perceptual_branch():
    """tau unset: the paper's 0.2 with LPIPS weights, 0 without; a tau given is used as given."""
    from inceptiongs.bootstrap.refine import LPIPS_TAU, perceptual_tau, virtual_view_loss

    g = torch.Generator().manual_seed(4)
    target = torch.rand(32, 32, 3, generator=g)
    render = (target + 0.01 * torch.rand(32, 32, 3, generator=g)).clamp(0, 1)   # the right structure
    _, default = virtual_view_loss(render, target, BootstrapConfig(), 0.2)
    _, given = virtual_view_loss(render, target, BootstrapConfig(tau=0.2), 0.2)
    assert default["virtual_ssim_loss"] <= 0.2
    assert default["virtual_branch"] == "l1_ssim" and given["virtual_branch"] == "perceptual"

    def lpips(a, b):     # stands in for the network: only its presence matters here
        return (a - b).abs().mean()

    _, with_weights = virtual_view_loss(render, target, BootstrapConfig(), 0.2, lpips=lpips)
    assert with_weights["virtual_branch"] == "perceptual"
    assert perceptual_tau(BootstrapConfig(), lpips) == LPIPS_TAU and perceptual_tau(BootstrapConfig()) == 0.0
    assert perceptual_tau(BootstrapConfig(tau=0.5)) == 0.5


def test_only_pixels_on_the_targets_own_surface_count_when_a_region_is_given(grid):
    from inceptiongs.bootstrap.experimental.validation import seen_cells

    target = near_camera("target", 0.3)                   # sees x in [-0.77, 1.37]
    region = seen_cells(grid, target, depth(target))
    beside, elsewhere = near_camera("beside", 0.6), near_camera("elsewhere", 2.6)   # the latter: x in [1.53, 3.67]
    candidates = [VirtualView(c, -1, 0.0, c.name) for c in (elsewhere, beside)]
    anywhere = place_by_evidence(candidates, grid, depth)
    assert [v.name for v in anywhere.views] == ["beside", "elsewhere"]
    focused = place_by_evidence(candidates, grid, depth, region=region)
    assert [v.name for v in focused.views] == ["beside"]
    scores = {s.name: s for s in focused.scores}
    assert scores["elsewhere"].positive == 0.0 and scores["elsewhere"].mean_margin_db is None
    assert seen_cells(None, target, depth(target)) is None
    assert not bool(seen_cells(grid, target, torch.zeros(HEIGHT, WIDTH, 1)).any())
