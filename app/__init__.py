"""The desktop viewer/editor (GLFW + imgui-bundle) over the GL splat renderer."""
