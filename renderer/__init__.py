"""The OpenGL splat renderer (moderngl): contexts, buffers, sorting, draw passes, read-back.
Imports no GUI; from inceptiongs only its constants, camera and model types.

Modules: ``context`` (create_offscreen_context, check_context, RendererError), ``splats``
(SplatRenderer), ``gl_camera`` (the one Camera -> GL conversion), ``sorting`` (GPU bitonic
and numpy depth sorts), ``shaders`` (GLSL loading with the constants injected),
``crosscheck`` (GL-vs-reference agreement figures), ``layout`` (the packed texel layouts the
passes share), and the CPU compositing's parts, the default on software GL such as llvmpipe
(numba): ``preprocess_numba`` (the preprocess shader's rules), ``sort_numba`` (the depth
order), ``cpu_composite`` (front to back with the stop rule), ``pack_numba`` (chosen rows
packed without gathering them). See docs/rendering.md."""
