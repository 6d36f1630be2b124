"""Stage-II hyper-parameters: one dataclass, written to RUN2/bootstrap/config.json.

The stage-I TrainConfig of the input run is kept as it is in RUN2/config.json (so the output
is a run folder every reader understands); everything that belongs to the bootstrap loop lives
here. Each field carries its meaning, unit and role in its metadata (``option``);
docs/bootstrap_options.md is generated from them (scripts/gen_bootstrap_options.py).
``BootstrapConfig.load`` reads such a file strictly: `inceptiongs bootstrap --config FILE.json`.
"""

from __future__ import annotations

import difflib
import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path

from ..io.config_json import SavedConfig, read_json_object
from ..errors import InputError

SAMPLING = ("langevin", "uniform")
VIRTUAL_DEPTHS = ("render", "sources", "both", "auto")
PLACEMENTS = ("paths", "evidence")

# A field's role (docs/bootstrap_options.md explains them).
DEFAULT_PATH = "default path"           # its value shapes a run with every default
EXPERIMENTAL = "experimental variant"   # read only when a non-default variant is chosen (the meaning says which)
ABLATION = "ablation"                   # one of the paper's ablations; off by default
BOOKKEEPING = "bookkeeping"             # logs, evaluations, checkpoints, saved images: never the model
ROLES = (DEFAULT_PATH, EXPERIMENTAL, ABLATION, BOOKKEEPING)


