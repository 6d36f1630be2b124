"""The viewer's GL-free parts: camera controllers, flags file, selection math, undo stack,
frustums, the training thread wrapper, and the reference comparison maths."""

from __future__ import annotations

import json
import math
import threading
import time

import numpy as np
import pytest

from inceptiongs.camera import Camera, look_at, read_camera_json
from inceptiongs.errors import InputError
from inceptiongs.app import editing, flags, frustums, navigation, reference
from inceptiongs.io import flags as flag_io
from inceptiongs.app.live_training import LiveTraining
from inceptiongs.live import SnapshotBox


def _camera(eye=(0.0, 0.0, -4.0), target=(0.0, 0.0, 0.0), width=64, height=48, f=50.0):
    pose = look_at(np.array(eye), np.array(target), np.array([0.0, -1.0, 0.0]))
    return Camera("c", width, height, f, f, width / 2, height / 2, pose)


# --- navigation -------------------------------------------------------------------------

def test_from_camera_round_trips_pose_and_fov():
    cam = _camera(eye=(1.0, -0.5, -3.0))
    state = navigation.NavigationState.from_camera(cam)
    out = state.camera(cam.width, cam.height)
    np.testing.assert_allclose(out.world_to_camera, cam.world_to_camera, atol=1e-12)
    np.testing.assert_allclose(out.fy, cam.fy, rtol=1e-12)


def test_fly_moves_along_camera_axes_at_speed():
    cam = _camera()
    state = navigation.NavigationState.from_camera(cam, speed=2.0)
    state.fly(np.array([0.0, 0.0, 1.0]), seconds=0.5)  # W: forward
    np.testing.assert_allclose(state.center, cam.center + cam.rotation[2] * 1.0, atol=1e-12)
    state.fly(np.array([1.0, 0.0, 1.0]), seconds=1.0)  # diagonal is not faster
    assert math.isclose(np.linalg.norm(state.center - cam.center - cam.rotation[2]), 2.0, rel_tol=1e-12)


def test_look_right_turns_forward_towards_right_and_keeps_horizon():
    state = navigation.NavigationState.from_camera(_camera())
    right_before = state.rotation[0].copy()
    forward_before = state.rotation[2].copy()
    state.look(50.0, 0.0)
    assert state.rotation[2] @ right_before > 0  # turned right
    assert abs(state.rotation[0] @ state.up) < 1e-9  # no roll: x stays horizontal
    state.look(0.0, -10_000.0)  # far past straight up: pitch is limited
    assert state.rotation[2] @ state.up < 1.0 - 1e-5
    assert np.allclose(state.rotation @ state.rotation.T, np.eye(3), atol=1e-9)
    assert state.rotation[2] @ forward_before > -1  # still a valid orientation


def test_orbit_keeps_distance_and_pivot_in_view():
    cam = _camera()
    pivot = np.zeros(3)
    state = navigation.NavigationState.from_camera(cam, pivot=pivot)
    distance = np.linalg.norm(state.center - pivot)
    for dx, dy in [(40, 0), (0, 30), (-70, 15)]:
        state.orbit(dx, dy)
        assert math.isclose(np.linalg.norm(state.center - pivot), distance, rel_tol=1e-9)
        pixels, depth = editing.project_means(pivot[None], state.camera(64, 48))
        np.testing.assert_allclose(pixels[0], (32, 24), atol=1e-6)  # pivot stays at image centre
        assert depth[0] > 0
    state.zoom(2)
    assert math.isclose(np.linalg.norm(state.center - pivot), distance * 0.85 ** 2, rel_tol=1e-9)


def test_default_view_sees_all_points():
    rng = np.random.default_rng(0)
    means = rng.normal(size=(500, 3)) + np.array([10.0, 2.0, -3.0])
    state = navigation.default_view(means, 320, 240)
    pixels, depth = editing.project_means(means, state.camera(320, 240))
    inside = (depth > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < 320) & (pixels[:, 1] >= 0) & (pixels[:, 1] < 240)
    assert inside.mean() > 0.9


def _shell(count: int, radius: float, rng, centre=(0.0, 0.0, 0.0), thickness: float = 0.15) -> np.ndarray:
    """``count`` points all around ``centre``, radius * (1 +- thickness): a stage-I sky shell."""
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return np.asarray(centre) + directions * radius * rng.uniform(1 - thickness, 1 + thickness, size=(count, 1))


