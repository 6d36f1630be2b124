"""The scene-adaptive fixer (bootstrap/fixer.py) on synthetic images whose answer is known: a
degradation (a colour shift and a blur) applied to 'renders' that the fixer must learn to undo."""

import numpy as np
import pytest
import torch
from torch.nn import functional as F

from inceptiongs.bootstrap import fixer
from inceptiongs.gaussians import Gaussians

# Tiny networks: one torch thread (conftest.one_torch_thread) is faster than two on two busy cores.
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def scene_photo(view: int, size: int = 32) -> torch.Tensor:
    """[size, size, 3] a smooth random texture per view (sums of sinusoids), in [0, 1]."""
    rng = np.random.default_rng(view)
    y, x = np.mgrid[0:size, 0:size] / size
    channels = []
    for _ in range(3):
        f = rng.uniform(1.0, 4.0, size=(3, 2))
        phase = rng.uniform(0, 2 * np.pi, size=3)
        wave = sum(np.sin(2 * np.pi * (fy * y + fx * x) + p) for (fy, fx), p in zip(f, phase))
        channels.append(0.5 + 0.15 * wave)
    return torch.as_tensor(np.stack(channels, -1).clip(0, 1), dtype=torch.float32)


def degrade(photo: torch.Tensor) -> torch.Tensor:
    """The known degradation: a 3 x 3 box blur, then a colour shift (darker, bluer)."""
    x = photo.permute(2, 0, 1)[None]
    x = F.avg_pool2d(F.pad(x, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    shift = torch.tensor([-0.08, -0.04, 0.06]).view(1, 3, 1, 1)
    return (x * 0.9 + shift).clamp(0, 1)[0].permute(1, 2, 0)


PHOTOS = {v: scene_photo(v) for v in range(8)}


def test_pairs_hold_the_degraded_render_and_the_photo():
    pairs = fixer.build_pairs(lambda v: degrade(PHOTOS[v]), PHOTOS, [1, 4])
    assert [p.view for p in pairs] == [1, 4]
    assert torch.equal(pairs[1].photo, PHOTOS[4])
    assert torch.allclose(pairs[0].degraded, degrade(PHOTOS[1]))
    with pytest.raises(ValueError, match="view 9 has no photo"):
        fixer.build_pairs(lambda v: PHOTOS[0], PHOTOS, [9])
    with pytest.raises(ValueError, match="view 2"):
        fixer.build_pairs(lambda v: PHOTOS[v][:16], PHOTOS, [2])


def test_held_out_views_are_the_isolated_poses():
    centres = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [5, 0, 0], [0.3, 0, 0], [-4, 0, 0]], float)
    assert fixer.held_out_views(centres, range(6), 2) == [3, 5]
    assert fixer.held_out_views(centres, [0], 1) == []


def test_fixer_learns_to_undo_a_known_degradation_and_passes_its_check():
    train = fixer.build_pairs(lambda v: degrade(PHOTOS[v]), PHOTOS, range(6))
    held = fixer.build_pairs(lambda v: degrade(PHOTOS[v]), PHOTOS, [6, 7])
    trained = fixer.train_fixer(train, fixer.FixerSettings(steps=150, crop=24, batch=4, width=8, lr=3e-3))
    assert np.mean(trained.losses[-20:]) < 0.5 * np.mean(trained.losses[:5])
    check = fixer.held_out_check(trained.net, held, margin_db=1.0)
    assert check.passes, check.words()
    assert "used" in check.words() and "not used" not in check.words()
    fixed = fixer.fix_where_check_says(trained.net, check, held[0].degraded)
    assert fixed.shape == held[0].degraded.shape


def test_check_refuses_a_fixer_that_does_not_beat_the_render():
    # Untrained: the zeroed output layer returns the render itself, a gain of exactly 0 dB.
    net = fixer.fixer_network(8)
    held = fixer.build_pairs(lambda v: degrade(PHOTOS[v]), PHOTOS, [6, 7])
    check = fixer.held_out_check(net, held, margin_db=0.1)
    assert check.gain_db == pytest.approx(0.0, abs=1e-6)
    assert not check.passes and "not used" in check.words()
    assert fixer.fix_where_check_says(net, check, held[0].degraded) is None
    # A fixer trained on one degradation, checked where the render is already the photo: it harms.
    trained = fixer.train_fixer(fixer.build_pairs(lambda v: degrade(PHOTOS[v]), PHOTOS, range(6)),
                                fixer.FixerSettings(steps=80, crop=24, width=8, lr=3e-3))
    perfect = fixer.build_pairs(lambda v: PHOTOS[v], PHOTOS, [6, 7])
    check = fixer.held_out_check(trained.net, perfect)
    assert check.gain_db < 0 and not check.passes
    assert not fixer.FixerCheck([], [], [], 0.1).passes


def test_loss_psnr_and_spectrum_stay_finite():
    photo = PHOTOS[0]
    assert fixer.psnr_db(photo, photo) == pytest.approx(100.0)
    flat = torch.full((16, 16, 3), 0.5)
    spectrum = fixer.error_spectrum(flat, flat)
    assert np.isfinite(spectrum).all() and spectrum.shape == (8,)
    # Blur errors are high-frequency, a colour shift has none (its mean is removed): they differ.
    blur = fixer.error_spectrum(degrade(photo), photo)
    assert fixer.spectrum_distance(blur, blur) == 0.0
    assert fixer.spectrum_distance(blur, spectrum) > 1.0
    # Saturated inputs (all 0 or 1) and odd sizes: padded, clamped, finite.
    net = fixer.fixer_network(8)
    for image in (torch.zeros(13, 17, 3), torch.ones(13, 17, 3)):
        out = fixer.apply_fixer(net, image)
        assert out.shape == image.shape and torch.isfinite(out).all()


