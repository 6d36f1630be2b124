// Shared by the splat shaders. Packed-texture access: per-item data is a run of RGBA32F
// texels in a TEXTURE_WIDTH-wide 2-D texture (no texture buffers in moderngl, and GL 3.3
// caps buffer-less indexed reads at textures).
vec4 fetch_texel(sampler2D tex, int index) {
    return texelFetch(tex, ivec2(index % TEXTURE_WIDTH, index / TEXTURE_WIDTH), 0);
}
