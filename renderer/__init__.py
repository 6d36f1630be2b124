"""The OpenGL splat renderer (moderngl): contexts, buffers, sorting, draw passes, read-back.
Imports no GUI; from inceptiongs only its constants, camera and model types."""
