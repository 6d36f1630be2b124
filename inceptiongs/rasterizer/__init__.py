"""The torch reference rasterizer: ``projection`` (EWA projection of 3-D Gaussians), ``sh``
(colour from spherical harmonics), ``composite`` (tile-binned front-to-back compositing in
torch), ``composite_numba`` (the same on the CPU cores, forward and backward) and ``rasterize``
(``render``: the one entry point, with the outputs a caller asks for)."""
