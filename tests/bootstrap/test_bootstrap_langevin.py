"""View-adaptive Langevin sampling: pose vectors, the step, snapping, and the pose gradient."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inceptiongs.bootstrap.langevin import (l1_log_p, langevin_step, pose_gradient, pose_gradient_fd,
                                            pose_to_vector, pose_value_and_gradient, sampling_weight,
                                            snap_to_nearest, vector_to_pose)
from inceptiongs.camera import look_at, pose_distance, quat_normalize, quat_to_rotation
from inceptiongs.rasterizer.rasterize import render

from rasterize_cases import make_camera, random_gaussians


def _random_pose(rng) -> np.ndarray:
    eye = rng.normal(size=3) * 2.0
    return look_at(eye, rng.normal(size=3) * 0.3, up=quat_normalize(rng.normal(size=4))[1:])


def test_pose_vector_round_trip_and_hemisphere():
    rng = np.random.default_rng(0)
    for _ in range(20):
        pose = _random_pose(rng)
        vector = pose_to_vector(pose)
        assert vector.shape == (7,) and vector[3] >= 0
        assert np.linalg.norm(vector[3:]) == pytest.approx(1.0, abs=1e-12)
        centre = -pose[:3, :3].T @ pose[:3, 3]
        np.testing.assert_allclose(vector[:3], centre, atol=1e-12)
        np.testing.assert_allclose(vector_to_pose(vector), pose, atol=1e-12)
    # -q is the same pose; a scaled quaternion is too.
    flipped = np.concatenate([vector[:3], -3.0 * vector[3:]])
    np.testing.assert_allclose(vector_to_pose(flipped), pose, atol=1e-12)
    torch_pose = vector_to_pose(torch.tensor(vector))
    assert isinstance(torch_pose, torch.Tensor)
    np.testing.assert_allclose(torch_pose.numpy(), pose, atol=1e-12)


def test_step_without_noise_is_gradient_ascent_then_renormalised():
    rng = np.random.default_rng(1)
    pose = pose_to_vector(_random_pose(rng))
    grad = rng.normal(size=7)
    out = langevin_step(pose, grad, step_size=0.05, noise_scale=0.0)
    np.testing.assert_allclose(out[:3], pose[:3] + 0.05 * grad[:3], atol=1e-15)
    q = pose[3:] + 0.05 * grad[3:]
    q = q / np.linalg.norm(q)
    np.testing.assert_allclose(out[3:], q if q[0] >= 0 else -q, atol=1e-15)


def test_step_keeps_a_unit_quaternion_on_the_w_hemisphere():
    rng = np.random.default_rng(2)
    pose = np.array([0.1, -0.2, 0.3, 0.05, 0.7, -0.7, 0.1])
    pose[3:] /= np.linalg.norm(pose[3:])
    # A gradient pushing w negative: the result must flip to w >= 0 and be the same rotation.
    push = np.array([0, 0, 0, -10.0, 0, 0, 0])
    out = langevin_step(pose, push, step_size=0.02, noise_scale=0.0)
    raw = pose[3:] + 0.02 * push[3:]
    assert raw[0] < 0 and out[3] >= 0
    np.testing.assert_allclose(quat_to_rotation(out[3:]), quat_to_rotation(raw), atol=1e-12)
    for _ in range(300):
        pose = langevin_step(pose, rng.normal(size=7), step_size=0.05, noise_scale=1.0, rng=rng)
        assert np.linalg.norm(pose[3:]) == pytest.approx(1.0, abs=1e-12)
        assert pose[3] >= 0 and np.all(np.isfinite(pose))


def test_step_noise_has_the_langevin_scale():
    rng = np.random.default_rng(3)
    pose = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    step, scale = 0.01, np.array([0.3, 0.3, 0.3, 0.1, 0.1, 0.1, 0.1])
    moves = np.array([langevin_step(pose, np.zeros(7), step, scale, rng)[:3] for _ in range(4000)])
    # Centre displacement ~ N(0, 2 * step * scale^2): std sqrt(0.02) * 0.3 ~ 0.0424.
    np.testing.assert_allclose(moves.std(axis=0), math.sqrt(2 * step) * 0.3, rtol=0.06)
    assert np.all(np.abs(moves.mean(axis=0)) < 0.004)
    a = langevin_step(pose, np.zeros(7), step, scale, np.random.default_rng(7))
    b = langevin_step(pose, np.zeros(7), step, scale, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="rng"):
        langevin_step(pose, np.zeros(7), step, scale, None)
    with pytest.raises(ValueError):
        langevin_step(pose, np.zeros(7), 0.0, scale, rng)


@pytest.mark.parametrize("rotation_weight", [1.0, 0.3])
def test_snap_equals_brute_force_nearest_pose(rotation_weight):
    rng = np.random.default_rng(4)
    virtual = [_random_pose(rng) for _ in range(15)]
    vectors = np.array([pose_to_vector(p) for p in virtual])
    for _ in range(40):
        query = _random_pose(rng)
        # Random pose vectors as the chain produces them: any hemisphere on input.
        vector = pose_to_vector(query)
        if rng.random() < 0.5:
            vector[3:] = -vector[3:]
        brute = min(range(len(virtual)), key=lambda i: (pose_distance(query, virtual[i], rotation_weight), i))
        assert snap_to_nearest(vector, vectors, rotation_weight) == brute
    # A pose on a virtual view snaps to it; exact duplicates go to the lower index.
    assert snap_to_nearest(vectors[6], vectors) == 6
    assert snap_to_nearest(vectors[2], np.stack([vectors[5], vectors[2], vectors[2]])) == 1
    with pytest.raises(ValueError):
        snap_to_nearest(vectors[0], np.zeros((0, 7)))


def test_l1_log_p_and_sampling_weight():
    a = torch.zeros(4, 5, 3)
    b = torch.full((4, 5, 3), 0.25)
    assert float(l1_log_p(a, b)) == pytest.approx(0.25)
    assert sampling_weight(0.0) == 1.0
    assert sampling_weight(0.25) == pytest.approx(math.exp(-0.25))


def _pose_loss_setup():
    g = random_gaussians(n=14, degree=1, seed=7, spread=0.8, log_scale=-1.6)
    g.opacity_logits.clamp_(-2.0, 1.5)
    camera = make_camera()
    other = look_at(np.array([0.35, -0.2, -2.9]), np.array([0.05, 0.0, 0.0]))
    target = render(g, camera, world_to_camera=torch.tensor(other), backend="torch",
                    background=torch.tensor([0.2, 0.3, 0.25], dtype=torch.float64))["rgb"].detach()

    def loss(pose):
        return l1_log_p(render(g, camera, world_to_camera=pose, backend="torch")["rgb"], target)
    return camera, loss


def test_pose_gradient_matches_central_differences():
    camera, loss = _pose_loss_setup()
    value, autograd = pose_value_and_gradient(loss, camera.world_to_camera)
    # eps 1e-7: small enough that no pixel's alpha crosses the renderer's 1/255 skip threshold
    # (a jump) within +-eps on this scene, large enough that float64 rounding (~1e-16 / eps) is
    # negligible. At eps 1e-6 one such crossing already dominates some components.
    finite = pose_gradient_fd(loss, camera.world_to_camera, eps=1e-7)
    assert value > 0.01
    assert np.linalg.norm(autograd[:3]) > 1e-3  # a real gradient, not zeros on both sides
    # Stated tolerance: relative 1e-4, absolute 1e-6 (central-difference truncation ~eps^2).
    np.testing.assert_allclose(autograd, finite, rtol=1e-4, atol=1e-6)
    np.testing.assert_array_equal(pose_gradient(loss, camera.world_to_camera), autograd)
    # A step along the gradient raises log P (ascent), to first order.
    vector = pose_to_vector(camera.world_to_camera)
    moved = langevin_step(vector, autograd, step_size=1e-3, noise_scale=0.0)
    with torch.no_grad():
        assert float(loss(vector_to_pose(torch.tensor(moved)))) > value