def option(default, meaning: str, unit: str = "-", role: str = DEFAULT_PATH):
    """A BootstrapConfig field with its documentation: what it means, its unit ("-": none) and
    its role (one of ROLES)."""
    assert role in ROLES, role
    return field(default=default, metadata={"meaning": meaning, "unit": unit, "role": role})


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
    placement: str = option("paths", "where the virtual views go: \"paths\" (default: k * l poses on the paths "
                                     "from each target to its k nearest photos, gated by `agreement_min_db`) or "
                                     "\"evidence\" (experimental: poses near the target where the leave-one-out "
                                     "estimate says the blend beats the render, validation.py and placement.py; "
                                     "pixels without that evidence carry no virtual loss; replaces the agreement gate)")
    evidence_min_fraction: float = option(0.05, "placement \"evidence\" only: a virtual view is used when at "
                                                "least this share of its pixels with depth lie on regions of "
                                                "positive evidence", "fraction, in (0, 1]", EXPERIMENTAL)
    evidence_photos: int = option(6, "placement \"evidence\" only: training photos near the targets at which "
                                     "the leave-one-out estimate is measured each round", "views", EXPERIMENTAL)
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
                                       "what is left of `minutes`", "minutes", EXPERIMENTAL)
    prior_steps: int | None = option(None, "the short prior training also stops after this many steps, "
                                           "whichever of it and prior_minutes ends first; null: the minutes alone",
                                       "steps", EXPERIMENTAL)
    ddim_steps: int = option(10, "DDIM denoising steps per generated image (a prior is used only with fill "
                                 "\"prior\" or blending off)", "steps", EXPERIMENTAL)
    regenerate_every: int = option(50, "every this many refinement steps, I* of every virtual view is made "
                                       "again from the current Gaussians (their render is what is repaired); "
                                       "0: once per round", "steps")

    # --- blending: what I* is made of ----------------------------------------------------------
    blending: bool = option(True, "I* blends the trusted pixels of the warped photos over the fill; "
                                  "false: I* = the generated image alone (the paper's w/o-blending ablation)",
                            role=ABLATION)
    delta: float | None = option(None, "depth tolerance of the warp's occlusion test, relative to the depth "
                                       "(null: warp.DEFAULT_DELTA, 0.03)", "relative")
    save_views: int = option(4, "virtual views whose I*, mask and generated image are saved as PNGs in "
                                "RUN2/bootstrap/views", "views", BOOKKEEPING)
    supervision: str = option("blend", "\"blend\" (default): the warped photos' uniform mean under a binary "
                                       "trust mask; \"photo\" (experimental): photo-consistent depth, exposure "
                                       "matching, lumigraph weights and a soft mask (experimental/photo_supervision.py)")
    fill: str = option("render", "what fills the pixels no photo covers: \"render\" (default: the model's "
                                 "own render, no prior is trained or generated), \"inpaint\" (the blend "
                                 "inpainted) or \"prior\" (the generated image; the paper's, with blend)")
    virtual_depth: str = option("auto", "the depth the photos are warped into a virtual view with: \"render\" "
                                        "(the model's surface depth there), \"sources\" (the nearest "
                                        "`splat_views` training views' surface depths splatted into it, "
                                        "source_depth.py), \"both\" (blend only: the render's where its "
                                        "warps are trusted, else the splatted) or \"auto\" (default; blend "
                                        "only: per view, whichever places more photos; the photo "
                                        "supervision uses the splatted one)")
    agreement_min_db: float | None = option(-1.0, "a virtual view whose warped photos agree with each other "
                                                  "worse than with the render by more than this is left out "
                                                  "of the refinement (agreement.py); null: every view is used",
                                            "dB")
    splat_views: int = option(8, "training views whose surface depths are splatted into a virtual view "
                                 "(virtual_depth \"sources\", \"both\", \"auto\")", "views")
    align_px: float | None = option(None, "blend only: each warped photo is first moved onto the render by "
                                          "optical flow, shifts beyond this untrusted (experimental/align.py); null: off",
                                    "px", EXPERIMENTAL)

    # --- refinement ----------------------------------------------------------------------------
    virtual_every: int = option(4, "every n-th refinement step is a virtual view (virtual_mode "
                                   "\"additive\": carries one)", "steps")
    lambda_virtual: float = option(1.0, "loss weight of a virtual view against a photo's", "weight")
    tau: float = option(0.2, "a virtual view's loss is perceptual when its SSIM loss (1 - SSIM) <= tau, "
                             "else L1 + D-SSIM", "SSIM loss, in [0, 2]")
    densify: bool = option(False, "densify the Gaussians during the refinement", role=EXPERIMENTAL)
    generated_weight: float = option(1.0, "loss weight of a virtual view's untrusted (fill) pixels against "
                                          "the pixels trusted from warped photos; 1: the paper's loss on I*; "
                                          "lower trusts a weak fill less", "weight, in [0, 1]")
    virtual_pixels: str = option("all", "which pixels of a virtual view carry loss: \"all\" (default: "
                                        "trusted pixels 1, the fill `generated_weight`) or \"informative\" "
                                        "(experimental, supervision \"photo\" only: the trusted pixels where "
                                        "the photos contradict the render by more than they disagree among "
                                        "themselves, experimental/photo_supervision.informative_mask; a view without any is "
                                        "not sampled)")
    residual_floor: float | None = option(None, "virtual_pixels \"informative\" only: the smallest "
                                                "photo - render residual that counts (null: "
                                                "experimental/photo_supervision.RESIDUAL_FLOOR, 4/255); higher keeps only "
                                                "grossly wrong pixels", "colour, in [0, 1]", EXPERIMENTAL)
    virtual_mode: str = option("alternate", "\"alternate\" (default): a virtual step replaces a photo "
                                            "step; \"additive\" (experimental): that step is a photo step "
                                            "whose gradient also holds the virtual view's loss (one Adam "
                                            "step, so the photos lose no step)")
    geometry_weight: float = option(0.0, "weight of the geometry term at virtual views (experimental/multiview.py): 1 - NCC "
                                         "of the k source photos' patches mapped through the rendered depth "
                                         "and planar normal, into the Gaussians' geometry; 0: off (stage I's "
                                         "lambda_ncc, PGSR's weight of the same measure, is 0.15)",
                                    "weight", EXPERIMENTAL)
    geometry_samples: int = option(4096, "pixels per evaluation of the geometry term "
                                         "(multiview.DEFAULT_SAMPLES)", "pixels", EXPERIMENTAL)
    virtual_colour: bool = option(True, "the colour loss at virtual views (I* or the informative blend); "
                                        "false (experimental): only the geometry term, which must then be on")
    lpips_weights: str | None = option(None, "a TorchScript LPIPS file for the perceptual loss; null: MS-SSIM-G "
                                             "(weight-free)", "path", EXPERIMENTAL)
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

    @classmethod
    def load(cls, path: str | Path) -> "BootstrapConfig":
        """The config in the JSON object at ``path``: any subset of the field names (the others
        keep their defaults), read strictly (``read_bootstrap_config``)."""
        return read_bootstrap_config(path)

    def needs_prior(self) -> bool:
        """Whether any I* uses a generated image (False: no prior is trained or loaded)."""
        if not self.virtual_colour:
            return False        # no I* at all: the virtual views carry only the geometry term
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
        if self.sampling not in SAMPLING:
            raise InputError(f"{source}: sampling must be one of {', '.join(SAMPLING)}, got {self.sampling!r}")
        if self.prior not in ("trained", "untrained"):
            raise InputError(f"{source}: prior must be 'trained' or 'untrained', got {self.prior!r}")
        if self.delta is not None and not self.delta > 0:
            raise InputError(f"{source}: delta must be > 0, got {self.delta}")
        if not 0 <= self.tau <= 2:
            raise InputError(f"{source}: tau (an SSIM loss, in [0, 2]) out of range: {self.tau}")
        if not 0 <= self.generated_weight <= 1:
            raise InputError(f"{source}: generated_weight must be in [0, 1], got {self.generated_weight}")
        if self.supervision not in ("blend", "photo"):
            raise InputError(f"{source}: supervision must be 'blend' or 'photo', got {self.supervision!r}")
        if self.fill not in ("prior", "inpaint", "render"):
            raise InputError(f"{source}: fill must be 'prior', 'inpaint' or 'render', got {self.fill!r}")
        if self.agreement_min_db is not None and not math.isfinite(self.agreement_min_db):
            raise InputError(f"{source}: agreement_min_db must be a finite number (or null: off), got {self.agreement_min_db}")
        if self.align_px is not None and not (math.isfinite(self.align_px) and self.align_px > 0):
            raise InputError(f"{source}: align_px must be a positive number of pixels (or null: off), got {self.align_px}")
        if self.placement not in PLACEMENTS:
            raise InputError(f"{source}: placement must be one of {', '.join(PLACEMENTS)}, got {self.placement!r}")
        if not 0 < self.evidence_min_fraction <= 1:
            raise InputError(f"{source}: evidence_min_fraction must be in (0, 1], got {self.evidence_min_fraction}")
        if self.evidence_photos < 1:
            raise InputError(f"{source}: evidence_photos must be >= 1, got {self.evidence_photos}")
        if self.virtual_depth not in VIRTUAL_DEPTHS:
            raise InputError(f"{source}: virtual_depth must be one of {', '.join(VIRTUAL_DEPTHS)}, "
                             f"got {self.virtual_depth!r}")
        if self.virtual_pixels not in ("all", "informative"):
            raise InputError(f"{source}: virtual_pixels must be 'all' or 'informative', got {self.virtual_pixels!r}")
        if self.virtual_pixels == "informative" and self.supervision != "photo":
            raise InputError(f"{source}: virtual_pixels 'informative' needs supervision 'photo'")
        if self.residual_floor is not None and not self.residual_floor >= 0:
            raise InputError(f"{source}: residual_floor must be >= 0, got {self.residual_floor}")
        if self.virtual_mode not in ("alternate", "additive"):
            raise InputError(f"{source}: virtual_mode must be 'alternate' or 'additive', got {self.virtual_mode!r}")
        if not self.geometry_weight >= 0:
            raise InputError(f"{source}: geometry_weight must be >= 0, got {self.geometry_weight}")
        if self.geometry_samples < 1:
            raise InputError(f"{source}: geometry_samples must be >= 1, got {self.geometry_samples}")
        if not self.virtual_colour and self.geometry_weight == 0:
            raise InputError(f"{source}: virtual_colour off needs a geometry_weight > 0 (else a virtual view carries no loss)")
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
        for f in fields(self):  # a NaN passes every comparison above, an inf most of them
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise InputError(f"{source}: {f.name} must be a finite number, got {value}")
        return self


