"""Rasterizers. ``interface`` is the one way in: the ``Rasterizer`` protocol, its typed result
(``result.RenderResult``), the registry ``RASTERIZERS`` (torch, numba, gsplat) and
``resolve_device``, the one rule that turns ``--device auto|cpu|cuda`` into a ``Device``.

The torch reference: ``projection`` (EWA projection of 3-D Gaussians), ``sh`` (colour from
spherical harmonics), ``composite`` (tile-binned front-to-back compositing in torch) and
``rasterize`` (``render``, with the outputs a caller asks for). ``projection_numba``,
``sh_numba`` and ``composite_numba`` are the same stages as CPU kernels (forward and backward);
``backend`` says which one runs. ``gsplat_backend``: gsplat's CUDA kernels behind the same call."""
