"""Level of detail for scenes of millions of Gaussians.

:mod:`.hierarchy` builds a tree of moment-matched parents over any model
(:func:`~.hierarchy.build_hierarchy`), :mod:`.cut` picks the nodes to draw for a camera
(:func:`~.cut.cut_nodes` by projected size, :func:`~.cut.budget_cut_nodes` the finest cut within
a splat budget, :func:`~.cut.lod_gaussians` either as Gaussians), and :mod:`.cache` keeps built
hierarchies in the cache directory keyed by the model's content (:func:`~.cache.load_or_build`).
"""
