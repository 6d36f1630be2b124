"""Property-based fuzzing of every number a user or a shared file can give, generated from the
code: every numeric flag of every command (read off the parsers) and every setting of the run
and bootstrap configurations and every camera JSON key (read off the dataclasses), each with
-1, 0, NaN, infinity, 1e12, text, null and a number written as a string. Whatever the value, the
command succeeds or exits 2 with one 'error:' line naming the flag or the file, never a
traceback (fuzz_values_cases.py lists what is drawn).

Most cases run the command in-process with its long work (training, sampling, the bootstrap
loop, the demo's stages) replaced by a stub that is reached only after every value was checked;
a few reach the real training loop at a tiny size (2 steps on the 4-view scene at downscale 4).
hypothesis runs derandomized (the same cases every run) without deadlines.
"""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from fuzz_values_cases import (FLAG_VALUES, JSON_VALUES, Reached, assert_one_line_or_success,
                               bootstrap_setting_cases, camera_key_cases, flag_arguments, flag_cases, nested, run_cli,
                               subparsers, train_setting_cases, train_setting_edges)
from shared_run_cases import save_tiny_prior, train_one_step, write_text_scene

pytestmark = pytest.mark.usefixtures("one_torch_thread")

FUZZ = settings(deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
FLAGS = flag_cases()


def _stub(*_args, **_kwargs):
    raise Reached()


def _placeholders(command: str) -> list[str]:
    """Arguments a command needs besides the fuzzed flag, for the parse-level cases."""
    parser = subparsers()[command]
    argv = []
    for action in parser._actions:
        if not action.option_strings and action.dest not in ("help",):
            argv += ["X"] * (action.nargs if isinstance(action.nargs, int) else 1)
        elif action.required:
            argv += [action.option_strings[0], "X.png"]
    for group in parser._mutually_exclusive_groups:
        if group.required:
            argv += [group._group_actions[0].option_strings[0], "X"]
    return argv


# --- every flag, every value, at the parser ---------------------------------------------------------
def test_every_command_has_its_numeric_flags_found():
    commands = {command for command, _ in FLAGS}
    assert {"train", "prior", "generate", "bootstrap", "demo", "demo-scene", "render", "eval"} <= commands
    assert ("prior", "--unet-width") in FLAGS and ("generate", "--window") in FLAGS


@pytest.mark.parametrize("command, flag", FLAGS)
def test_a_flag_value_is_parsed_or_refused_in_one_line(command, flag, monkeypatch):
    """Parse level: every command's run is a stub, so only the flag's rule decides."""
    import inceptiongs.cli as cli

    modules = cli.available_commands()
    for module in modules.values():
        monkeypatch.setattr(module, "run", _stub)
    parser = subparsers()[command]
    for value in FLAG_VALUES:
        status, stderr = run_cli([command, *_placeholders(command), *flag_arguments(parser, flag, value)])
        assert_one_line_or_success(status, stderr, flag, (command, flag, value))
        if value in ("nan", "inf", "-inf", "text", "null"):
            assert status == 2, (command, flag, value)   # never a number, whatever the rule


# --- the commands themselves, on a real scene, run and prior --------------------------------------------
@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A 4-view scene, a one-step run on it, a tiny untrained prior saved in the run, a camera."""
    from inceptiongs.camera import write_camera_json
    from inceptiongs.runs.load import load_run

    root = tmp_path_factory.mktemp("fuzz_values")
    scene, run = root / "scene", root / "run"
    names = write_text_scene(scene)
    train_one_step(scene, run)
    save_tiny_prior(run)
    _, loaded, _ = load_run(run)
    camera = root / "camera.json"
    write_camera_json(loaded.normalization.camera_to_original(loaded.cameras[0]), camera)
    return {"root": root, "scene": scene, "run": run, "view": names[1], "camera": camera}


def _command_line(command: str, world, out) -> list[str]:
    """A valid command line of ``command`` on the world, writing below ``out``."""
    run, scene = str(world["run"]), str(world["scene"])
    return {
        "train": ["train", scene, "--out", str(out / "r"), "--device", "cpu"],
        "prior": ["prior", run, "--device", "cpu"],
        "generate": ["generate", run, "--view", world["view"], "--out", str(out / "g.png"), "--device", "cpu"],
        "bootstrap": ["bootstrap", run, "--out", str(out / "b"), "--target-view", world["view"]],
        "eval": ["eval", run, "--device", "cpu"],
        "render": ["render", str(world["run"] / "model.ply"), "--camera", str(world["camera"]),
                   "--out", str(out / "x.png"), "--backend", "torch", "--device", "cpu"],
        "coverage": ["coverage", scene, "--out", str(out / "c.png")],
        "demo": ["demo", str(out / "d"), "--device", "cpu"],
        "demo-scene": ["demo-scene", str(out / "s")],
    }[command]


def _stub_long_work(monkeypatch) -> None:
    """Each command's long work, reached only once its values were checked, raises Reached."""
    import inceptiongs.bootstrap.runner as runner
    import inceptiongs.commands.demo as demo
    import inceptiongs.commands.demo_scene as demo_scene
    import inceptiongs.evaluation.coverage_map as coverage_map
    import inceptiongs.evaluation.run as evaluation_run
    import inceptiongs.prior.model as model
    import inceptiongs.prior.trainer as prior_trainer
    import inceptiongs.train.trainer as trainer

    monkeypatch.setattr(trainer, "train", _stub)
    monkeypatch.setattr(prior_trainer.PriorTrainer, "train", _stub)
    monkeypatch.setattr(model.Prior, "generate", _stub)
    monkeypatch.setattr(runner, "load_stage1", _stub)
    monkeypatch.setattr(evaluation_run, "evaluate_run", _stub)
    monkeypatch.setattr(coverage_map, "scene_coverage", _stub)
    monkeypatch.setattr(demo, "_stage1", _stub)
    for name in ("write_courtyard_scene", "write_demo_scene", "write_town_scene"):
        monkeypatch.setattr(demo_scene, name, _stub)


RUN_FLAGS = [case for case in FLAGS if case[0] in ("train", "prior", "generate", "bootstrap", "eval", "render",
                                                   "coverage", "demo", "demo-scene")]


@settings(FUZZ, max_examples=80)
@given(case=st.sampled_from(RUN_FLAGS), value=st.sampled_from(FLAG_VALUES))
def test_a_command_given_any_flag_value_runs_or_refuses_in_one_line(world, tmp_path_factory, monkeypatch, case, value):
    command, flag = case
    _stub_long_work(monkeypatch)
    out = tmp_path_factory.mktemp("case")
    status, stderr = run_cli([*_command_line(command, world, out), *flag_arguments(subparsers()[command], flag, value)])
    assert_one_line_or_success(status, stderr, "", (command, flag, value))


# --- every config key and camera key --------------------------------------------------------------------
@pytest.mark.parametrize("key", train_setting_cases())
def test_a_train_setting_of_any_value_is_used_or_refused_in_one_line(world, tmp_path, monkeypatch, key):
    _stub_long_work(monkeypatch)
    for number, value in enumerate(JSON_VALUES):
        settings_file = tmp_path / f"settings_{number}.json"
        settings_file.write_text(json.dumps(nested(key, value)))
        status, stderr = run_cli(["train", str(world["scene"]), "--out", str(tmp_path / f"r{number}"),
                                  "--config", str(settings_file), "--device", "cpu"])
        assert_one_line_or_success(status, stderr, str(settings_file), (key, value))
        if isinstance(value, float) and not math.isfinite(value):
            assert status == 2 and key in stderr, (key, value, stderr)


@pytest.mark.parametrize("key", bootstrap_setting_cases())
def test_a_bootstrap_setting_of_any_value_is_used_or_refused_in_one_line(world, tmp_path, monkeypatch, key):
    _stub_long_work(monkeypatch)
    for number, value in enumerate(JSON_VALUES):
        settings_file = tmp_path / f"settings_{number}.json"
        settings_file.write_text(json.dumps({key: value}))
        status, stderr = run_cli(["bootstrap", str(world["run"]), "--out", str(tmp_path / f"b{number}"),
                                  "--target-view", world["view"], "--config", str(settings_file)])
        assert_one_line_or_success(status, stderr, str(settings_file), (key, value))
        if isinstance(value, float) and not math.isfinite(value):
            assert status == 2 and key in stderr, (key, value, stderr)


@pytest.mark.parametrize("key", camera_key_cases())
def test_a_camera_key_of_any_value_renders_or_is_refused_in_one_line(world, tmp_path, key):
    camera = json.loads(world["camera"].read_text())
    for number, value in enumerate(JSON_VALUES):
        path = tmp_path / f"camera_{number}.json"
        path.write_text(json.dumps({**camera, key: value}))
        status, stderr = run_cli(["render", str(world["run"] / "model.ply"), "--camera", str(path), "--out",
                                  str(tmp_path / "x.png"), "--backend", "torch", "--device", "cpu"])
        assert_one_line_or_success(status, stderr, str(path), (key, value))
        if not isinstance(value, (int, float)) or key in ("width", "height") and not float(value).is_integer():
            assert status == 2, (key, value)   # text or null is no number, a fraction no image side


# --- the training loop itself, at a tiny size ----------------------------------------------------------
@settings(FUZZ, max_examples=12)
@given(case=st.sampled_from(train_setting_edges()))
def test_training_two_steps_at_a_setting_edge_finishes_or_refuses_in_one_line(world, tmp_path_factory, case):
    """The real loop (2 steps on the 4-view scene at downscale 4) with one setting at an edge of
    what its reader accepts: the run finishes, or one line says what cannot be used."""
    key, value = case
    out = tmp_path_factory.mktemp("loop")
    settings_file = out / "settings.json"
    given_settings = nested(key, value)
    if not key.startswith("free_space."):
        given_settings["free_space"] = {"sky_shell": False}     # the 4-view scene has no sky
    settings_file.write_text(json.dumps(given_settings))
    status, stderr = run_cli(["train", str(world["scene"]), "--out", str(out / "r"), "--iterations", "2",
                              "--downscale", "4", "--config", str(settings_file), "--device", "cpu"])
    assert_one_line_or_success(status, stderr, "", case)
    if status == 0:
        assert (out / "r" / "model.ply").is_file()
