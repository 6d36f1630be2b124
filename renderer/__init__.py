"""The OpenGL splat renderer (moderngl): contexts, buffers, sorting, draw passes, read-back.
Imports no GUI; from inceptiongs only its constants, camera and model types.

Modules: ``context`` (create_offscreen_context, check_context, RendererError), ``splats``
(SplatRenderer), ``gl_camera`` (the one Camera -> GL conversion), ``sorting`` (GPU bitonic
and numpy depth sorts), ``shaders`` (GLSL loading with the constants injected),
``crosscheck`` (GL-vs-reference agreement figures), ``cpu_composite`` (front-to-back
compositing of the preprocessed splats on the CPU cores: the default on software GL such as
llvmpipe, numba). See docs/rendering.md."""
