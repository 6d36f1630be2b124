"""The variants' door (inceptiongs/bootstrap/variants.py) and the files written before the variants
had sections: they load into the sections, as strictly as ever."""

from __future__ import annotations

import copy
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest

from inceptiongs.bootstrap.config import BootstrapConfig
from inceptiongs.bootstrap.variants import VARIANT_CLASSES, VARIANT_NAMES, Variant, variant_class
from inceptiongs.errors import InputError

# RUN2/bootstrap/config.json as a bootstrap with every default wrote it before the variants had
# sections (`inceptiongs bootstrap run --config F` with F = {"follow_outlook": false}, 40 iterations).
FLAT_FILE = {
    "agreement_min_db": -1.0, "align_px": None, "blending": True, "checkpoint_every": 200, "conscience_every": 25,
    "conscience_tolerance": 0.05, "ddim_steps": 10, "delta": None, "densify": False, "eval_every": 0,
    "evidence_min_fraction": 0.05, "evidence_photos": 6, "fill": "render", "follow_outlook": False,
    "generated_weight": 1.0, "geometry_samples": 4096, "geometry_weight": 0.0, "include_target": True,
    "iterations": 40, "k": None, "l": None, "lambda_virtual": 1.0, "langevin_noise": None, "langevin_step": None,
    "log_every": 10, "lpips_weights": None, "max_virtual_views": 64, "minutes": None, "placement": "paths",
    "prior": "trained", "prior_minutes": 2.0, "prior_steps": None, "regenerate_every": 50, "residual_floor": None,
    "rounds": 1, "sampling": "langevin", "save_views": 4, "seed": 0, "splat_views": 8, "supervision": "blend",
    "tau": 0.2, "virtual_colour": True, "virtual_depth": "auto", "virtual_every": 4, "virtual_mode": "alternate",
    "virtual_pixels": "all"}


