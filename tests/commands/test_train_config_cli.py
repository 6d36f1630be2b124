"""`inceptiongs train`: a short --help, every other setting through a strict --config file of
TrainConfig's sections, docs/train_options.md generated from the same dataclasses, and the flat
config.json of run folders written before the sections loading into them with the same values."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import math
import sys
from pathlib import Path

import pytest

from inceptiongs.cli import build_parser, main
from inceptiongs.commands import train as train_command
from inceptiongs.errors import InputError
from inceptiongs.io.config_json import config_value, setting_paths, with_values
from inceptiongs.runs.config import (FLAT_KEYS, SCHEDULE_FIELDS, TrainConfig, read_settings, short_run_schedule,
                                     sized_schedule)

ROOT = Path(__file__).resolve().parents[2]
GENERATOR = ROOT / "scripts" / "gen_train_options.py"
# A run's config.json exactly as stage I wrote it before the sections (150 iterations of the tiny
# demo courtyard, unstructured protocol; only the scene path differs).
FLAT_FILE = Path(__file__).with_name("flat_run_config.json")
# Where every key of that file lands: written out here, not derived from FLAT_KEYS.
FLAT_TO_NESTED = {
    "camera_ball": "free_space.camera_ball", "camera_sigmas": "free_space.camera_sigmas",
    "checkpoint_every": "output.checkpoint_every", "densify_every": "densification.densify_every",
    "densify_from": "densification.densify_from", "densify_grad_threshold": "densification.densify_grad_threshold",
    "densify_until": "densification.densify_until", "device": "device", "downscale": "downscale",
    "eval_every": "output.eval_every", "exclude_photos": "exclude_photos", "free_space": "free_space.enabled",
    "iterations": "iterations", "keep_checkpoints": "output.keep_checkpoints",
    "lambda_dssim": "losses.lambda_dssim", "lambda_flatten": "pgsr_terms.lambda_flatten",
    "lambda_geo": "pgsr_terms.lambda_geo", "lambda_ncc": "pgsr_terms.lambda_ncc",
    "lambda_normal": "pgsr_terms.lambda_normal", "log_every": "output.log_every",
    "lr_log_scales": "learning_rates.log_scales", "lr_means": "learning_rates.means",
    "lr_means_final": "learning_rates.means_final", "lr_opacity": "learning_rates.opacity",
    "lr_quats": "learning_rates.quats", "lr_sh_dc": "learning_rates.sh_dc", "lr_sh_rest": "learning_rates.sh_rest",
    "max_gaussians": "densification.max_gaussians", "max_width": "max_width", "minutes": "minutes",
    "multiview_every": "pgsr_terms.multiview_every", "multiview_from": "pgsr_terms.multiview_from",
    "multiview_pixel_noise_max": "pgsr_terms.multiview_pixel_noise_max",
    "multiview_scale": "pgsr_terms.multiview_scale", "ncc_patch_radius": "pgsr_terms.ncc_patch_radius",
    "ncc_samples": "pgsr_terms.ncc_samples", "near_margin": "free_space.near_margin",
    "near_percentile": "free_space.near_percentile", "neighbours_max": "pgsr_terms.neighbours_max",
    "neighbours_max_angle_deg": "pgsr_terms.neighbours_max_angle_deg", "normal_from": "pgsr_terms.normal_from",
    "opacity_reset_every": "densification.opacity_reset_every", "percent_dense": "densification.percent_dense",
    "pgsr": "pgsr", "protocol": "protocol", "prune_large_from": "densification.prune_large_from",
    "prune_opacity": "densification.prune_opacity", "prune_screen_radius": "densification.prune_screen_radius",
    "prune_world_fraction": "densification.prune_world_fraction", "random_background": "losses.random_background",
    "scarce_views": "scarce_views", "scene": "scene", "see_through_min_views": "free_space.see_through_min_views",
    "see_through_tolerance": "free_space.see_through_tolerance", "seed": "seed",
    "sh_degree_max": "sh.degree_max", "sh_increase_every": "sh.increase_every", "sh_min_views": "sh.min_views",
    "sh_spread_deg_per_degree": "sh.spread_deg_per_degree", "size_to_minutes": "size_to_minutes",
    "sky_min_scale": "free_space.sky_min_scale", "sky_shell": "free_space.sky_shell", "strategy": "strategy",
    "triangulate_init": "triangulate_init",
    "mcmc": "mcmc", "dropgaussian": "dropgaussian",
}
# What a user of the command needs on its own flag; everything else is in --config. Two more come
# with the large-capture work, so the help stays within 16 options then.
KEPT_FLAGS = {"--out", "--config", "--minutes", "--iterations", "--downscale", "--protocol", "--seed", "--device",
              "--resume", "--strategy", "--exclude-photos", "--prior", "--prior-backend", "--sd-path", "--blocks",
              "--photo-memory"}
# The parser's own, present in every command.
COMMON_FLAGS = {"-h", "--help", "--debug", "--cache-dir"}


def load_generator():
    spec = importlib.util.spec_from_file_location("gen_train_options", GENERATOR)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def train_parser():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return sub.choices["train"]


def help_flags(text: str) -> set[str]:
    """Every long or short flag that starts an entry of the printed options lists."""
    flags = set()
    for line in text.split("options:", 1)[1].splitlines():
        stripped = line.strip()
        if line.startswith("  -") and stripped:
            flags.update(part.split()[0] for part in stripped.split(", ") if part.startswith("-"))
    return flags


def _args(*argv: str) -> argparse.Namespace:
    return train_parser().parse_args(["/some/scene", *argv])


def _settings(tmp_path: Path, content, name: str = "settings.json") -> Path:
    path = tmp_path / name
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    return path


# --- the command line ---------------------------------------------------------------------------------

def test_help_prints_at_most_sixteen_options_and_points_to_the_settings_page(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    printed = help_flags(text) - COMMON_FLAGS
    assert printed == KEPT_FLAGS, printed ^ KEPT_FLAGS
    assert len(printed) <= 16
    declared = {flag for action in train_parser()._actions for flag in action.option_strings} - COMMON_FLAGS
    assert declared == printed                      # no suppressed flag hides in the parser
    assert "docs/train_options.md" in " ".join(text.split())


def test_the_settings_of_the_folded_flags_are_reachable_through_config(tmp_path):
    settings = _settings(tmp_path, {"pgsr": False, "free_space": {"enabled": False, "sky_shell": False,
                                                                  "sky_min_scale": 0.0}})
    config = train_command.build_config(_args("--config", str(settings), "--iterations", "300"))
    assert not config.pgsr and config.free_space == dataclasses.replace(
        TrainConfig().free_space, enabled=False, sky_shell=False, sky_min_scale=0.0)
    page = (ROOT / "docs" / "train_options.md").read_text()
    for key in ('{"pgsr": false}', '{"free_space": {"enabled": false}}', '{"free_space": {"sky_shell": false}}',
                '{"free_space": {"sky_min_scale": 0}}'):
        assert key in page, key


def test_no_config_builds_the_command_lines_schedule():
    """Without --config the flags alone make the config, as `train` always made it."""
    config = train_command.build_config(_args("--iterations", "150", "--protocol", "unstructured", "--seed", "3"))
    expected = short_run_schedule(TrainConfig(scene=str(Path("/some/scene").resolve()), iterations=150,
                                              protocol="unstructured", seed=3))
    assert config == expected
    assert config.densification.densify_until == 75 and config.pgsr_terms.normal_from == 35
    assert train_command.build_config(_args()).protocol == "llff"             # the command line's default


def test_config_gives_any_subset_and_flags_given_override_it(tmp_path):
    settings = _settings(tmp_path, {"seed": 7, "protocol": "none", "strategy": "mcmc", "downscale": 2,
                                    "losses": {"lambda_dssim": 0.3}, "mcmc": {"growth": 0.2},
                                    "output": {"eval_every": 50}})
    config = train_command.build_config(_args("--config", str(settings), "--iterations", "3000"))
    assert (config.seed, config.protocol, config.strategy, config.downscale) == (7, "none", "mcmc", 2)
    assert config.losses == dataclasses.replace(TrainConfig().losses, lambda_dssim=0.3)
    assert config.mcmc.growth == 0.2 and config.mcmc.noise_lr == TrainConfig().mcmc.noise_lr
    assert config.output.eval_every == 50 and config.output.log_every == TrainConfig().output.log_every
    flagged = train_command.build_config(_args("--config", str(settings), "--iterations", "3000", "--seed", "1",
                                               "--protocol", "llff", "--strategy", "default", "--downscale", "4"))
    assert (flagged.seed, flagged.protocol, flagged.strategy, flagged.downscale) == (1, "llff", "default", 4)
    assert flagged.losses.lambda_dssim == 0.3                                   # not a flag: the file's


def test_milestones_the_file_gives_are_kept_the_others_scale(tmp_path):
    settings = _settings(tmp_path, {"densification": {"densify_until": 2500}, "iterations": 3000})
    config = train_command.build_config(_args("--config", str(settings)))
    scaled = short_run_schedule(TrainConfig(scene=config.scene, iterations=3000, protocol="llff"))
    assert config.iterations == 3000 and config.densification.densify_until == 2500   # as given, not scaled
    for path in SCHEDULE_FIELDS:
        if path != "densification.densify_until":
            assert config_value(config, path) == config_value(scaled, path), path
    # --iterations overrides the file's length; the file's milestone stays.
    longer = train_command.build_config(_args("--config", str(settings), "--iterations", "6000"))
    assert longer.iterations == 6000 and longer.densification.densify_until == 2500
    # A budget alone sizes the schedule, which sets every milestone: the file may not give one.
    budget = _settings(tmp_path, {"densification": {"densify_until": 2500}}, "budget.json")
    with pytest.raises(InputError, match=r"budget.json: densification.densify_until is a step of the schedule"):
        train_command.build_config(_args("--config", str(budget), "--minutes", "3"))
    sized = train_command.build_config(_args("--config", str(_settings(tmp_path, {"minutes": 2}, "m.json"))))
    assert sized.size_to_minutes and sized.minutes == 2 and sized.iterations == 140


def test_the_resolved_config_is_written_nested_to_the_run_folder(tmp_path):
    from demo_cases import copy_of_demo_scene

    scene = copy_of_demo_scene(tmp_path / "scene")
    settings = _settings(tmp_path, {"pgsr": False, "free_space": {"sky_shell": False},
                                    "output": {"eval_every": 1}})
    run = tmp_path / "run"
    assert main(["train", str(scene), "--out", str(run), "--config", str(settings), "--iterations", "2",
                 "--downscale", "4", "--protocol", "none", "--device", "cpu"]) == 0
    stored = json.loads((run / "config.json").read_text())
    assert stored["pgsr"] is False and stored["free_space"]["sky_shell"] is False
    assert stored["output"]["eval_every"] == 1 and stored["iterations"] == 2 and stored["downscale"] == 4
    assert "lambda_dssim" not in stored and stored["losses"]["lambda_dssim"] == 0.2
    assert TrainConfig.load(run / "config.json") == train_command.build_config(
        train_parser().parse_args([str(scene), "--config", str(settings), "--iterations", "2", "--downscale", "4",
                                   "--protocol", "none", "--device", "cpu"]))
    # A resume keeps the run's settings: --config is refused, before anything is read.
    assert main(["train", str(scene), "--out", str(run), "--resume", "--config", str(settings)]) == 2


@pytest.mark.parametrize("content, message", [
    ({"lambda_dssim": 0.3}, "unknown key 'lambda_dssim' (did you mean 'losses.lambda_dssim'?)"),
    ({"lr_means": 1e-4}, "unknown key 'lr_means' (did you mean 'learning_rates.means'?)"),
    ({"losses": {"lamda_dssim": 0.3}}, "unknown key 'losses.lamda_dssim' (did you mean 'losses.lambda_dssim'?)"),
    ({"densification": {"densify_util": 10}}, "did you mean 'densification.densify_until'?"),
    ({"bogus": 1}, "unknown key 'bogus'"),
    ({"iterations": "300"}, "iterations must be an integer, got \"300\""),
    ({"iterations": 3.5}, "iterations must be an integer, got 3.5"),
    ({"pgsr": 0}, "pgsr must be true or false, got 0"),
    ({"losses": {"lambda_dssim": "NaN"}}, "losses.lambda_dssim must be a finite number"),
    ('{"losses": {"lambda_dssim": NaN}}', "losses.lambda_dssim must be a finite number, got NaN"),
    ('{"mcmc": {"noise_lr": Infinity}}', "mcmc.noise_lr must be a finite number, got Infinity"),
    ({"losses": {"lambda_dssim": 1.5}}, r"losses.lambda_dssim must be in [0, 1] (weight), got 1.5"),
    ({"free_space": {"camera_ball": -0.1}}, "free_space.camera_ball must be in [0, 1]"),
    ({"sh": {"degree_max": 4}}, "sh.degree_max must be in [0, 3]"),
    ({"output": {"log_every": 0}}, "output.log_every must be >= 1"),
    ({"strategy": "adc"}, "strategy must be one of default, mcmc, dropgaussian, got 'adc'"),
    ({"protocol": "random"}, "protocol must be one of llff, unstructured, none"),
    ({"losses": 0.2}, "losses must be an object"),
    ({"scarce_views": "a,b"}, "scarce_views must be a list of strings"),
    ({"scene": "/x"}, "scene is not a settings key"),
    ({"size_to_minutes": True}, "size_to_minutes is not a settings key"),
    ({"scarce_views": ["a"], "protocol": "llff"}, "scarce_views need the unstructured protocol"),
    ("[1, 2]", "must be an object"),
    ("{", "not a readable train settings JSON"),
])
def test_a_bad_settings_file_is_one_line_naming_the_file_and_the_key(tmp_path, capsys, content, message):
    settings = _settings(tmp_path, content)
    assert main(["train", str(tmp_path), "--config", str(settings), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {settings}") and err.count("\n") == 1, err
    assert message in err, err
    assert not (tmp_path / "run").exists()


def test_read_settings_returns_only_the_keys_given(tmp_path):
    given = read_settings(_settings(tmp_path, {"minutes": 3, "free_space": {"camera_ball": 0}, "mcmc": {}}))
    assert given == {"minutes": 3.0, "free_space.camera_ball": 0.0}
    assert isinstance(given["minutes"], float)   # an integer in the file, a float setting


# --- the settings page ----------------------------------------------------------------------------------

def test_options_page_is_generated_from_the_dataclasses():
    generator = load_generator()
    text = (ROOT / "docs" / "train_options.md").read_text()
    assert text == generator.render_options_doc(), "run python3 scripts/gen_train_options.py"
    for path in setting_paths(TrainConfig):
        assert f"| `{path}` |" in text, path
    for flat, path in FLAT_KEYS.items():
        if flat != path.rsplit(".", 1)[-1]:
            assert f"| `{flat}` | `{path}` |" in text, flat


def test_every_setting_says_what_it_means_and_its_default_is_in_range():
    generator = load_generator()
    undocumented = dataclasses.make_dataclass("Undocumented", [("x", int, dataclasses.field(default=1))])
    with pytest.raises(ValueError, match="no meaning"):
        generator.option_sections(undocumented)
    TrainConfig().validate("defaults")   # every default within its own range and choices


# --- run folders written before the sections -------------------------------------------------------------

def test_a_flat_run_config_loads_every_value_into_its_section():
    flat = json.loads(FLAT_FILE.read_text())
    assert set(flat) == set(FLAT_TO_NESTED)
    config = TrainConfig.load(FLAT_FILE)
    for key, path in FLAT_TO_NESTED.items():
        value = config_value(config, path)
        assert (dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value) == flat[key], key
    # Written again it is nested, and loads back the same.
    assert TrainConfig.from_json_dict(config.to_json_dict(), "nested") == config


def _changed(key: str, value):
    """A value other than ``value`` that the setting of flat ``key`` accepts."""
    if isinstance(value, bool):
        return not value
    if key == "sh_degree_max":
        return value - 1
    if isinstance(value, int):
        return value + 7
    if isinstance(value, float):
        return value * 0.5 + 0.001        # a zero default moves too; every range still holds it
    return {"protocol": "llff", "device": "cpu", "strategy": "mcmc", "scene": "/elsewhere", "scarce_views": [],
            "exclude_photos": ["000.png"], "max_width": 640, "minutes": 2.5}[key]


def test_every_key_of_a_flat_file_reaches_its_own_setting(tmp_path):
    """Each key of the flat file changed alone changes exactly its own setting (so no key lands
    in another setting, or nowhere); the strategies' flat keys of older files too."""
    flat = json.loads(FLAT_FILE.read_text())
    base = TrainConfig.load(FLAT_FILE)
    paths = setting_paths(TrainConfig)
    strategy_keys = {"mcmc_noise_lr": "mcmc.noise_lr", "mcmc_opacity_reg": "mcmc.opacity_reg",
                     "mcmc_scale_reg": "mcmc.scale_reg", "mcmc_dead_opacity": "mcmc.dead_opacity",
                     "mcmc_growth": "mcmc.growth", "drop_rate_max": "dropgaussian.rate_max"}
    older = {key: value for key, value in flat.items() if key not in ("mcmc", "dropgaussian")}
    older.update({key: config_value(base, path) for key, path in strategy_keys.items()})
    assert TrainConfig.from_json_dict(older, "older") == base
    cases = [(flat, key, FLAT_TO_NESTED[key]) for key in flat if key not in ("mcmc", "dropgaussian")]
    cases += [(older, key, path) for key, path in strategy_keys.items()]
    for data, key, path in cases:
        value = _changed(key, data[key])
        if key == "scarce_views":      # names of the scarce cluster need the unstructured protocol (it is)
            value = ["000.png"]
        config = TrainConfig.from_json_dict({**data, key: value}, "one key")
        moved = [p for p in paths if config_value(config, p) != config_value(base, p)]
        assert moved == [path], (key, moved)
        assert config_value(config, path) == value, key