@pytest.mark.parametrize("scene_count, shell_count", [(9000, 800), (1500, 8000)])
def test_a_sky_shell_saved_with_a_model_is_found_and_left_out_of_the_opening_view(scene_count, shell_count):
    """A model file alone (no cameras, no sparse points) with stage I's shell around it, a thin
    one or one that holds most Gaussians: the shell is found, and the opening view frames the
    scene from inside it."""
    rng = np.random.default_rng(3)
    scene = rng.normal(size=(scene_count, 3)) * np.array([3.0, 1.0, 3.0]) + np.array([2.0, 0.0, -1.0])
    shell = _shell(shell_count, 40.0, rng, centre=(1.0, -2.0, 0.0))
    means = np.concatenate([scene, shell])
    found = navigation.model_shell(means)
    assert found is not None
    centre, radius = found
    # The shell is all beyond the radius; of the scene at most its far tail (a normal's 4 sigma).
    assert np.all(np.linalg.norm(shell - centre, axis=1) > radius)
    assert np.mean(np.linalg.norm(scene - centre, axis=1) < radius) > 0.995
    state = navigation.default_view(means, 320, 240)
    assert np.linalg.norm(state.center - centre) < 0.8 * 40.0 * 0.85          # inside the shell, not in it
    pixels, depth = editing.project_means(scene, state.camera(320, 240))
    inside = (depth > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < 320) & (pixels[:, 1] >= 0) & (pixels[:, 1] < 240)
    assert inside.mean() > 0.9


def test_a_model_without_a_shell_is_not_given_one():
    """A blob; a street whose two far ends are apart from its middle; a blob with a few floaters
    far off to one side: nothing surrounds them, so nothing is left out."""
    rng = np.random.default_rng(4)
    blob = rng.normal(size=(5000, 3))
    ends = np.concatenate([rng.normal(size=(3000, 3)) + [x, 0.0, 0.0] for x in (-30.0, 0.0, 30.0)])
    floaters = np.concatenate([blob, rng.normal(size=(200, 3)) + [50.0, 5.0, 0.0]])
    for means in (blob, ends, floaters):
        assert navigation.model_shell(means) is None
        assert navigation.inside_shell(means, [], None).all()


def test_look_at_shows_world_up_as_image_up():
    up = np.array([0.0, 0.0, 1.0])
    pose = look_at(np.array([3.0, 1.0, 0.5]), np.zeros(3), up)
    assert -pose[1, :3] @ up > 0.9
    assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3)) and np.linalg.det(pose[:3, :3]) > 0
    pixels, _ = editing.project_means(np.zeros((1, 3)), Camera("c", 10, 10, 5, 5, 5, 5, pose))
    np.testing.assert_allclose(pixels[0], (5, 5), atol=1e-9)