def test_fewer_gaussians_drops_the_least_visible():
    n = 10
    g = Gaussians(means=torch.zeros(n, 3), log_scales=torch.full((n, 3), -2.0), quats=torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                  opacity_logits=torch.linspace(-5, 5, n), sh=torch.zeros(n, 1, 3))
    kept = fixer.fewer_gaussians(g, 0.3)
    assert len(kept) == 3
    assert torch.equal(kept.opacity_logits, g.opacity_logits[7:])
    with pytest.raises(ValueError):
        fixer.fewer_gaussians(g, 0.0)


def test_kept_pairs_hold_the_budget_and_train_the_same_fixer():
    # 24 training views, a budget of 2 pairs: at most 2 pairs are kept between steps and one
    # batch's beside them, never all 24; a pair that went is made again to the same values,
    # so the fixer trains exactly as on the pairs all built at once.
    from collections.abc import Sequence

    from photo_counting import AliveCount

    photos = {v: scene_photo(v, size=16) for v in range(24)}
    render = lambda v: degrade(photos[v])   # noqa: E731
    settings = fixer.FixerSettings(steps=12, crop=8, batch=4, width=4)
    count = AliveCount()
    pairs = fixer.KeptPairs(render, photos, list(photos), budget=2 * 2 * 16 * 16 * 3 * 4)

    class Counted(Sequence):   # the pairs handed out, followed until nothing holds them
        def __len__(self):
            return len(pairs)

        def __getitem__(self, index):
            return count.track_once(pairs[index])

    counted = Counted()
    kept = fixer.train_fixer(counted, settings)
    everything = fixer.train_fixer(fixer.build_pairs(render, photos, list(photos)), settings)
    assert count.reads > 2 and count.peak <= 2 + settings.batch, count.peak
    assert kept.losses == everything.losses
    for a, b in zip(kept.net.parameters(), everything.net.parameters()):
        assert torch.equal(a, b)
    with pytest.raises(ValueError, match="view 30 has no photo"):
        fixer.KeptPairs(render, photos, [1, 30], budget=10 ** 6)


def test_whole_target_is_the_fixed_render_everywhere_and_skips_the_warps_judgement():
    """variants.fixer.target "whole": I* is the fixed render on every pixel (mask 1), no warp is
    placed, and the view carries no agreement margin (the held-out check is its gate); a failed
    check leaves the loop's own supervision (None); a bad target is one line."""
    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.bootstrap.experimental.fixer import Fixer
    from inceptiongs.bootstrap.view_supervision import ViewContext
    from inceptiongs.errors import InputError

    render = scene_photo(3, size=24)
    net = fixer.fixer_network(4)
    with torch.no_grad():                 # a fixer that brightens: I* must be its output, not the render
        net.decoder.conv_out.bias.fill_(0.1)
    expected = fixer.apply_fixer(net, render)
    assert not torch.allclose(expected, render, atol=1e-3)
    variant = Fixer(target="whole")
    variant.state.net = net
    variant.state.check = fixer.FixerCheck(views=[0], render_db=[10.0], fixed_db=[20.0], margin_db=0.1)

    def no_warps(_camera):
        raise AssertionError("the whole target places no photo")

    context = ViewContext(config=BootstrapConfig(), camera=None, fill=render, sources=[0], cameras=[], photos={},
                          render_depth=no_warps, render_rgb=lambda _camera: render)
    supervision = variant.supervise(context)
    assert torch.allclose(supervision.image, expected.clamp(0, 1), atol=1e-6)
    assert supervision.mask.shape == (24, 24, 1) and bool((supervision.mask == 1).all())
    assert supervision.report == {"agreement_db": None}
    variant.state.check = fixer.FixerCheck(views=[0], render_db=[10.0], fixed_db=[10.0], margin_db=0.1)
    assert variant.supervise(context) is None
    with pytest.raises(InputError, match="variants.fixer.target must be \"fill\", \"whole\" or \"guided\", got .all."):
        Fixer(target="all").check("variants.fixer", BootstrapConfig())


def guided(view: int) -> torch.Tensor:
    """[32, 32, 7]: a render that shows the wrong texture, and a guide whose left half holds the
    view's photo (mask 1) and whose right half holds the render (mask 0): the answer is in the
    guide where its mask says so, and nowhere in the render."""
    render, photo = scene_photo(view + 100), PHOTOS[view]
    mask = torch.zeros(32, 32, 1)
    mask[:, :16] = 1.0
    return torch.cat([render, mask * photo + (1 - mask) * render, mask], dim=-1)


def test_a_guided_fixer_copies_the_guide_where_its_mask_holds():
    """The guided fixer (render + the nearest photos' blend + its mask) learns to take the blend
    where the mask says a photo reached (the render holds none of that content): on held-out
    views its error is far lower on the guided half than on the other."""
    settings = fixer.FixerSettings(steps=150, crop=24, batch=4, width=8, lr=3e-3)
    train = fixer.build_pairs(guided, PHOTOS, range(6))
    held = fixer.build_pairs(guided, PHOTOS, [6, 7])
    trained = fixer.train_fixer(train, settings)
    check = fixer.held_out_check(trained.net, held, margin_db=2.0)
    assert check.passes, check.words()
    fixed = fixer.apply_fixer(trained.net, held[0].degraded)
    assert fixed.shape == (32, 32, 3)
    error = (fixed - held[0].photo).abs()
    left, right = error[:, 2:14].mean(), error[:, 18:30].mean()
    assert left < 0.5 * right, (float(left), float(right))