def test_commands_that_read_a_run_open_a_flat_run_folder(tmp_path, capsys):
    """eval, render and the run loader read a run folder whose config.json is flat, with the
    schedule it trained (the bootstrap's continuation of it too)."""
    from inceptiongs.bootstrap.refine import continuation_config
    from inceptiongs.runs.load import load_run
    from shared_run_cases import train_one_step

    from demo_cases import copy_of_demo_scene

    scene = copy_of_demo_scene(tmp_path / "scene")
    run = tmp_path / "run"
    train_one_step(scene, run)
    nested = TrainConfig.load(run / "config.json")
    flat = {}
    for key, path in FLAT_TO_NESTED.items():
        value = config_value(nested, path)
        flat[key] = dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value
    (run / "config.json").write_text(json.dumps(flat, indent=2, sort_keys=True))
    gaussians, _, config = load_run(run)
    assert config == nested and len(gaussians) > 0
    assert continuation_config(config, 1, 10) == continuation_config(nested, 1, 10)
    view = load_run(run)[1].cameras[0].name
    assert main(["render", str(run), "--view", view, "--backend", "torch", "--out", str(tmp_path / "v.png")]) == 0
    assert (tmp_path / "v.png").is_file()
    assert main(["eval", str(run)]) == 0
    assert json.loads((run / "eval" / "eval.json").read_text())["protocol"] == config.protocol


def test_a_sized_schedule_is_the_same_for_a_config_from_a_flat_file(tmp_path):
    config = TrainConfig.load(FLAT_FILE)
    resized = sized_schedule(config, 600)
    assert resized.densification.densify_until == 300 and resized.pgsr_terms.normal_from == 140
    assert resized == sized_schedule(with_values(config, {"densification.densify_until": 9}), 600)
    assert math.isclose(resized.learning_rates.means, 1.6e-4)
