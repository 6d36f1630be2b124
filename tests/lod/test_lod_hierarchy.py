"""Building the LOD tree level by level in parts (inceptiongs/lod/hierarchy.merge_level)."""

from __future__ import annotations

import numpy as np

from inceptiongs.gaussians import Gaussians


def test_a_level_merged_in_parts_equals_it_merged_at_once(monkeypatch):
    from inceptiongs.lod import hierarchy as tree_module

    rng = np.random.default_rng(5)
    n = 1000
    model = Gaussians.from_numpy({
        "means": rng.normal(0, 1, (n, 3)).astype(np.float32), "log_scales": rng.normal(-3, 0.5, (n, 3)).astype(np.float32),
        "quats": rng.normal(0, 1, (n, 4)).astype(np.float32), "opacity_logits": rng.normal(0, 1, n).astype(np.float32),
        "sh": rng.normal(0, 0.5, (n, 4, 3)).astype(np.float32)})
    whole = tree_module.build_hierarchy(model)
    monkeypatch.setattr(tree_module, "MERGE_CHUNK_PARENTS", 7)   # parts that split the levels unevenly
    parted = tree_module.build_hierarchy(model)
    for name, values in whole.arrays().items():
        assert np.array_equal(np.asarray(values), np.asarray(parted.arrays()[name])), name