def test_estimate_up_from_cameras():
    cams = [_camera(eye=(x, 0.0, -4.0)) for x in (-1.0, 0.0, 1.0)]
    np.testing.assert_allclose(navigation.estimate_up(cams), [0.0, -1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(navigation.estimate_up([]), [0.0, -1.0, 0.0])


def _arc_rig(turn=np.eye(3), azimuths=np.linspace(0, 150, 12), height=1.5, rolls_deg=None) -> list[Camera]:
    """Level cameras (world +Z up) on part of a circle of radius 4 at ``height``, looking down at
    the origin (as the demo scene's), the whole rig turned by ``turn`` [3, 3]; camera i then
    rolled by rolls_deg[i] about its own viewing axis (a hand-held capture)."""
    cams = []
    rolls_deg = np.zeros(len(azimuths)) if rolls_deg is None else rolls_deg
    for azimuth, roll_deg in zip(np.radians(azimuths), rolls_deg):
        eye = np.array([4 * np.cos(azimuth), 4 * np.sin(azimuth), height])
        pose = look_at(turn @ eye, np.zeros(3), turn @ np.array([0.0, 0.0, 1.0]))
        c, s = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
        pose[:3, :] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ pose[:3, :]
        cams.append(Camera("c", 64, 48, 50.0, 50.0, 32.0, 24.0, pose))
    return cams


def test_estimate_up_is_level_for_cameras_looking_down_from_part_of_a_circle():
    """The cameras' mean up leans towards what they look down at when they cover part of a
    circle (the demo scene's up showed as "tilted"); their right axes are level, so the up
    perpendicular to them is the world's +Z exactly."""
    cams = _arc_rig()
    mean = np.mean([-c.rotation[1] for c in cams], axis=0)
    assert math.degrees(math.acos(mean[2] / np.linalg.norm(mean))) > 5  # the plain mean is off
    np.testing.assert_array_equal(navigation.estimate_up(cams), [0.0, 0.0, 1.0])
    assert navigation.up_label(navigation.estimate_up(cams)) == "+Z"
    # A world that is really tilted (the rig turned 20 deg about x) keeps its tilt, and says so.
    angle = math.radians(20.0)
    turn = np.array([[1, 0, 0], [0, math.cos(angle), -math.sin(angle)], [0, math.sin(angle), math.cos(angle)]])
    up = navigation.estimate_up(_arc_rig(turn))
    np.testing.assert_allclose(up, turn @ [0.0, 0.0, 1.0], atol=1e-9)
    assert navigation.up_label(up) == "tilted 20 deg from +Z"


def test_estimate_up_of_forward_facing_cameras_is_their_mean_up_made_level():
    """Cameras that all face one way (LLFF) do not fix a horizontal plane: up is their mean up,
    perpendicular to their common right axis, not the noise of a plane fit."""
    cams = [_camera(eye=(x, -0.3, -4.0), target=(x * 0.2, 0.0, 0.0)) for x in (-0.3, -0.1, 0.1, 0.3)]
    up = navigation.estimate_up(cams)
    mean = np.mean([-c.rotation[1] for c in cams], axis=0)
    assert np.linalg.norm(up) == pytest.approx(1.0)
    assert max(abs(up @ c.rotation[0]) for c in cams) < 0.1  # level: perpendicular to the right axes
    assert up @ mean / np.linalg.norm(mean) > 0.99
    # Hand-held: each camera of the arc rolled up to 3 deg either way; the up stays within a degree.
    rolls = np.random.default_rng(0).uniform(-3.0, 3.0, 12)
    rolled = navigation.estimate_up(_arc_rig(rolls_deg=rolls))
    assert rolled @ [0.0, 0.0, 1.0] > math.cos(math.radians(1.0))


# --- flags --------------------------------------------------------------------------------

def test_flags_round_trip_and_format(tmp_path):
    path = flag_io.flags_path(tmp_path)
    assert flag_io.load_flags(path) == []
    cam = _camera()
    items = [flags.flag_camera(cam, "flag 1"), flags.flag_aimed_at(cam, np.array([0.5, 0.2, 0.0]), "flag 2")]
    flag_io.save_flags(path, items)
    data = json.loads(path.read_text())
    assert data["version"] == 1 and [f["name"] for f in data["flags"]] == ["flag 1", "flag 2"]
    assert set(data["flags"][0]["camera"]) >= {"width", "height", "fx", "fy", "cx", "cy", "world_to_camera"}
    # each flag's camera is plain camera JSON: the project's camera reader takes it as is
    (tmp_path / "cam.json").write_text(json.dumps(data["flags"][1]["camera"]))
    np.testing.assert_allclose(read_camera_json(tmp_path / "cam.json").world_to_camera,
                               items[1].camera.world_to_camera)
    loaded = flag_io.load_flags(path)
    assert [f.name for f in loaded] == ["flag 1", "flag 2"]
    np.testing.assert_allclose(loaded[1].camera.world_to_camera, items[1].camera.world_to_camera)
    assert flags.unique_flag_name(loaded) == "flag 3"


def test_flag_aimed_at_looks_at_target_from_same_place():
    cam = _camera()
    target = np.array([0.7, -0.4, 1.0])
    flag = flags.flag_aimed_at(cam, target, "f")
    np.testing.assert_allclose(flag.camera.center, cam.center, atol=1e-12)
    pixels, _ = editing.project_means(target[None], flag.camera)
    np.testing.assert_allclose(pixels[0], (cam.cx, cam.cy), atol=1e-9)
    assert flag.camera.rotation[1] @ cam.rotation[1] > 0.5  # not rolled upside down


def test_unproject_inverts_projection():
    cam = _camera(eye=(0.3, -1.0, -4.0))
    point = np.array([0.2, 0.1, 0.5])
    pixels, depth = editing.project_means(point[None], cam)
    back = flags.unproject_pixel(cam, pixels[0, 0] - 0.5, pixels[0, 1] - 0.5, depth[0])
    np.testing.assert_allclose(back, point, atol=1e-12)


@pytest.mark.parametrize("text, problem", [("{", "not a readable"), ('{"flags": []}', "version"),
                                           ('{"version": 1, "flags": [{"camera": {"width": 1}}]}', "missing")])
def test_bad_flags_file_is_input_error(tmp_path, text, problem):
    path = tmp_path / "flags.json"
    path.write_text(text)
    with pytest.raises(InputError, match=problem) as info:
        flag_io.load_flags(path)
    assert str(path) in str(info.value)


# --- editing ------------------------------------------------------------------------------

def _arrays(n=200, seed=1):
    rng = np.random.default_rng(seed)
    return {"means": rng.uniform(-1, 1, (n, 3)).astype(np.float32),
            "log_scales": rng.uniform(-5, 0, (n, 3)).astype(np.float32),
            "quats": np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
            "opacity_logits": rng.normal(size=n).astype(np.float32),
            "sh": rng.normal(size=(n, 1, 3)).astype(np.float32)}


def test_projection_matches_pinhole_loop():
    cam = _camera(eye=(0.5, -0.3, -3.0))
    means = _arrays()["means"]
    pixels, depth = editing.project_means(means, cam)
    for m, p, z in zip(means[:20], pixels[:20], depth[:20]):
        c = cam.world_to_camera @ np.append(m, 1.0)
        assert math.isclose(z, c[2], rel_tol=1e-9)
        assert math.isclose(p[0], cam.fx * c[0] / c[2] + cam.cx, rel_tol=1e-9)
    behind, _ = editing.project_means(np.array([[0.0, 0.0, -10.0]]), cam)
    assert np.isnan(behind).all()
    assert not editing.select_rectangle(behind, (-1e9, -1e9), (1e9, 1e9)).any()


def test_rectangle_and_brush_selection():
    pixels = np.array([[1.0, 1.0], [5.0, 5.0], [9.0, 2.0], [np.nan, np.nan]])
    assert editing.select_rectangle(pixels, (6.0, 0.0), (0.0, 6.0)).tolist() == [True, True, False, False]
    assert editing.select_brush(pixels, (5.0, 4.0), 1.5).tolist() == [False, True, False, False]


def test_threshold_selection():
    logits = np.array([-5.0, 0.0, 5.0])
    log_scales = np.log(np.array([[0.01] * 3, [0.5, 0.01, 0.01], [0.02] * 3]))
    assert editing.select_thresholds(logits, log_scales, max_opacity=0.1).tolist() == [True, False, False]
    assert editing.select_thresholds(logits, log_scales, min_size=0.1).tolist() == [False, True, False]
    assert editing.select_thresholds(logits, log_scales).tolist() == [False, False, False]


def test_delete_undo_redo_crop():
    arrays = _arrays()
    state = editing.EditState(arrays)
    first = arrays["means"][:, 0] > 0.5
    state.select(first)
    assert state.delete_selected()
    assert state.count == 200 - first.sum()
    assert not state.selected.any()
    np.testing.assert_array_equal(state.visible_arrays()["means"], arrays["means"][~first])
    state.crop(np.array([-1, -1, -0.5]), np.array([1, 1, 1]))
    expected = ~first & (arrays["means"][:, 2] >= -0.5)
    np.testing.assert_array_equal(state.alive, expected)
    assert state.undo() and np.array_equal(state.alive, ~first)
    assert state.undo() and state.alive.all()
    assert np.array_equal(state.selected, first)  # undoing a deletion brings its selection back
    assert state.undo() and not state.selected.any()  # selection changes are undo steps too
    assert not state.undo()
    assert state.redo() and np.array_equal(state.selected, first) and state.alive.all()
    assert state.redo() and np.array_equal(state.alive, ~first)
    state.select(arrays["means"][:, 1] > 0.9)
    state.delete_selected()  # a new edit drops the redo history
    assert not state.redo()
    # deleted Gaussians cannot be selected
    state.select(np.ones(200, bool))
    assert not (state.selected & ~state.alive).any()


def test_a_brush_stroke_is_one_undo_step():
    arrays = _arrays()
    state = editing.EditState(arrays)
    version = state.version
    state.select(arrays["means"][:, 0] > 0.5, "add")                          # the stroke's first dab
    state.select(arrays["means"][:, 1] > 0.5, "add", record=False)            # ... dragged on
    assert state.version == version  # selecting changes nothing drawn as splats
    assert state.undo() and not state.selected.any() and not state.undo()


def test_selection_modes():
    a = np.array([True, True, False, False])
    b = np.array([False, True, True, False])
    assert editing.combine_selection(a, b, "add").tolist() == [True, True, True, False]
    assert editing.combine_selection(a, b, "subtract").tolist() == [True, False, False, False]
    assert editing.combine_selection(a, b, "replace").tolist() == b.tolist()


# --- frustums -----------------------------------------------------------------------------

def test_frustum_corners_project_to_image_corners():
    cam = _camera(eye=(0.2, 0.3, -2.0))
    segments = frustums.frustum_segments(cam, depth=0.5)
    assert segments.shape == (8, 2, 3)
    np.testing.assert_allclose(segments[:4, 0], np.tile(cam.center, (4, 1)))
    pixels, depth = editing.project_means(segments[:4, 1], cam)
    np.testing.assert_allclose(pixels, [[0, 0], [64, 0], [64, 48], [0, 48]], atol=1e-9)
    np.testing.assert_allclose(depth, 0.5, atol=1e-12)
    assert frustums.segments_for_cameras([], 1.0).shape == (0, 2, 3)


# --- training thread wrapper ----------------------------------------------------------------

class _CountingJob:
    """Publishes a moving Gaussian every few milliseconds until told to stop."""

    def __init__(self, fail_at=None):
        self.fail_at = fail_at
        self.finished_cleanly = False

    def run(self, box, control):
        iteration = 0
        while not control.stop.is_set():
            if control.pause.is_set():
                time.sleep(0.005)
                continue
            iteration += 1
            if self.fail_at is not None and iteration == self.fail_at:
                raise RuntimeError("loss is NaN")
            arrays = _arrays(3)
            arrays["means"][:, 0] += iteration
            box.publish(iteration, arrays, {"loss": 1.0 / iteration})
            time.sleep(0.002)
        self.finished_cleanly = True


def test_live_training_pause_resume_stop():
    job = _CountingJob()
    run = LiveTraining(job)
    run.start()
    deadline = time.time() + 5
    while run.poll() is None and time.time() < deadline:
        time.sleep(0.01)
    assert run.state == "running" and run.progress.iteration >= 1
    run.pause()
    time.sleep(0.05)
    run.poll()
    paused_at = run.progress.iteration
    time.sleep(0.1)
    run.poll()
    assert run.state == "paused" and run.progress.iteration == paused_at
    run.resume()
    time.sleep(0.1)
    run.poll()
    assert run.progress.iteration > paused_at
    assert run.stop(timeout=5)
    assert job.finished_cleanly and run.state == "stopped"
    iterations, losses = run.progress.history["loss"]
    assert iterations == sorted(iterations) and all(l > 0 for l in losses)
    assert run.progress.gaussian_count == 3


def test_live_training_exception_is_reported_not_raised():
    run = LiveTraining(_CountingJob(fail_at=3))
    run.start()
    run._thread.join(5)
    assert run.state == "failed" and "loss is NaN" in run.error
    assert threading.current_thread().is_alive()


def test_a_log_line_after_a_model_does_not_hide_the_model():
    """The box has one slot: a reader that polls after a model and then a message were both
    published must still get the model (the job's last Gaussians are usually followed by its
    "finished" line)."""
    box = SnapshotBox()
    assert box.publish(0, None, {}, "starting") == 1
    assert box.latest(0).gaussians is None and box.latest(0).gaussians_version == 0
    arrays = _arrays(3)
    model_version = box.publish(5, arrays, {"loss": 0.5})
    box.publish(5, None, {}, "finished at iteration 5")
    newest = box.latest(0)
    assert newest.message == "finished at iteration 5" and newest.version == model_version + 1
    assert newest.gaussians is arrays and newest.gaussians_version == model_version
    replacement = _arrays(4)
    box.publish(6, replacement, {})
    assert box.latest(0).gaussians is replacement and box.latest(0).gaussians_version == model_version + 2



def test_poll_gaussians_returns_each_model_once():
    box = SnapshotBox()
    run = LiveTraining(_CountingJob(), box=box)
    assert run.poll_gaussians() is None
    model = _arrays(3)
    box.publish(1, model, {})
    box.publish(1, None, {}, "finished")
    assert run.poll_gaussians() is model and run.progress.message == "finished"
    box.publish(2, None, {}, "another line")
    assert run.poll_gaussians() is None and run.progress.message == "another line"

# --- reference comparison -------------------------------------------------------------------

def test_heatmap_and_side_by_side():
    a = np.zeros((4, 6, 3), np.float32)
    b = a.copy()
    b[0, 0] = 1.0  # one pixel fully wrong
    heat = reference.error_heatmap(a, b)
    assert heat.shape == (4, 6, 3) and heat[0, 0].tolist() == [1.0, 1.0, 0.0] and heat[1:].max() == 0
    both = reference.side_by_side(a, np.ones_like(a))
    assert both[:, :3].max() == 0 and both[:, 4:].min() == 1


def test_moving_render_scale_holds_the_budget_and_stays_sharp_when_shrinking_buys_nothing():
    drawing = pytest.importorskip("inceptiongs.app.drawing")
    pick, step, budget = drawing.next_moving_scale, drawing.MOVING_SCALE_STEP, drawing.MOVING_BUDGET_MS

    def settle(cost_of, scale=drawing.MOVING_RENDER_SCALE, frames=40):
        costs = {}
        for _ in range(frames):
            drawing.add_render_cost(costs, scale, cost_of(scale))
            scale = pick(scale, costs)
        return scale

    # Draw-bound: 10 ms fixed + 120 ms per full frame of pixels: the largest size within budget.
    scale = settle(lambda s: 10.0 + 120.0 * s * s)
    assert 10.0 + 120.0 * scale ** 2 <= budget and 10.0 + 120.0 * (scale + step) ** 2 > drawing.MOVING_GROW_SHARE * budget
    assert settle(lambda s: 3.0 + 5.0 * s * s) == 1.0  # cheap: the full size
    # Sort-bound (donut-like on a loaded machine: 53 ms whatever the size, 79 ms of pixels at
    # full size): no size holds 40 ms; it stops where a step down buys under 15 %, not at 1/4.
    scale = settle(lambda s: 53.0 + 79.0 * s * s, scale=1.0)
    assert scale > drawing.MOVING_SCALE_MIN
    cost = 53.0 + 79.0 * scale ** 2
    assert 53.0 + 79.0 * (scale - step) ** 2 > drawing.MOVING_SHRINK_GAIN * cost
    assert settle(lambda s: 5000.0 * s * s) == drawing.MOVING_SCALE_MIN  # pixel-bound and slow: the floor
    assert pick(0.5, {}) == 0.5  # no cost known yet: kept
    # A first slow render at 0.5 (a new texture, a busy machine) does not hold a cheap model at 0.375.
    assert pick(0.375, {0.5: 90.0, 0.375: 1.5}) == 0.5


def test_lasso_selects_inside_the_polygon():
    pixels = np.array([[5.0, 5.0], [15.0, 5.0], [5.0, 15.0], [1.0, 1.0], [np.nan, np.nan]])
    triangle = [(0.0, 0.0), (20.0, 0.0), (0.0, 20.0)]
    assert editing.select_lasso(pixels, triangle).tolist() == [True, False, False, True, False]
    # A concave "C": the notch is outside.
    c_shape = [(0, 0), (10, 0), (10, 3), (3, 3), (3, 7), (10, 7), (10, 10), (0, 10)]
    inside = editing.select_lasso(np.array([[1.0, 5.0], [6.0, 5.0], [6.0, 1.0]]), c_shape)
    assert inside.tolist() == [True, False, True]
    assert not editing.select_lasso(pixels, triangle[:2]).any()


def test_box_handles_and_face_drag():
    handles = editing.box_handles([0, 0, 0], [2, 4, 6])
    np.testing.assert_allclose(handles, [[0, 2, 3], [2, 2, 3], [1, 0, 3], [1, 4, 3], [1, 2, 0], [1, 2, 6]])
    lo, hi = editing.drag_box_face([0, 0, 0], [2, 4, 6], 3, 1.5)
    assert (lo, hi) == ([0, 0, 0], [2, 5.5, 6])
    lo, hi = editing.drag_box_face([0, 0, 0], [2, 4, 6], 0, 5.0)  # past the opposite face: stops there
    assert lo[0] == 2 and hi[0] == 2


def test_resume_on_a_same_time_baseline_says_what_it_is(tmp_path):
    """A same-time baseline run from the verdict's button became the open run and the greyed
    "resume" said it "would undo this bootstrap's repair": a baseline repairs nothing."""
    from inceptiongs.app.runs import resume_blocked_reason

    for name, targets in (("run_bootstrap", True), ("run_baseline", False)):
        (tmp_path / name / "bootstrap").mkdir(parents=True)
        (tmp_path / name / "bootstrap" / "config.json").write_text("{}")
        if targets:
            (tmp_path / name / "bootstrap" / "targets.json").write_text("[]")
    assert "undo this bootstrap's repair" in resume_blocked_reason(tmp_path / "run_bootstrap")
    baseline = resume_blocked_reason(tmp_path / "run_baseline")
    assert "same-time baseline" in baseline and "repair" not in baseline, baseline
    assert resume_blocked_reason(tmp_path) is None
