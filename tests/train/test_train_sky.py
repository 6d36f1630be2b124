"""The sky shell: far Gaussians only where the photos see past every sparse point, and left alone
by the size rules."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from inceptiongs.camera import Camera, look_at
from inceptiongs.gaussians import Gaussians
from inceptiongs.runs.config import Densification, FreeSpace, TrainConfig
from inceptiongs.train.densify import DensifyStats, densify_and_prune
from inceptiongs.train.optim import make_optimizer, params_from_gaussians
from inceptiongs.train.sky import (SKY_GRID, cell_texture, fibonacci_directions, in_background, open_cells,
                                   shell_geometry, sky_shell)


def _camera(eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, 1.0), width=64, height=48, name="cam") -> Camera:
    return Camera(name, width, height, 50.0, 50.0, width / 2, height / 2,
                  look_at(np.array(eye, float), np.array(target, float), up=(0.0, -1.0, 0.0)))


def _ground_points(camera: Camera, rows: slice, depth: float = 3.0) -> np.ndarray:
    """Points at ``depth`` on a grid of the camera's pixels in ``rows`` (the image's lower part)."""
    v, u = np.mgrid[0:camera.height, 0:camera.width][:, rows, :]
    u, v = u.ravel() + 0.5, v.ravel() + 0.5
    local = np.stack([(u - camera.cx) / camera.fx * depth, (v - camera.cy) / camera.fy * depth,
                      np.full(u.shape, depth)], 1)
    c2w = camera.camera_to_world
    return local @ c2w[:3, :3].T + c2w[:3, 3]


def test_fibonacci_directions_are_unit_and_spread_evenly():
    d = fibonacci_directions(2000)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.abs(d.mean(0)).max() < 0.01                      # no side of the sphere favoured
    # Nearest-neighbour angles are close to each other (no clumps, no holes).
    cos = d @ d.T
    np.fill_diagonal(cos, -1.0)
    nearest = np.arccos(np.clip(cos.max(1), -1, 1))
    assert nearest.max() < 2.0 * nearest.min()


def test_open_cells_are_the_image_cells_without_sparse_points():
    camera = _camera()
    points = _ground_points(camera, slice(24, 48))             # the lower half of the image
    cells = open_cells(camera, points).reshape(SKY_GRID, SKY_GRID)
    assert cells[: SKY_GRID // 2].all()                        # upper half: open sky
    assert not cells[SKY_GRID // 2:].any()                     # lower half: occupied
    # Points behind the camera do not close anything.
    assert open_cells(camera, -points).all()


def test_the_shell_covers_only_open_sky_with_the_photos_colour():
    cameras = [_camera(eye=(x, 0.0, 0.0), target=(x, 0.0, 1.0), name=f"c{i}") for i, x in enumerate((-0.1, 0.0, 0.1))]
    points = np.concatenate([_ground_points(c, slice(24, 48)) for c in cameras])
    images = []
    for camera in cameras:
        image = np.full((camera.height, camera.width, 3), 0.5)
        image[:24] = (0.2, 0.4, 0.9)                           # sky above, grey ground below
        images.append(image)
    means, colours, scales, sphere = sky_shell(cameras, images, points)
    centre, radius = shell_geometry(cameras, points)
    assert len(means) > 10
    assert np.allclose(sphere, [*centre, radius])
    assert np.allclose(np.linalg.norm(means - centre, axis=1), radius)
    assert radius > 3.0 * np.linalg.norm(points - centre, axis=1).max() * 0.9
    # Every shell Gaussian is in the upper half of the views that see it (y down: negative y).
    assert np.all(means[:, 1] < 0)
    assert np.all(np.abs(colours.astype(int) - np.array([51, 102, 230])) <= 1)
    assert np.all(scales > 0)
    # A view full of sparse points gets no shell at all.
    full = _ground_points(cameras[1], slice(0, 48))
    assert len(sky_shell(cameras[1:2], images[1:2], full)[0]) == 0


def test_a_direction_only_some_cameras_see_open_needs_the_open_fraction(monkeypatch):
    """Two cameras look the same way; the first sees sparse points all over its image, the
    second stands beyond them and sees none. With SKY_OPEN_FRACTION 0 the one open view
    suffices; above 0.5 the directions both frame get no shell."""
    import inceptiongs.train.sky as sky

    cameras = [_camera(eye=(0.0, 0.0, z), target=(0.0, 0.0, z + 1.0), name=f"c{i}") for i, z in enumerate((0.0, 4.0))]
    points = _ground_points(cameras[0], slice(0, 48))           # a wall at depth 3 behind the second camera
    images = [np.full((c.height, c.width, 3), 0.5) for c in cameras]
    monkeypatch.setattr(sky, "SKY_OPEN_FRACTION", 0.0)
    anyone = len(sky.sky_shell(cameras, images, points)[0])
    monkeypatch.setattr(sky, "SKY_OPEN_FRACTION", 0.75)
    most = len(sky.sky_shell(cameras, images, points)[0])
    assert anyone > 10 and most < anyone // 2


def test_cell_texture_is_zero_on_flat_colour_and_does_not_depend_on_resolution():
    flat = np.full((48, 64, 3), 0.7)
    assert np.allclose(cell_texture(flat), 0.0)
    # Vertical stripes 1/8 of the image wide: the same texture measured at two resolutions.
    def stripes(width, height):
        u = np.arange(width)[None, :, None] * 16 // width
        return np.broadcast_to((u % 2) * 0.8 + 0.1, (height, width, 3)).astype(np.float64)
    small, large = cell_texture(stripes(64, 48)), cell_texture(stripes(512, 384))
    assert small.max() > 0.05
    assert np.allclose(small, large, atol=0.02)


def test_a_textured_open_cell_is_a_gap_in_the_points_not_sky(monkeypatch):
    """Sparse points cover the lower half of the images; above them the left half of each photo
    is a smooth sky, the right half a fine checker (a wall SfM found no point on). With the
    texture limit only the smooth half gets shell Gaussians; without it both halves do."""
    import inceptiongs.train.sky as sky

    cameras = [_camera(eye=(x, 0.0, 0.0), target=(x, 0.0, 1.0), name=f"c{i}") for i, x in enumerate((-0.1, 0.0, 0.1))]
    points = np.concatenate([_ground_points(c, slice(24, 48)) for c in cameras])
    images = []
    for camera in cameras:
        v, u = np.mgrid[0:camera.height, 0:camera.width]
        image = np.full((camera.height, camera.width, 3), 0.5)
        image[:24, :32] = (0.2, 0.4, 0.9)
        checker = ((u // 2 + v // 2) % 2)[:24, 32:, None] * 0.6 + 0.2
        image[:24, 32:] = checker
        images.append(image)
    monkeypatch.setattr(sky, "SKY_MAX_TEXTURE", float("inf"))
    everywhere, _, _, _ = sky.sky_shell(cameras, images, points)
    monkeypatch.setattr(sky, "SKY_MAX_TEXTURE", 0.02)
    smooth, colours, _, _ = sky.sky_shell(cameras, images, points)
    # Columns left of the centre are world x < 0 (the cameras look along +z with y down).
    assert (everywhere[:, 0] > 0.5).sum() > 10
    assert len(smooth) > 10 and np.all(smooth[:, 0] < 0.5)
    assert np.all(np.abs(colours.astype(int) - np.array([51, 102, 230])) <= 1)


def test_background_gaussians_survive_the_size_rules_and_scene_ones_do_not():
    n = 4
    means = torch.tensor([[0.0, 0, 0], [0.2, 0, 0], [40.0, 0, 0], [0.0, 45.0, 0]])
    log_scales = torch.full((n, 3), math.log(0.001))
    log_scales[1:] = math.log(2.0)                             # 1 (scene) and 2, 3 (background): huge
    gaussians = Gaussians(means, log_scales, torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                          torch.full((n,), 2.0), torch.zeros(n, 1, 3))
    sphere = torch.tensor([0.0, 0.0, 0.0, 50.0])
    background = in_background(means, sphere)
    assert background.tolist() == [False, False, True, True]
    assert not in_background(means, None).any()
    config = TrainConfig(densification=Densification(prune_world_fraction=0.1))
    for exempt, survivors in ((background, 3), (None, 1)):
        params = params_from_gaussians(gaussians)
        optimizer = make_optimizer(params, config, 1.0)
        densify_and_prune(params, optimizer, DensifyStats.zeros(n), config.densification, 1.0, prune_large=True,
                          generator=torch.Generator().manual_seed(0), background=exempt)
        assert params["means"].shape[0] == survivors


def test_a_hidden_shell_gaussian_takes_its_sky_seen_neighbours_colour():
    """Rows 0-2: shell seen as sky (donors); row 3: hidden behind the scene, near donors 0 and 1;
    row 4: a scene Gaussian. With two neighbours row 3 gets the mean of rows 0 and 1, loses its
    view-dependent colour, and nothing else changes."""
    from inceptiongs.train.sky import fill_hidden_shell

    params = {
        "means": torch.tensor([[10.0, 0, 0], [10.0, 1, 0], [-10.0, 0, 0], [10.0, 0.5, 0.1], [0.0, 0, 0]]),
        "sh_dc": torch.tensor([[[1.0, 0, 0]], [[0.0, 1, 0]], [[0.0, 0, 1]], [[5.0, 5, 5]], [[0.3, 0.3, 0.3]]]),
        "sh_rest": torch.ones(5, 3, 3),
        "opacity_logits": torch.tensor([1.0, 3.0, -2.0, -6.0, 0.5]),
    }
    before = {k: v.clone() for k, v in params.items()}
    hidden = torch.tensor([False, False, False, True, False])
    donors = torch.tensor([True, True, True, False, False])
    assert fill_hidden_shell(params, hidden, donors, neighbours=2) == 1
    assert torch.allclose(params["sh_dc"][3], torch.tensor([[0.5, 0.5, 0.0]]))
    assert float(params["opacity_logits"][3]) == 2.0
    assert float(params["sh_rest"][3].abs().sum()) == 0.0
    keep = torch.tensor([0, 1, 2, 4])
    for name in params:
        assert torch.equal(params[name][keep], before[name][keep]), name
    # Nothing to fill from, or nothing hidden: unchanged.
    assert fill_hidden_shell(params, hidden, torch.zeros(5, dtype=torch.bool)) == 0
    assert fill_hidden_shell(params, torch.zeros(5, dtype=torch.bool), donors) == 0


def test_shell_exposure_tells_sky_from_hidden_from_unframed():
    """One camera looking down +z: a shell centre on a pixel the scene covers (alpha 1) is hidden,
    one on an uncovered pixel is sky, one behind the camera is not framed."""
    from inceptiongs.train.sky import shell_exposure

    camera = _camera()
    alpha = torch.zeros(camera.height, camera.width)
    alpha[:, : camera.width // 2] = 1.0                       # the scene covers the left half
    means = torch.tensor([[-2.0, 0.0, 10.0], [2.0, 0.0, 10.0], [0.0, 0.0, -10.0]])
    assert shell_exposure(means, [camera], [alpha]).tolist() == [0, 1, -1]
    # A second camera that sees the first centre as sky makes it a donor.
    other = _camera(eye=(-4.0, 0.0, 0.0), target=(-2.0, 0.0, 10.0))
    clear = torch.zeros(other.height, other.width)
    assert shell_exposure(means, [camera, other], [alpha, clear]).tolist()[0] == 1


def test_a_shell_gaussian_behind_a_translucent_foreground_is_not_hidden():
    """Behind alpha 0.7 the shell still shows (30 % of the pixel) in the training photo: with the
    fill's hidden_alpha (0.99) it is neither hidden nor sky (2), so its trained colour stays; with
    the old threshold (0.5) it counted as hidden."""
    from inceptiongs.train.sky import HIDDEN_ALPHA, shell_exposure

    camera = _camera()
    alpha = torch.zeros(camera.height, camera.width)
    alpha[:, : camera.width // 2] = 0.7                       # a translucent foreground on the left
    alpha[: camera.height // 2, : camera.width // 2] = 1.0    # opaque in its top half
    means = torch.tensor([[-2.0, 2.0, 10.0], [-2.0, -2.0, 10.0], [2.0, 0.0, 10.0]])
    top_is_opaque = shell_exposure(means, [camera], [alpha], hidden_alpha=HIDDEN_ALPHA).tolist()
    # Which image row y = +2 lands on depends on the camera's axis convention: find the opaque one.
    opaque = 0 if top_is_opaque[0] == 0 else 1
    translucent = 1 - opaque
    assert top_is_opaque[opaque] == 0 and top_is_opaque[translucent] == 2 and top_is_opaque[2] == 1
    assert shell_exposure(means, [camera], [alpha]).tolist()[translucent] == 0   # default threshold 0.5


def test_hold_shell_scales_raises_only_the_shells_short_axes():
    """Rows 0-1 are shell, row 2 is scene: only the shell's axes below the floor move, to it."""
    from inceptiongs.train.sky import hold_shell_scales

    log_scales = torch.tensor([[-5.0, -1.0, 0.5], [-0.5, -0.25, -3.0], [-9.0, -9.0, -9.0]])
    before = log_scales.clone()
    background = torch.tensor([True, True, False])
    hold_shell_scales(log_scales, background, -1.0)
    assert log_scales[0].tolist() == [-1.0, -1.0, 0.5]
    assert log_scales[1].tolist() == [-0.5, -0.25, -1.0]
    assert torch.equal(log_scales[2], before[2])
    held = log_scales.clone()
    hold_shell_scales(log_scales, background, -1.0)                          # idempotent
    assert torch.equal(log_scales, held)
    hold_shell_scales(log_scales, torch.zeros(3, dtype=torch.bool), 5.0)     # no shell: nothing moves
    assert torch.equal(log_scales, held)


