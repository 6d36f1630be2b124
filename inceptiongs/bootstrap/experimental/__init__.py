"""Stage-II variants that were measured and left off by default (docs/bootstrap.md has the
numbers). Each is a variant of ``..variants`` (its options and hooks in one frozen dataclass),
chosen by name in ``BootstrapConfig.variants`` so the benchmark can run it again:

- ``photo_supervision`` (with ``lumigraph``, ``exposure`` and ``photo_depth``): photo-consistent
  depth, exposure matching, lumigraph weights, soft mask;
- ``inpaint``: the photos' blend inpainted where no photo reaches;
- ``align``: warps moved onto the render by optical flow;
- ``informative``: loss only where the photos contradict the render;
- ``additive``: the virtual loss added to a photo step;
- ``geometry`` (``multiview``): the geometry term at virtual views;
- ``evidence`` (``placement``, ``validation``): views placed by the leave-one-out evidence;
- ``densify``: densification during the refinement.

Nothing is imported here, and nothing outside this folder imports it: ``..variants.variant_class``
loads a variant's module by name when a config chooses it.
"""
