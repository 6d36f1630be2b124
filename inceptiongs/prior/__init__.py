"""The scene-adaptive conditional diffusion prior (tiny backend).

hashgrid (learnable features over the scene box) -> gbuffer (normal, alpha, hash features
rendered by the torch rasterizer) -> controlnet/unet (conditional epsilon predictor) ->
schedule + ddim + multidiffusion (sampling at any resolution) -> trainer (patch training,
checkpoints in RUN/prior/). See docs/prior.md.
"""
