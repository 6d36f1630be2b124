// Shows a frame composited on the CPU (renderer/cpu_composite.py) in the caller's framebuffer:
// texel = (sum T alpha value, final T, negated where the stop rule finished the pixel), row 0 =
// image top. Output is premultiplied with alpha = 1 - T for (ONE, ONE_MINUS_SRC_ALPHA) blending
// over the cleared background, the same result the back-to-front draw gives.
uniform sampler2D composited;
uniform int image_height;
out vec4 out_colour;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 texel = texelFetch(composited, ivec2(pixel.x, image_height - 1 - pixel.y), 0);
    out_colour = vec4(texel.rgb, 1.0 - abs(texel.a));
}
