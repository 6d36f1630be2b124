"""Stage-II variants that were measured and left off by default (docs/bootstrap.md has the
numbers). Each stays selectable through the same ``BootstrapConfig`` field, so the benchmark can
run it again:

- ``photo_supervision`` (``supervision="photo"``, with ``lumigraph``, ``exposure`` and
  ``photo_depth``): photo-consistent depth, exposure matching, lumigraph weights, soft mask;
- ``inpaint`` (``fill="inpaint"``): the photos' blend inpainted where no photo reaches;
- ``align`` (``align_px``): warps moved onto the render by optical flow;
- ``informative`` (``virtual_pixels="informative"``): loss only where the photos contradict
  the render;
- ``additive`` (``virtual_mode="additive"``): the virtual loss added to a photo step;
- ``multiview`` (``geometry_weight``): the geometry term at virtual views.

Nothing is imported here: ``supervise.supervision_kind`` imports ``photo_supervision`` (which
registers "photo") when that kind is asked for, the loop the others when their field is on.
"""
