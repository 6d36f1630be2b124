"""Stage II: generative bootstrapping of badly observed regions (docs/bootstrap.md).

Geometry: ``virtual_views``, ``warp``, ``langevin``, ``perceptual``. The loop:
``config.BootstrapConfig``, ``targets`` (flags, a named view or j*), ``generation`` (prior,
cache, blending), ``refine`` (virtual-view steps, Langevin view sampling),
``runner.run_bootstrap`` / ``runner.baseline_run`` and ``job.BootstrapJob`` (the viewer's live
job). Nothing is imported here: each caller imports the module it needs.
"""
