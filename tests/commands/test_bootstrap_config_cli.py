"""`inceptiongs bootstrap`: a short --help, every other setting through a strict --config file,
and docs/bootstrap_options.md generated from the same dataclass."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import sys
from pathlib import Path

import pytest

from inceptiongs.bootstrap.config import BootstrapConfig, checked_value, option
from inceptiongs.cli import build_parser, main
from inceptiongs.commands.bootstrap import config_from_args
from inceptiongs.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
GENERATOR = ROOT / "scripts" / "gen_bootstrap_options.py"
# What a user of the command needs on its own flag; everything else is in --config.
KEPT_FLAGS = {"--targets", "--target-view", "--out", "--overwrite", "--rounds", "--minutes", "--iterations",
              "--seed", "--config"}


def load_generator():
    spec = importlib.util.spec_from_file_location("gen_bootstrap_options", GENERATOR)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def bootstrap_parser():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return sub.choices["bootstrap"]


def help_flags(text: str) -> set[str]:
    """Every long or short flag that starts an entry of the printed options list."""
    section = text.split("options:", 1)[1]
    flags = set()
    for line in section.splitlines():
        stripped = line.strip()
        if line.startswith("  -") and stripped:
            flags.update(part.split()[0] for part in stripped.split(", ") if part.startswith("-"))
    return flags


def test_help_prints_at_most_twelve_options_and_the_ones_a_user_needs(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["bootstrap", "--help"])
    assert exit_info.value.code == 0
    printed = help_flags(capsys.readouterr().out) - {"-h", "--help"}
    assert KEPT_FLAGS <= printed, KEPT_FLAGS - printed
    assert len(printed) <= 12, sorted(printed)
    # The parser agrees with what was printed (no suppressed flag hides in it).
    declared = {flag for action in bootstrap_parser()._actions for flag in action.option_strings} - {"-h", "--help"}
    assert declared == printed


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, key, fragment", [
    ('{"no_such_thing": 1}', "no_such_thing", "unknown key"),
    ('{"ddim_step": 3}', "ddim_step", "did you mean 'ddim_steps'"),
    ('{"k": 2.5}', "k", "integer"),
    ('{"densify": 1}', "densify", "true or false"),
    ('{"iterations": true}', "iterations", "integer"),
    ('{"fill": 3}', "fill", "string"),
    ('{"tau": NaN}', "tau", "finite"),
    ('{"minutes": Infinity}', "minutes", "finite"),
    ('{"lambda_virtual": null}', "lambda_virtual", "null"),
    ('{"rounds": 0}', "rounds", ">= 1"),
    ('{"fill": "paint"}', "fill", "paint"),
    ('{"generated_weight": 1.5}', "generated_weight", "[0, 1]"),
    # The variants' sections are read as strictly.
    ('{"variants": {"alin": {}}}', "alin", "did you mean 'align'"),
    ('{"variants": {"align": {"max_shift": 2}}}', "variants.align.max_shift", "did you mean 'max_shift_px'"),
    ('{"variants": {"align": {"max_shift_px": "2"}}}', "variants.align.max_shift_px", "finite number"),
    ('{"variants": {"align": {"max_shift_px": Infinity}}}', "variants.align.max_shift_px", "finite"),
    ('{"variants": {"align": {"max_shift_px": -1}}}', "variants.align", "max_shift_px must be a positive"),
    ('{"variants": {"align": 2}}', "variants.align", "object"),
    ('{"variants": ["align"]}', "variants", "object"),
    ('{"variants": {"informative": {}}}', "variants.informative", "needs the variant photo_supervision"),
    # So are the flat keys of older files.
    ('{"align_p": 2}', "align_p", "did you mean 'align_px'"),
    ('{"align_px": NaN}', "align_px", "finite"),
    ('{"supervision": "photos"}', "supervision", "photos"),
    ('{"evidence_photos": 0}', "evidence", "photos must be >= 1"),
    ('{"virtual_colour": false}', "virtual_colour", "geometry_weight > 0"),
])
def test_a_bad_config_file_is_one_line_naming_the_file_and_the_key(tmp_path, capsys, text, key, fragment):
    bad = write(tmp_path / "settings.json", text)
    capsys.readouterr()
    status = main(["bootstrap", str(tmp_path / "run"), "--config", str(bad), "--out", str(tmp_path / "out")])
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(lines) == 1, lines
    assert str(bad) in lines[0] and key in lines[0] and fragment in lines[0], lines[0]
    assert not (tmp_path / "out").exists()


def test_no_suggestion_when_no_key_is_close(tmp_path):
    bad = write(tmp_path / "settings.json", '{"zzzzzz": 1}')
    with pytest.raises(InputError, match="unknown key 'zzzzzz'") as error:
        BootstrapConfig.load(bad)
    assert "did you mean" not in str(error.value)


def test_a_file_that_is_not_a_json_object_is_refused(tmp_path):
    for text in ("[1, 2]", "{not json"):
        with pytest.raises(InputError, match="settings.json"):
            BootstrapConfig.load(write(tmp_path / "settings.json", text))


def parse(*argv: str):
    return build_parser().parse_args(["bootstrap", "RUN", *argv])


def test_flags_given_override_the_file_and_the_rest_keep_the_file(tmp_path):
    settings = write(tmp_path / "settings.json", json.dumps(
        {"iterations": 120, "rounds": 2, "seed": 5, "minutes": 3, "k": 2, "variants": {"align": {"max_shift_px": 2}}}))
    from_file = config_from_args(parse("--config", str(settings)))
    assert (from_file.iterations, from_file.rounds, from_file.seed, from_file.minutes) == (120, 2, 5, 3.0)
    assert from_file.k == 2 and from_file.to_json_dict()["variants"] == {"align": {"max_shift_px": 2.0}}
    overridden = config_from_args(parse("--config", str(settings), "--iterations", "7", "--seed", "9"))
    assert (overridden.iterations, overridden.seed) == (7, 9)
    assert (overridden.rounds, overridden.minutes, overridden.k, overridden.variants) == \
        (2, 3.0, 2, from_file.variants)
    # No --config: the dataclass's defaults, with the flags given.
    assert config_from_args(parse("--rounds", "3")) == dataclasses.replace(BootstrapConfig(), rounds=3)
    assert config_from_args(parse()) == BootstrapConfig()


def test_a_bad_flag_value_is_still_refused_after_the_file(tmp_path, capsys):
    settings = write(tmp_path / "settings.json", '{"rounds": 2}')
    with pytest.raises(InputError, match="rounds"):
        config_from_args(parse("--config", str(settings), "--rounds", "0"))


def test_a_missing_lpips_file_named_in_the_config_is_refused(tmp_path):
    settings = write(tmp_path / "settings.json", json.dumps({"lpips_weights": str(tmp_path / "none.pt")}))
    with pytest.raises(InputError, match="lpips_weights"):
        config_from_args(parse("--config", str(settings)))


@pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")
def test_a_torchscript_lpips_file_named_in_a_shared_config_is_refused_before_it_loads(tmp_path, monkeypatch):
    """A config (or a stopped bootstrap's saved one) may come from someone else: a TorchScript
    file it names can create and overwrite files when loaded and run, so it is never loaded."""
    import torch

    class Distance(torch.nn.Module):
        def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
            return (a - b).abs().mean()

    torch.jit.script(Distance()).save(str(tmp_path / "lpips.pt"))
    loads = []
    monkeypatch.setattr(torch.jit, "load", lambda *args, **kwargs: loads.append(args))
    settings = write(tmp_path / "settings.json", json.dumps({"lpips_weights": str(tmp_path / "lpips.pt")}))
    with pytest.raises(InputError, match="TorchScript"):
        config_from_args(parse("--config", str(settings)))
    assert loads == []


def test_the_saved_config_reads_back_as_a_config_file(tmp_path):
    """RUN2/bootstrap/config.json is written by BootstrapConfig.save: every field, and it loads
    through --config to the same config (also with every optional field set)."""
    settings = write(tmp_path / "settings.json", json.dumps(
        {"k": 2, "l": 3, "delta": 0.05, "align_px": 2.5, "supervision": "photo", "virtual_pixels": "informative",
         "residual_floor": 0.02, "conscience_tolerance": None, "agreement_min_db": None, "densify": True,
         "lpips_weights": None, "prior_steps": 4, "langevin_step": 0.02, "langevin_noise": 0.0}))
    config = config_from_args(parse("--config", str(settings), "--minutes", "1.5"))
    # The flat keys of the file are in the variants' sections.
    assert config.to_json_dict()["variants"] == {"photo_supervision": {}, "align": {"max_shift_px": 2.5},
                                                 "informative": {"residual_floor": 0.02}, "densify": {}}
    saved = tmp_path / "RUN2" / "bootstrap" / "config.json"
    saved.parent.mkdir(parents=True)
    config.save(saved)
    assert set(json.loads(saved.read_text())) == {f.name for f in dataclasses.fields(BootstrapConfig)}
    assert config_from_args(parse("--config", str(saved))) == config
    BootstrapConfig().save(saved)
    assert BootstrapConfig.load(saved) == BootstrapConfig()


def test_every_field_type_is_one_the_strict_reader_knows():
    from inceptiongs.bootstrap.variants import VARIANT_NAMES, variant_class

    owners = [BootstrapConfig, *(variant_class(name) for name in VARIANT_NAMES)]
    for f in (f for cls in owners for f in dataclasses.fields(cls) if f.name != "variants"):
        stored = json.loads(json.dumps(f.default))
        assert checked_value(Path("x.json"), f.name, f.type, stored) == f.default, f.name
    # The variants' sections are read by their own reader: every variant's defaults read back.
    every = {name: {} for name in VARIANT_NAMES}
    assert BootstrapConfig(variants=every).to_json_dict()["variants"].keys() == every.keys()


def test_the_options_doc_is_generated_from_the_dataclass():
    generator = load_generator()
    text = (ROOT / "docs" / "bootstrap_options.md").read_text()
    assert text == generator.render_options_doc(), "run python3 scripts/gen_bootstrap_options.py"
    for f in dataclasses.fields(BootstrapConfig):
        assert f"| `{f.name}` |" in text and f.metadata["meaning"] in text


def test_the_doc_check_fails_on_a_changed_default_or_an_undocumented_field():
    generator = load_generator()
    current = generator.render_options_doc()

    @dataclasses.dataclass
    class ChangedDefault(BootstrapConfig):
        iterations: int = option(301, "refinement steps per round", "steps")

    changed = generator.render_options_doc(ChangedDefault)
    assert changed != current and "| `iterations` | integer | `301` |" in changed

    @dataclasses.dataclass
    class Undocumented(BootstrapConfig):
        new_knob: float = 1.0

    with pytest.raises(ValueError, match="new_knob"):
        generator.render_options_doc(Undocumented)


def test_a_non_finite_flag_is_refused_too(tmp_path, capsys):
    capsys.readouterr()
    assert main(["bootstrap", str(tmp_path / "run"), "--minutes", "nan", "--out", str(tmp_path / "out")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--minutes must be a finite number" in lines[0], lines