def write(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    return path


def test_a_flat_file_of_the_default_path_loads_as_the_default_and_loads_no_variant(tmp_path):
    # (Such files wrote tau 0.2, then the default; it is kept as the setting the run was made with.)
    path = write(tmp_path / "config.json", FLAT_FILE)
    script = (f"import sys; from inceptiongs.bootstrap.config import BootstrapConfig as B; "
              f"c = B.load({str(path)!r}); print(c == __import__('dataclasses').replace(B(), iterations=40, "
              f"follow_outlook=False, tau=0.2), sorted(m for m in sys.modules if 'bootstrap.experimental' in m))")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.split() == ["True", "[]"], out.stdout + out.stderr


def test_flat_keys_choose_their_variants_with_their_options(tmp_path):
    given = {"supervision": "photo", "align_px": 2.0, "placement": "evidence"}
    config = BootstrapConfig.load(write(tmp_path / "settings.json", given))
    assert config.to_json_dict()["variants"] == {"photo_supervision": {}, "align": {"max_shift_px": 2.0},
                                                 "evidence": {"min_fraction": 0.05, "photos": 6}}
    # Every flat key of a file of the time, each non-default, in a full file.
    every = {**FLAT_FILE, "supervision": "photo", "virtual_pixels": "informative", "residual_floor": 0.02,
             "virtual_mode": "additive", "geometry_weight": 0.6, "geometry_samples": 512, "virtual_colour": False,
             "placement": "evidence", "evidence_min_fraction": 0.1, "evidence_photos": 3, "densify": True,
             "fill": "inpaint", "align_px": 1.5}
    config = BootstrapConfig.load(write(tmp_path / "every.json", every))
    # Every variant a flat key chooses (the fixer has only its section), in the table's order.
    assert config.fill == "render" and list(config.variants) == [n for n in VARIANT_NAMES if n != "fixer"]
    assert config.to_json_dict()["variants"] == {
        "photo_supervision": {}, "inpaint": {}, "align": {"max_shift_px": 1.5}, "informative": {"residual_floor": 0.02},
        "additive": {}, "geometry": {"weight": 0.6, "samples": 512, "colour": False},
        "evidence": {"min_fraction": 0.1, "photos": 3}, "densify": {}}
    # What is saved now reads back to the same config; so does the flat file.
    config.save(tmp_path / "saved.json")
    assert BootstrapConfig.load(tmp_path / "saved.json") == config
    assert not set(json.loads((tmp_path / "saved.json").read_text())) & {"supervision", "align_px", "placement"}
    # A file of the time with a section added: the flat keys' old defaults give way to the section.
    mixed = {**FLAT_FILE, "variants": {"evidence": {"photos": 3}}}
    config = BootstrapConfig.load(write(tmp_path / "mixed.json", mixed))
    assert config.to_json_dict()["variants"] == {"evidence": {"min_fraction": 0.05, "photos": 3}}


def test_a_checkpoints_flat_config_loads_into_the_sections():
    """A checkpoint's "bootstrap" entry holds the config as it was written then."""
    payload = {"bootstrap": {"round": 1, "config": {**FLAT_FILE, "supervision": "photo", "fill": "prior"},
                             "pose": None}}
    config = BootstrapConfig.from_json(copy.deepcopy(payload["bootstrap"]["config"]), "step_000200.pt: bootstrap")
    assert config.fill == "prior" and list(config.variants) == ["photo_supervision"]
    with pytest.raises(InputError, match="step_000200.pt: bootstrap: supervision must be one of"):
        BootstrapConfig.from_json({**FLAT_FILE, "supervision": "sketch"}, "step_000200.pt: bootstrap")


def test_flat_keys_are_as_strict_as_they_were(tmp_path):
    cases = [({"align_px": 0.0}, "max_shift_px must be a positive"),           # chosen, out of range
             ({"geometry_weight": -1.0}, "weight must be > 0"),
             ({"residual_floor": -0.1}, "residual_floor must be >= 0"),         # not chosen: still checked
             ({"evidence_min_fraction": 1.5}, "min_fraction must be in (0, 1]"),
             ({"geometry_samples": 1.5}, "geometry_samples must be an integer"),
             ({"densify": "yes"}, "densify must be true or false"),
             ({"virtual_pixels": "informative"}, "needs the variant photo_supervision"),
             ({"align_px": 2.0, "variants": {"align": {"max_shift_px": 3.0}}}, "both given")]
    for given, fragment in cases:
        path = write(tmp_path / "settings.json", given)
        with pytest.raises(InputError) as error:
            BootstrapConfig.load(path)
        assert str(path) in str(error.value) and fragment in str(error.value), (given, str(error.value))


def test_every_variant_is_found_by_its_name_and_owns_documented_frozen_options():
    for name in VARIANT_NAMES:
        cls = variant_class(name)
        assert cls.NAME == name and issubclass(cls, Variant), name
        assert cls.__dataclass_params__.frozen, name
        for f in dataclasses.fields(cls):
            assert f.metadata.get("meaning") and f.metadata.get("role") == "variant", (name, f.name)
        cls().check(f"variants.{name}", BootstrapConfig())            # its defaults are valid
        assert all(other in VARIANT_CLASSES for other in cls.REQUIRES)
    with pytest.raises(InputError, match="settings.json: unknown variant 'geometri' \\(did you mean 'geometry'\\?\\)"):
        variant_class("geometri", "settings.json")
    with pytest.raises(InputError, match="unknown variant 'photo'; one of photo_supervision, inpaint"):
        variant_class("photo", "settings.json")     # nothing close: every name


def test_chosen_variants_run_their_hooks_in_the_tables_order():
    config = BootstrapConfig(variants={"densify": {}, "align": {}, "photo_supervision": {}})
    assert list(config.variants) == ["photo_supervision", "align", "densify"]
    assert config == BootstrapConfig(variants={"photo_supervision": {}, "densify": {}, "align": {}})
    # A variant may drop the colour target: then no prior is needed, whatever the fill.
    assert BootstrapConfig(fill="prior").needs_prior()
    assert not BootstrapConfig(fill="prior", variants={"geometry": {"colour": False}}).needs_prior()
    with pytest.raises(InputError, match="needs fill \"render\""):
        BootstrapConfig(fill="prior", variants={"inpaint": {}}).validate()
