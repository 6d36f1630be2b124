"""How well a model renders held-out views: ``metrics`` (PSNR, SSIM, Frechet distance),
``protocols`` (which views are held out: scarce and covered groups), ``scoring`` (pure: render
and score), ``run`` (a run folder's evaluation, above training), ``generated`` (the prior's
images), ``report`` / ``report_prior`` (error against run time)."""