def test_the_scale_floor_at_fraction_one_is_the_shells_initial_scale():
    from inceptiongs.train.sky import shell_log_scale_floor

    camera = _camera()
    points = _ground_points(camera, slice(camera.height // 2, None))
    image = np.full((camera.height, camera.width, 3), 0.6)
    _, _, scales, sphere = sky_shell([camera], [image], points)
    assert len(scales) > 0
    floor = shell_log_scale_floor(torch.as_tensor(sphere), [camera], 1.0)
    assert math.isclose(math.exp(floor), float(scales[0]), rel_tol=1e-9)
    assert math.isclose(shell_log_scale_floor(torch.as_tensor(sphere), [camera], 0.5), floor + math.log(0.5))


def test_training_with_sky_min_scale_keeps_the_shell_closed():
    """A ball photographed on black from a ring: the shell around it is told to vanish, and the
    optimiser shrinks it. With ``sky_min_scale`` no shell axis ends below the floor; without, some
    do (so the floor is what holds them)."""
    from tests.train_cases import ball, config, photos, ring_cameras, run_steps, setup
    from inceptiongs.train.sky import shell_log_scale_floor
    from inceptiongs.train.step import with_sky_shell

    cameras = ring_cameras(8)
    truth = ball(200, sh_degree=0)
    images = photos(truth, cameras)
    points = truth.means.detach().numpy()
    ends = {}
    for fraction in (0.0, 1.0):
        model, sphere = with_sky_shell(ball(200, seed=1, sh_degree=0), cameras,
                                       [images[i].numpy() for i in range(len(cameras))], points, lambda m: None)
        cfg = config(free_space={"sky_min_scale": fraction}, learning_rates={"log_scales": 0.05})
        data, state = setup(model, cameras, images, cfg, points)
        state.sky = sphere
        run_steps(state, data, cfg, 30)
        shell = in_background(state.params["means"].detach(), sphere)
        assert bool(shell.any())
        ends[fraction] = float(state.params["log_scales"].detach()[shell].min())
    floor = shell_log_scale_floor(sphere, cameras, 1.0)
    assert ends[1.0] >= floor - 1e-6
    assert ends[0.0] < floor - 0.05


def test_a_negative_or_non_finite_scale_floor_is_refused_with_its_name():
    import pytest

    from inceptiongs.errors import InputError

    for bad in (-0.5, float("nan"), float("inf")):
        with pytest.raises(InputError, match="free_space.sky_min_scale"):
            TrainConfig(free_space=FreeSpace(sky_min_scale=bad)).validate()
    TrainConfig(free_space=FreeSpace(sky_min_scale=0.5)).validate()


def test_a_run_written_before_the_floor_loads_without_it(tmp_path):
    """A config.json without ``sky_min_scale`` is a run trained with a free shell: it loads with
    the floor off (a bootstrap or resume must not raise its shell), while a new config has it on
    and a saved value is kept."""
    import json

    assert TrainConfig().free_space.sky_min_scale == 1.0
    saved = TrainConfig(free_space=FreeSpace(sky_min_scale=0.5))
    saved.save(tmp_path / "new.json")
    assert TrainConfig.load(tmp_path / "new.json").free_space.sky_min_scale == 0.5
    without = json.loads((tmp_path / "new.json").read_text())
    del without["free_space"]["sky_min_scale"]
    (tmp_path / "without.json").write_text(json.dumps(without))
    assert TrainConfig.load(tmp_path / "without.json").free_space.sky_min_scale == 0.0
    # A flat file (every setting at the top level) of those runs: the same.
    (tmp_path / "old.json").write_text(json.dumps({"scene": "/x", "free_space": True, "sky_shell": True,
                                                   "camera_ball": 0.25}))
    old = TrainConfig.load(tmp_path / "old.json").free_space
    assert (old.sky_min_scale, old.enabled, old.sky_shell, old.camera_ball) == (0.0, True, True, 0.25)
