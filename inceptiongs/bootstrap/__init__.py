"""Stage II: generative bootstrapping of badly observed regions (docs/bootstrap.md).

Read in this order:
``runner.run_bootstrap`` (a :class:`stage1.Stage1` in, RUN2 out; ``runner.baseline_run`` is the
same loop on the photos alone) -> ``loop.Bootstrap`` (prepare, a round's virtual views and their
I*, refine, finish; the clocks, bar and pause come from ``inceptiongs.train.loop``) ->
``view_targets`` (I* at one virtual view: the fill, ``supervise`` for the photos warped in) ->
``refine`` (virtual-view steps, Langevin view sampling).

Pieces: ``config.BootstrapConfig``, ``targets`` (flags, a named view or j*), ``virtual_views``,
``warp``, ``source_depth``, ``agreement``, ``conscience``, ``generation`` (prior, cache),
``langevin``, ``perceptual``; ``supervision_kinds`` (the interface of the supervision kinds);
``job.BootstrapJob`` (the viewer's live job). ``experimental/`` holds the variants that were
measured and left off by default, still selectable by their config fields. Nothing is imported
here: each caller imports the module it needs.
"""
