"""Stage I: the PGSR-style planar 3DGS trainer.

``config.TrainConfig`` (the settings), ``step`` (one step and its data and state),
``trainer.train`` (the loop into a run folder), ``run_folder.load_run`` (a finished or
interrupted run -> Gaussians, Scene, config), ``job.TrainJob`` (the loop on a viewer thread).
Nothing is imported here: each caller imports the module it needs.
"""
