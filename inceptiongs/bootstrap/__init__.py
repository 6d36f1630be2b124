"""Stage II: generative bootstrapping of badly observed regions (docs/bootstrap.md).

Read in this order:
``runner.run_bootstrap`` (a :class:`stage1.Stage1` in, RUN2 out; ``runner.baseline_run`` is the
same loop on the photos alone) -> ``prepare`` (RUN2, the restored state, the round plan and the
pool: ``state.Setting``, ``plan.RoundPlan``, ``state.LoopState``, ``pool.ViewPool``) ->
``loop`` (the rounds and their steps, the finish; the clocks, bar and pause come from
``inceptiongs.train.loop``) -> ``round_views`` (a round's views into the pool) ->
``view_targets`` (I* at one virtual view: the fill, ``supervise`` for the photos warped in) ->
``refine`` (virtual-view steps, Langevin view sampling).

Pieces: ``config.BootstrapConfig`` (``options``: how settings are declared and read),
``targets`` (flags, a named view or j*), ``virtual_views``, ``warp``, ``source_depth``,
``agreement``, ``conscience``, ``outlook``, ``generation`` (prior, cache), ``langevin``,
``perceptual``; ``view_supervision`` (what a supervision works on and returns);
``job.BootstrapJob`` (the viewer's live job). ``variants`` is the one door to ``experimental/``,
the variants that were measured and left off by default, chosen by name in
``BootstrapConfig.variants``. Nothing is imported here: each caller imports the module it needs.
"""
