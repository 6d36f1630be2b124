"""Stage-II hyper-parameters: one dataclass, written to RUN2/bootstrap/config.json.

The stage-I TrainConfig of the input run is kept as it is in RUN2/config.json (so the output
is a run folder every reader understands); everything that belongs to the bootstrap loop lives
here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..io.config_json import SavedConfig
from ..errors import InputError

SAMPLING = ("langevin", "uniform")
VIRTUAL_DEPTHS = ("render", "sources", "both", "auto")


@dataclass
class BootstrapConfig(SavedConfig):
    CONFIG_KIND = "bootstrap config"

    seed: int = 0
    rounds: int = 1
    iterations: int = 300               # refinement steps per round (real + virtual)
    minutes: float | None = None        # wall budget for the whole bootstrap (prior + generation + refinement)

    # --- virtual views (engineer A's defaults when None) -------------------------------------
    k: int | None = None                # nearest training views per target
    l: int | None = None                # interpolated poses per (target, training view) pair
    # Virtual views are generated and rendered at the training resolution: a flagged view made
    # in a large viewer window is scaled so its width matches the training photos'.
    max_virtual_views: int = 64
    # Also supervise the target pose itself (t = 0) with the prior's repair of its render: the
    # view the user flagged is where the repair matters most (statuette, 400 steps: scarce views
    # +0.05 dB over K * L views alone). Off: |V| = K * L exactly.
    include_target: bool = True

    # --- generation --------------------------------------------------------------------------
    prior: str = "trained"              # "trained" (the run's, else a short one) | "untrained" (ablation)
    prior_minutes: float = 2.0          # budget of the short prior training when the run has none
    prior_steps: int | None = None      # ... or this many steps (whichever ends first)
    ddim_steps: int = 10
    # Every this many refinement steps, I* of all virtual views is generated again from the
    # current Gaussians (their render is what the prior repairs); 0: once per round. Statuette,
    # 400 steps: scarce views 15.93 -> 16.26 dB with 50, where a fixed I* stayed at ~16.0 dB;
    # one regeneration of 13 views costs about 20 refinement steps.
    regenerate_every: int = 50

    # --- blending ----------------------------------------------------------------------------
    blending: bool = True
    delta: float | None = None          # relative depth tolerance of the warp (A's default when None)
    save_views: int = 4                 # PNGs (I*, mask, generated) for this many virtual views
    # What the warped photos are blended with: "blend" (binary mask, uniform mean; the paper's
    # with fill "prior") or "photo" (photo-consistent depth, exposure matching, lumigraph
    # weights, soft mask; supervision.py), and what fills the pixels no photo covers: "prior"
    # (the generated image), "inpaint" or "render" (no prior is trained or generated then).
    # bench_supervision on the README courtyard (docs/bootstrap.md, session 17): with the
    # scene's own depth splatted from the training views, the blend over the render is 1.2 dB
    # above the render on the scarce views (16.10 vs 14.88) and 0.8 on the covered ones; the
    # photo supervision's soft mask trusts none of the scarce pixels (its witnesses stand 3-4x
    # farther from the facade than the view), so it stays at the render. The CPU-trained
    # prior's repair is 6 dB below the render, so it fills nothing by default.
    supervision: str = "blend"
    fill: str = "render"
    # The depth the photos are warped into a virtual view with: "render" (the model's surface
    # depth at that view), "sources" (the nearest ``splat_views`` training views' surface
    # depths splatted into it: source_depth.py), "both" (blend only: the render's depth where
    # its warps are trusted, the splatted one elsewhere) or "auto" (blend only: per view,
    # whichever of the two places more photos; the photo supervision uses the splatted one).
    # Each wins where it places more photos: held-out views as virtual views, I* - render on
    # the scarce ones, render / sources depth: courtyard +0.65 / +1.22 dB, bonsai +0.85 / +0.48.
    # In the loop against the same-time baseline (scarce / covered): courtyard "auto" +0.76 /
    # -0.15 ("sources" +0.69 to +0.74, "both" +0.53), bonsai "auto" +0.05 / -0.01 ("render"
    # +0.06 / -0.04, "sources" -0.19 / -0.23). docs/bootstrap.md, session 17.
    virtual_depth: str = "auto"
    # A virtual view whose warped photos agree with each other worse than with the render by
    # more than this (dB; agreement.py) is left out of the refinement; None: every view is used.
    agreement_min_db: float | None = -1.0
    splat_views: int = 8
    # Blend only: each warped photo is first moved onto the render by optical flow, shifts of
    # more than this many pixels left untrusted (align.py); None: the warps as placed.
    align_px: float | None = None

    # --- refinement --------------------------------------------------------------------------
    # Every n-th step is a virtual view, its loss weighted lambda_virtual against a photo's. The
    # README courtyard's bootstrap (92 s) against the same-time baseline: every 2nd at 0.5
    # +0.35 / -0.31 dB (scarce / covered), every 4th at 1.0 +0.38 / -0.10 (docs/bootstrap.md).
    virtual_every: int = 4
    lambda_virtual: float = 1.0
    tau: float = 0.2                    # perceptual loss when the view's SSIM loss (1 - SSIM) <= tau
    densify: bool = False               # densify during refinement (measured: new, unconverged Gaussians cost covered views)
    # Weight of generated (untrusted) pixels against pixels trusted from warped photos in a
    # virtual view's loss; 1 is the paper's loss on I*. Lower trusts a weak prior less.
    generated_weight: float = 1.0
    # Which pixels of a virtual view carry loss: "all" (trusted pixels 1, the fill
    # ``generated_weight``; the paper's loss on I*) or "informative" (photo supervision only: the
    # trusted pixels where the photos contradict the render by more than they disagree among
    # themselves, supervision.informative_mask; L1 + D-SSIM of that residual, nothing elsewhere).
    # A view without informative pixels is not sampled; when no view has any, the step is a photo step.
    virtual_pixels: str = "all"
    # The informative mask's residual floor (None: supervision.RESIDUAL_FLOOR, 4/255): a higher
    # floor keeps only pixels where the render is grossly wrong (see docs/bootstrap.md).
    residual_floor: float | None = None
    # "alternate": every ``virtual_every``-th step is a virtual view instead of a photo; "additive":
    # that step is a photo step whose gradient also holds the virtual view's loss (one Adam step,
    # so the photos lose no step to the virtual views).
    virtual_mode: str = "alternate"
    # The geometry term (multiview.py): at a virtual view, 1 - NCC between the K source photos'
    # patches mapped through the rendered depth and planar normal, back-propagated into the
    # Gaussians' geometry (no warped colour is a target). Its weight against the view's colour
    # loss; 0: off. 0.15 is stage I's lambda_ncc (PGSR's weight of the same measure).
    geometry_weight: float = 0.0
    geometry_samples: int = 4096        # pixels per evaluation (multiview.DEFAULT_SAMPLES)
    # The colour loss at virtual views (I* or the informative blend); False: a virtual view
    # carries only the geometry term (which then must be on).
    virtual_colour: bool = True
    lpips_weights: str | None = None    # TorchScript LPIPS for the perceptual branch (else MS-SSIM-G)
    # The conscience (conscience.py): every ``conscience_every`` steps the L1 of the training photos
    # nearest the targets is measured; above its start value by more than this (relative) the
    # virtual views' weight halves, and recovers once the photos are back. None: off.
    conscience_tolerance: float | None = 0.05
    conscience_every: int = 25

    # --- view-adaptive sampling (Algorithm 1) --------------------------------------------------
    sampling: str = "langevin"          # "langevin" | "uniform" (ablation)
    langevin_step: float | None = None  # step size on the 7-D pose (A's langevin.DEFAULT_STEP_SIZE when None)
    langevin_noise: float | None = None # exploration noise scale (A's DEFAULT_NOISE_SCALE when None)

    # --- bookkeeping -------------------------------------------------------------------------
    log_every: int = 10
    eval_every: int = 0                 # 0: evaluate only at the start and after each round
    checkpoint_every: int = 200

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
        if not self.geometry_weight >= 0 or self.geometry_samples < 1:
            raise InputError(f"{source}: geometry_weight must be >= 0 and geometry_samples >= 1, got "
                             f"{self.geometry_weight}, {self.geometry_samples}")
        if not self.virtual_colour and self.geometry_weight == 0:
            raise InputError(f"{source}: virtual_colour off needs a geometry_weight > 0 (else a virtual view carries no loss)")
        if self.conscience_tolerance is not None and not self.conscience_tolerance >= 0:
            raise InputError(f"{source}: conscience_tolerance must be >= 0 (or null: off), got {self.conscience_tolerance}")
        if self.lambda_virtual < 0:
            raise InputError(f"{source}: lambda_virtual must be >= 0, got {self.lambda_virtual}")
        if (self.langevin_step is not None and self.langevin_step <= 0) or (
                self.langevin_noise is not None and self.langevin_noise < 0):
            raise InputError(f"{source}: langevin_step must be > 0 and langevin_noise >= 0")
        if self.eval_every < 0 or self.save_views < 0 or self.regenerate_every < 0:
            raise InputError(f"{source}: eval_every, save_views and regenerate_every must be >= 0")
        return self
