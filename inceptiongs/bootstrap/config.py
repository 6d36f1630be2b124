"""Stage-II hyper-parameters: one dataclass, written to RUN2/bootstrap/config.json.

The stage-I TrainConfig of the input run is kept as it is in RUN2/config.json (so the output
is a run folder every reader understands); everything that belongs to the bootstrap loop lives
here: the default path's settings, and the experimental variants chosen with their own options
(``variants``; the door: variants.py). Each setting carries its meaning, unit and role in its
metadata (options.option); docs/bootstrap_options.md is generated from them
(scripts/gen_bootstrap_options.py). ``BootstrapConfig.load`` reads such a file strictly:
`inceptiongs bootstrap --config FILE.json`. Files written before the variants had sections
(flat keys such as ``"supervision": "photo"`` or ``"align_px": 2.0``) are read into them
(:func:`sections_from_flat_keys`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError
from ..io.config_json import SavedConfig, check_field_types, read_json_object
from ..io.limits import check_allocation
from .options import (ABLATION, BOOKKEEPING, DEFAULT_PATH, PRIOR_FILL, check_finite, checked_value,  # noqa: F401
                      option, read_options)
from .variants import Variant, chosen_variants
from .virtual_views import DEFAULT_K, DEFAULT_L

SAMPLING = ("langevin", "uniform")
VIRTUAL_DEPTHS = ("render", "sources", "both", "auto")
FILLS = ("render", "prior")
# One candidate virtual view in memory: its camera (a 4x4 float64 pose, intrinsics, a name) and
# its record, rounded up generously (measured about 1 KiB with Python's object overheads).
VIRTUAL_VIEW_BYTES = 2048


@dataclass
class BootstrapConfig(SavedConfig):
    CONFIG_KIND = "bootstrap config"

    seed: int = option(0, "seed of the prior's generation and of the virtual-view sampling")
    rounds: int = option(1, "bootstrap rounds; round r+1 starts from round r's Gaussians with new targets "
                            "and keeps round r's virtual views", "rounds")
    iterations: int = option(300, "refinement steps per round, photo and virtual steps together", "steps")
    minutes: float | None = option(None, "wall budget for the whole bootstrap (prior training, generation, "
                                         "refinement); whichever of it and the steps ends first. null: no budget",
                                   "minutes")

    # --- virtual views -----------------------------------------------------------------------
    # Virtual views are generated and rendered at the training resolution: a flagged view made
    # in a large viewer window is scaled so its width matches the training photos'.
    k: int | None = option(None, "nearest training views per target (null: virtual_views.DEFAULT_K, 3)", "views")
    l: int | None = option(None, "poses interpolated between a target and each of its k training views "
                                 "(null: virtual_views.DEFAULT_L, 4)", "poses")
    max_virtual_views: int = option(64, "at most this many virtual views per round; the rest are dropped", "views")
    # The view the user flagged is where the repair matters most.
    include_target: bool = option(True, "also supervise the target pose itself (t = 0) with the repair of its "
                                        "render; false: exactly k * l virtual views per target")
    # A stage with nothing to do is left out; photo steps come first while they gain more.
    follow_outlook: bool = option(True, "follow the outlook printed before the start (outlook.py): \"nothing to "
                                        "repair\" makes no virtual views (every step a photo step); \"train "
                                        "longer\" takes photo steps until stage I's curve predicts they gain less "
                                        "than 0.5 dB a minute. false: virtual steps from the first step either way")

    # --- generation (only when a prior is used: fill "prior" or blending off) ---------------
    prior: str = option("trained", "\"trained\": the run's prior, else a short one trained here; "
                                   "\"untrained\": a randomly initialised prior (the paper's w/o-FT ablation)",
                        role=ABLATION)
    prior_minutes: float = option(2.0, "budget of the short prior training when a prior is used (fill "
                                       "\"prior\" or blending off) and the run has none; at most half of "
                                       "what is left of `minutes`", "minutes", PRIOR_FILL)
    prior_steps: int | None = option(None, "the short prior training also stops after this many steps, "
                                           "whichever of it and prior_minutes ends first; null: the minutes alone",
                                       "steps", PRIOR_FILL)
    ddim_steps: int = option(10, "DDIM denoising steps per generated image (a prior is used only with fill "
                                 "\"prior\" or blending off)", "steps", PRIOR_FILL)
    regenerate_every: int = option(50, "every this many refinement steps, I* of the virtual views is made "
                                       "again from the current Gaussians (their render is what is repaired): "
                                       "a view left out by the gate at once, a view in use when next chosen; "
                                       "0: once per round", "steps")

    # --- blending: what I* is made of ----------------------------------------------------------
    blending: bool = option(True, "I* blends the trusted pixels of the warped photos over the fill; "
                                  "false: I* = the generated image alone (the paper's w/o-blending ablation)",
                            role=ABLATION)
    delta: float | None = option(None, "depth tolerance of the warp's occlusion test, relative to the depth "
                                       "(null: warp.DEFAULT_DELTA, 0.03)", "relative")
    save_views: int = option(4, "virtual views whose I*, mask and generated image are saved as PNGs in "
                                "RUN2/bootstrap/views", "views", BOOKKEEPING)
    fill: str = option("render", "what fills the pixels no photo covers: \"render\" (default: the model's "
                                 "own render, no prior is trained or generated) or \"prior\" (the generated "
                                 "image; the paper's, with blend); the variant \"inpaint\" inpaints the blend "
                                 "over the render instead")
    virtual_depth: str = option("auto", "the depth the photos are warped into a virtual view with: \"render\" "
                                        "(the model's surface depth there), \"sources\" (the nearest "
                                        "`splat_views` training views' surface depths splatted into it, "
                                        "source_depth.py), \"both\" (blend only: the render's where its "
                                        "warps are trusted, else the splatted) or \"auto\" (default; blend "
                                        "only: per view, whichever places more photos; the variant "
                                        "photo_supervision uses the splatted one)")
    agreement_min_db: float | None = option(-1.0, "a virtual view whose warped photos agree with each other "
                                                  "worse than with the render by more than this is left out "
                                                  "of the refinement (agreement.py); null: every view is used",
                                            "dB")
    splat_views: int = option(8, "training views whose surface depths are splatted into a virtual view "
                                 "(virtual_depth \"sources\", \"both\", \"auto\")", "views")

    # --- refinement ----------------------------------------------------------------------------
    virtual_every: int = option(4, "every n-th refinement step is a virtual view (the variant "
                                   "\"additive\": carries one)", "steps")
    lambda_virtual: float = option(1.0, "loss weight of a virtual view against a photo's", "weight")
    tau: float | None = option(None, "a virtual view's loss is perceptual when its SSIM loss (1 - SSIM) <= "
                                     "tau, else L1 + D-SSIM; null: 0.2 (the paper's) with lpips_weights, else 0 "
                                     "(the weight-free MS-SSIM-G stands in for LPIPS only when tau is given: on "
                                     "bonsai it halved what flagged views gained, docs/results.md)",
                               "SSIM loss, in [0, 2]")
    generated_weight: float = option(1.0, "loss weight of a virtual view's untrusted (fill) pixels against "
                                          "the pixels trusted from warped photos; 1: the paper's loss on I*; "
                                          "lower trusts a weak fill less", "weight, in [0, 1]")
    lpips_weights: str | None = option(None, "AlexNet-LPIPS weights as plain tensors (scripts/lpips_weights.py "
                                             "makes them; TorchScript is refused) for the perceptual loss; null: "
                                             "MS-SSIM-G (weight-free)", "path")
    # The conscience (conscience.py) keeps the virtual views from pulling well observed regions down.
    conscience_tolerance: float | None = option(0.05, "every `conscience_every` steps the L1 of the training "
                                                      "photos nearest the targets is measured; above its start "
                                                      "by more than this, the virtual views' weight halves, "
                                                      "and recovers once the photos are back; null: off",
                                                "relative")
    conscience_every: int = option(25, "refinement steps between the conscience's checks", "steps")

    # --- view-adaptive sampling (Algorithm 1) --------------------------------------------------
    sampling: str = option("langevin", "\"langevin\": the next virtual view by Langevin Monte Carlo on the "
                                       "7-D pose; \"uniform\": drawn uniformly (the paper's ablation)",
                           role=ABLATION)
    langevin_step: float | None = option(None, "drift step size on the 7-D pose (null: "
                                               "langevin.DEFAULT_STEP_SIZE, 0.01)",
                                         "scene units^2 per unit of log P")
    langevin_noise: float | None = option(None, "exploration noise scale (null: langevin.DEFAULT_NOISE_SCALE, "
                                                "0.2; its square is the temperature)", "-")

    # --- bookkeeping ---------------------------------------------------------------------------
    log_every: int = option(10, "refinement steps between log lines", "steps", BOOKKEEPING)
    eval_every: int = option(0, "refinement steps between evaluations; 0: only at the start and after "
                                "each round", "steps", BOOKKEEPING)
    checkpoint_every: int = option(200, "refinement steps between checkpoints", "steps", BOOKKEEPING)

    # --- variants --------------------------------------------------------------------------------
    # The experimental variants chosen, each with its own options (variants.py; none by default).
    variants: dict[str, Variant] = field(default_factory=dict, metadata={
        "meaning": "the experimental variants chosen, by name, each with its own options (listed below); "
                   "{}: none, the default path", "unit": "-", "role": DEFAULT_PATH})

    def __post_init__(self) -> None:
        # A variant given as a mapping of its options (a test, a benchmark, the reader) becomes
        # its options dataclass, and the chosen ones stand in the table's order (their hooks' order).
        self.variants = chosen_variants(self.variants)

    @classmethod
    def load(cls, path: str | Path) -> "BootstrapConfig":
        """The config in the JSON object at ``path``: any subset of the keys (the others keep
        their defaults), read strictly (``read_bootstrap_config``)."""
        return read_bootstrap_config(path)

    @classmethod
    def from_json(cls, data: dict, source: str) -> "BootstrapConfig":
        """The config of a JSON object already read (a checkpoint's "bootstrap"/"config"),
        flat keys of older files included; errors name ``source``."""
        return config_from_json(data, source)

    def colour_target(self) -> bool:
        """Whether a virtual view carries a colour loss (and I* is built): a variant may drop it."""
        return all(variant.colour_target() for variant in self.variants.values())

    def needs_prior(self) -> bool:
        """Whether any I* uses a generated image (False: no prior is trained or loaded)."""
        if not self.colour_target():
            return False        # no I* at all: the virtual views carry another loss only
        return not self.blending or self.fill == "prior"

    def validate(self, source: str = "bootstrap config") -> "BootstrapConfig":
        self.check_types(source)
        positive = ("rounds", "iterations", "ddim_steps", "virtual_every", "log_every",
                    "checkpoint_every", "max_virtual_views", "conscience_every", "splat_views")
        for name in positive:
            if getattr(self, name) < 1:
                raise InputError(f"{source}: {name} must be >= 1, got {getattr(self, name)}")
        for name in ("k", "l", "prior_steps"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise InputError(f"{source}: {name} must be >= 1, got {value}")
        for name in ("minutes", "prior_minutes"):
            value = getattr(self, name)
            if value is not None and value <= 0:
                raise InputError(f"{source}: {name} must be > 0, got {value}")
        # k x l candidate poses are made per target before max_virtual_views keeps the first:
        # their memory is checked before a single one is built.
        poses = (DEFAULT_K if self.k is None else self.k) * (DEFAULT_L if self.l is None else self.l)
        check_allocation(poses * VIRTUAL_VIEW_BYTES, source, f"k x l = {poses} virtual view poses per target")
        if self.sampling not in SAMPLING:
            raise InputError(f"{source}: sampling must be one of {', '.join(SAMPLING)}, got {self.sampling!r}")
        if self.prior not in ("trained", "untrained"):
            raise InputError(f"{source}: prior must be 'trained' or 'untrained', got {self.prior!r}")
        if self.delta is not None and not self.delta > 0:
            raise InputError(f"{source}: delta must be > 0, got {self.delta}")
        if self.tau is not None and not 0 <= self.tau <= 2:
            raise InputError(f"{source}: tau (an SSIM loss, in [0, 2]) out of range: {self.tau}")
        if not 0 <= self.generated_weight <= 1:
            raise InputError(f"{source}: generated_weight must be in [0, 1], got {self.generated_weight}")
        if self.fill not in FILLS:
            raise InputError(f"{source}: fill must be 'render' or 'prior' (the inpainting fill is the variant "
                             f"\"inpaint\"), got {self.fill!r}")
        if self.agreement_min_db is not None and not math.isfinite(self.agreement_min_db):
            raise InputError(f"{source}: agreement_min_db must be a finite number (or null: off), got {self.agreement_min_db}")
        if self.virtual_depth not in VIRTUAL_DEPTHS:
            raise InputError(f"{source}: virtual_depth must be one of {', '.join(VIRTUAL_DEPTHS)}, "
                             f"got {self.virtual_depth!r}")
        if self.conscience_tolerance is not None and not self.conscience_tolerance >= 0:
            raise InputError(f"{source}: conscience_tolerance must be >= 0 (or null: off), got {self.conscience_tolerance}")
        if self.lambda_virtual < 0:
            raise InputError(f"{source}: lambda_virtual must be >= 0, got {self.lambda_virtual}")
        if self.langevin_step is not None and self.langevin_step <= 0:
            raise InputError(f"{source}: langevin_step must be > 0 (or null: the default), got {self.langevin_step}")
        if self.langevin_noise is not None and self.langevin_noise < 0:
            raise InputError(f"{source}: langevin_noise must be >= 0 (or null: the default), got {self.langevin_noise}")
        for name in ("eval_every", "save_views", "regenerate_every"):
            if getattr(self, name) < 0:
                raise InputError(f"{source}: {name} must be >= 0, got {getattr(self, name)}")
        check_finite(self, source)
        self.validate_variants(source)
        return self

    def validate_variants(self, source: str) -> None:
        """Each chosen variant's options (types, finite, ranges) and what it needs of the rest."""
        for name, variant in self.variants.items():
            where = f"{source}: variants.{name}"
            check_field_types(variant, where)
            check_finite(variant, where)
            variant.check(where, self)
            missing = [other for other in variant.REQUIRES if other not in self.variants]
            if missing:
                raise InputError(f"{where}: needs the variant {', '.join(missing)} too")


def read_bootstrap_config(path: str | Path) -> BootstrapConfig:
    """A BootstrapConfig from a JSON object of its keys at ``path``, validated. An unknown key
    (with the nearest key name when one is close), a value of the wrong type, a non-finite number
    or an out-of-range value is an InputError: one line naming the file and the key."""
    path = Path(path)
    return config_from_json(read_json_object(path, BootstrapConfig.CONFIG_KIND), str(path))


def config_from_json(data: dict, source: str) -> BootstrapConfig:
    """:func:`read_bootstrap_config` of a JSON object already read; ``source`` names it in errors."""
    data = sections_from_flat_keys(data, source)
    settings = {key: value for key, value in data.items() if key != "variants"}
    values = read_options(BootstrapConfig, settings, source, also_known=FLAT_KEYS)
    values["variants"] = chosen_variants(data.get("variants", {}), source)
    return BootstrapConfig(**values).validate(source)


# --- files of flat keys ---------------------------------------------------------------------------
# Before the variants had sections a file chose them with flat keys. Each key is still read, checked
# as it was, and moved into the section of the variant it chose:
# key -> (its type, {value: the variant it chooses; None: none}).
FLAT_CHOICES = {
    "supervision": ("str", {"blend": None, "photo": "photo_supervision"}),
    "virtual_mode": ("str", {"alternate": None, "additive": "additive"}),
    "virtual_pixels": ("str", {"all": None, "informative": "informative"}),
    "placement": ("str", {"paths": None, "evidence": "evidence"}),
    "densify": ("bool", {False: None, True: "densify"}),
}
# key -> (its type, the value that chose nothing, the variant any other value chooses, its option).
FLAT_SWITCHES = {
    "align_px": ("float | None", None, "align", "max_shift_px"),
    "geometry_weight": ("float", 0.0, "geometry", "weight"),
}
# key -> (its type, the variant, its option, the key's default then): kept when the file chooses the
# variant. Every file of that time holds them all, so the defaults are dropped unread.
FLAT_OPTIONS = {
    "geometry_samples": ("int", "geometry", "samples", 4096),
    "virtual_colour": ("bool", "geometry", "colour", True),
    "residual_floor": ("float | None", "informative", "residual_floor", None),
    "evidence_min_fraction": ("float", "evidence", "min_fraction", 0.05),
    "evidence_photos": ("int", "evidence", "photos", 6),
}
FLAT_KEYS = (*FLAT_CHOICES, *FLAT_SWITCHES, *FLAT_OPTIONS)


def sections_from_flat_keys(data: dict, source: str) -> dict:
    """``data`` (a config JSON object) with every flat key of an older file (FLAT_CHOICES,
    FLAT_SWITCHES, FLAT_OPTIONS; ``"fill": "inpaint"``) moved into its variant's section under
    "variants". A flat key's value is checked as before (type, allowed values); the option of a
    variant the file does not choose had no effect and is dropped once its range is checked.
    A flat key and the variant's section both setting the same option is an error, unless the
    flat key holds its old default (files of the time hold every key)."""
    data = dict(data)
    sections = data.get("variants", {})
    if not isinstance(sections, dict):
        raise InputError(f"{source}: variants must be an object of variant names and their options, got {sections!r}")
    sections = {name: dict(options) if isinstance(options, dict) else options for name, options in sections.items()}
    options: dict[str, dict] = {}
    for key, (kind, values) in FLAT_CHOICES.items():
        if key in data:
            value = checked_value(source, key, kind, data.pop(key))
            if value not in values:
                raise InputError(f"{source}: {key} must be one of {', '.join(repr(v) for v in values)}, got {value!r}")
            if values[value] is not None:
                sections.setdefault(values[value], {})
    if data.get("fill") == "inpaint":
        data["fill"] = "render"         # the inpainting is over the render's blend: no prior
        sections.setdefault("inpaint", {})
    for key, (kind, off, name, option_name) in FLAT_SWITCHES.items():
        if key in data:
            value = checked_value(source, key, kind, data.pop(key))
            if value != off:
                sections.setdefault(name, {})
                options.setdefault(name, {})[option_name] = (key, value)
    defaults = set()                    # (variant, option) a flat key gives at its default then
    for key, (kind, name, option_name, default) in FLAT_OPTIONS.items():
        if key in data:
            value = checked_value(source, key, kind, data.pop(key))
            if value != default or name in sections:
                options.setdefault(name, {})[option_name] = (key, value)
            if value == default:
                defaults.add((name, option_name))
    if options.get("geometry", {}).get("colour", (None, True))[1] is False and "geometry" not in sections:
        raise InputError(f"{source}: virtual_colour off needs a geometry_weight > 0 (else a virtual view carries no loss)")
    for name, given in options.items():
        if name not in sections:
            # Not chosen: the options had no effect, but an out-of-range one was refused and still is.
            (unused,) = chosen_variants({name: {option: value for option, (_, value) in given.items()}},
                                        source).values()
            check_finite(unused, f"{source}: {name}")
            unused.check(f"{source}: {name}", BootstrapConfig())
            continue
        if not isinstance(sections[name], dict):
            continue                    # refused with its own message when the sections are read
        for option_name, (key, value) in given.items():
            if option_name in sections[name]:
                if (name, option_name) in defaults:
                    continue            # a file of the time holds every key: its default says nothing
                raise InputError(f"{source}: {key} and variants.{name}.{option_name} both given; keep one")
            sections[name][option_name] = value
    if sections:
        data["variants"] = sections
    return data
