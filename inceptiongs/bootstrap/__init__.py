"""Stage II: generative bootstrapping of badly observed regions (docs/bootstrap.md).

Geometry (engineer A): ``virtual_views``, ``warp``, ``langevin``, ``perceptual``.
The loop (this package's other modules): ``config.BootstrapConfig``, ``targets`` (flags, a
named view or j*), ``generation`` (prior, cache, blending), ``refine`` (virtual-view steps,
Langevin view sampling), ``runner.run_bootstrap`` / ``runner.baseline_run`` and
``job.BootstrapJob`` (the viewer's live job). Imports are lazy: reading a config stays cheap.
"""

__all__ = ["BootstrapConfig", "BootstrapJob", "run_bootstrap", "baseline_run"]


def __getattr__(name):
    if name == "BootstrapConfig":
        from .config import BootstrapConfig
        return BootstrapConfig
    if name in ("run_bootstrap", "baseline_run"):
        from . import runner
        return getattr(runner, name)
    if name == "BootstrapJob":
        from .job import BootstrapJob
        return BootstrapJob
    raise AttributeError(name)