def read_bootstrap_config(path: str | Path) -> BootstrapConfig:
    """A BootstrapConfig from a JSON object of field names at ``path``, validated. An unknown
    key (with the nearest field name when one is close), a value of the wrong type, a non-finite
    number or an out-of-range value is an InputError: one line naming the file and the key."""
    path = Path(path)
    data = read_json_object(path, BootstrapConfig.CONFIG_KIND)
    by_name = {f.name: f for f in fields(BootstrapConfig)}
    values = {}
    for key, value in data.items():
        if key not in by_name:
            close = difflib.get_close_matches(key, list(by_name), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise InputError(f"{path}: unknown key {key!r}{hint}; docs/bootstrap_options.md lists the keys")
        values[key] = checked_value(path, key, by_name[key].type, value)
    return BootstrapConfig(**values).validate(str(path))


def checked_value(path: Path, key: str, annotation: str, value):
    """``value`` from a JSON file when it fits the field's annotation (a string such as
    "int", "float | None"), an int widened to float for a float field; else an InputError
    naming ``path`` and ``key``."""
    kinds = {kind.strip() for kind in str(annotation).split("|")}
    nullable = "None" in kinds
    (kind,) = kinds - {"None"}
    wanted = {"int": "an integer", "float": "a finite number", "str": "a string", "bool": "true or false"}[kind]
    if value is None and nullable:
        return None
    if kind == "bool" and isinstance(value, bool):
        return value
    if kind == "int" and isinstance(value, int) and not isinstance(value, bool):
        return value
    if kind == "str" and isinstance(value, str):
        return value
    if (kind == "float" and isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value)):
        return float(value)
    shown = json.dumps(value, allow_nan=True)
    raise InputError(f"{path}: {key} must be {wanted}{' or null' if nullable else ''}, got {shown}")
