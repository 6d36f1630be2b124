"""Run folders, below training: what every command and the viewer open.

``config.TrainConfig`` (RUN/config.json), ``folder`` (where runs go, whether a folder holds a
result), ``metrics`` (RUN/metrics.jsonl), ``checkpoint`` (RUN/checkpoints), ``lock`` (one writer
per run folder), ``frames`` (normalised <-> original frame), ``load.load_run`` (a run -> its
Gaussians, scene and config). Nothing is imported here: each caller imports the module it needs.
"""
