"""Stage II's experimental variants, behind one door.

A variant is a frozen dataclass deriving from :class:`Variant`: its fields are its own options
(declared with ``options.option``, so docs/bootstrap_options.md lists them per variant) and its
methods are hooks the default path calls at fixed points; :class:`Variant` has every hook, each
doing what the default path does without it, so a variant overrides only those it changes. A
config chooses variants by name with their options (``BootstrapConfig.variants``, in a file
``{"variants": {"align": {"max_shift_px": 2.0}}}``).

:data:`VARIANT_CLASSES` is the one table of variants: name -> "module:Class" inside
``experimental/``, resolved with importlib by :func:`variant_class` the first time a config names
the variant. So a run with every default never loads experimental code, and no module outside
``experimental/`` imports it (scripts/check_imports.py refuses such an import). A table rather
than an entry-point group: the variants are this package's own code, registered without
reinstalling the package (entry points live in the installed metadata, which an edited checkout
only refreshes on `pip install`), and every name is known without importing anything, for the
strict reader's hints and the generated docs.

The hooks, in the order a run meets them (the arguments' types are the default path's: warps
are warp.WarpResult, a view is generation.VirtualTarget, a maker view_targets.TargetMaker, a
context view_supervision.ViewContext):

* ``check(source, config)``: InputError for an option out of range, or a config it cannot run with;
* ``continued_schedule(schedule, stage1, start, steps)``: the stage-I TrainConfig continued for
  the refinement (refine.continuation_config) -> the one to use;
* ``place_views(request)``: a round's virtual views (:class:`PlacementRequest`) ->
  :class:`PlacedViews`, or None for the default placement (k * l poses on paths, virtual_views.py);
* ``supervise(context)``: I* at a view -> view_supervision.ViewSupervision, or None for the
  default blend (supervise.py);
* ``adjust_warps(context, warps)``, ``finish_blend(image, mask, depth)``: the blend's warps before
  they are blended, its image after;
* ``view_geometry(sources, photos, cameras, depth_of)``: what the view keeps for a geometry term
  (VirtualTarget.geometry);
* ``colour_target()``: False when a virtual view carries no colour loss (then no I* is built);
* ``may_sample(view)``: False keeps a view the gate let through out of the sampling;
* ``pixel_weights(mask, weights)``, ``colour_loss(rgb, target, weights)``: the per-pixel loss
  weights, and the colour loss instead of refine.virtual_view_loss (None: the default's);
* ``render_outputs(view)``, ``extra_loss(out, view, seed, step, scale)``: more rasterizer outputs
  at a virtual step and a loss term on them;
* ``take_step(virtual_loss, photo_step)``: a virtual slot's step itself (None: the default
  virtual step); ``virtual_loss()`` -> (loss, render outputs, record) and ``photo_step()`` -> record
  are the default path's, handed over so a variant needs nothing of refine.py.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable, ClassVar, Sequence

from ..errors import InputError
from .options import closest, read_options

# The variants by name: "module:Class", the module relative to this package. The order is the
# order their hooks run in and the docs list them.
VARIANT_CLASSES: dict[str, str] = {
    "photo_supervision": "experimental.photo_supervision:PhotoSupervision",
    "inpaint": "experimental.inpaint:Inpaint",
    "align": "experimental.align:Align",
    "informative": "experimental.informative:Informative",
    "additive": "experimental.additive:Additive",
    "geometry": "experimental.geometry:Geometry",
    "evidence": "experimental.evidence:EvidencePlacement",
    "densify": "experimental.densify:Densify",
    "fixer": "experimental.fixer:Fixer",
}
VARIANT_NAMES = tuple(VARIANT_CLASSES)


@dataclass(frozen=True)
class PlacementRequest:
    """What a variant places a round's views with: the round (0-based) and its targets, the
    maker of I* from the round's starting Gaussians (its renders give depth and colour at any
    camera), the scene's cameras, the training views, the photos on the host, the config and the log."""

    round_index: int
    goal: Sequence
    maker: "TargetMaker"  # noqa: F821 (view_targets.TargetMaker)
    cameras: Sequence
    train: Sequence[int]
    photos: dict
    config: "BootstrapConfig"  # noqa: F821 (config.BootstrapConfig)
    log: Callable[[str], None]


@dataclass(frozen=True)
class PlacedViews:
    """A variant's placement of a round: ``views`` [(target index, virtual_views.VirtualView)],
    ``record`` (the round's summary keeps it under the variant's name), ``mark(view, maker)``
    applied to every view's I* made from then on (this round's and every regeneration), and
    ``left_out``: why a view it placed may still be left out (the round's log line)."""

    views: list
    record: dict
    mark: Callable
    left_out: str


@dataclass(frozen=True)
class Variant:
    """The hooks (module doc), each doing what the default path does."""

    NAME: ClassVar[str] = ""
    # Variants this one only works together with.
    REQUIRES: ClassVar[tuple[str, ...]] = ()

    def check(self, source: str, config) -> None:
        return None

    def continued_schedule(self, schedule, stage1, start: int, steps: int):
        return schedule

    def place_views(self, request: PlacementRequest) -> PlacedViews | None:
        return None

    def supervise(self, context):
        return None

    def adjust_warps(self, context, warps: list) -> list:
        return warps

    def finish_blend(self, image, mask, depth):
        return image

    def view_geometry(self, sources: Sequence[int], photos: dict, cameras: Sequence, depth_of: Callable) -> list:
        return []

    def colour_target(self) -> bool:
        return True

    def may_sample(self, view) -> bool:
        return True

    def pixel_weights(self, mask, weights):
        return weights

    def colour_loss(self, rgb, target, weights):
        return None

    def render_outputs(self, view) -> tuple[str, ...]:
        return ()

    def extra_loss(self, out: dict, view, seed: int, step: int, scale: float):
        return None

    def take_step(self, virtual_loss: Callable[[], tuple], photo_step: Callable[[], dict]) -> dict | None:
        return None


def variant_class(name: str, source: str = "bootstrap config") -> type[Variant]:
    """The class of the variant ``name``, its module imported now (the only import of
    experimental code); an unknown name is one line naming ``source`` and the nearest name."""
    if name not in VARIANT_CLASSES:
        raise InputError(f"{source}: unknown variant {name!r}{closest(name, VARIANT_NAMES)}; "
                         f"one of {', '.join(VARIANT_NAMES)} (docs/bootstrap_options.md)")
    module_name, class_name = VARIANT_CLASSES[name].split(":")
    cls = getattr(importlib.import_module(f".{module_name}", __package__), class_name)
    if cls.NAME != name or not issubclass(cls, Variant):
        raise ImportError(f"{VARIANT_CLASSES[name]} is not the variant {name!r}")
    return cls


def chosen_variants(given: dict, source: str = "bootstrap config") -> dict[str, Variant]:
    """{name: the variant's options} in the table's order, each given as a Variant or as a
    mapping of its options (a JSON object, read strictly)."""
    if not isinstance(given, dict):
        raise InputError(f"{source}: variants must be an object of variant names and their options, got {given!r}")
    for name in given:
        variant_class(name, source)          # an unknown name first, whatever its position
    chosen = {}
    for name in (n for n in VARIANT_NAMES if n in given):
        options, cls = given[name], variant_class(name, source)
        if isinstance(options, Variant):
            chosen[name] = options
            continue
        if not isinstance(options, dict):
            raise InputError(f"{source}: variants.{name} must be an object of the variant's options "
                             f"({{}}: its defaults), got {options!r}")
        chosen[name] = cls(**read_options(cls, options, source, f"variants.{name}."))
    return chosen
