"""Stage I: the PGSR-style planar 3DGS trainer.

``step`` (one step and its data and state), ``trainer.train`` (the loop into a run folder),
``strategies`` (default | mcmc | dropgaussian), ``job.TrainJob`` (the loop on a viewer thread).
The run folder it writes (config, checkpoints, metrics, loading) is ``inceptiongs.runs``.
Nothing is imported here: each caller imports the module it needs.
"""
