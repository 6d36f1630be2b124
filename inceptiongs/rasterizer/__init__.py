"""The torch reference rasterizer: ``projection`` (EWA projection of 3-D Gaussians), ``sh``
(colour from spherical harmonics), ``composite`` (tile-binned front-to-back compositing in
torch) and ``rasterize`` (``render``: the one entry point, with the outputs a caller asks for).
``projection_numba``, ``sh_numba`` and ``composite_numba`` are the same stages as CPU kernels
(forward and backward); ``backend`` says which one runs."""
