// Per-pixel Gaussian weight with the compositing rule of the torch rasterizer; premultiplied
// output for back-to-front "over" blending (ONE, ONE_MINUS_SRC_ALPHA).
uniform float flip_height;     // 0: pixel y = gl_FragCoord.y; H: pixel y = H - gl_FragCoord.y

flat in vec2 f_mean;
flat in vec3 f_conic;
flat in float f_opacity;
flat in vec3 f_value;

out vec4 out_colour;

void main() {
    // gl_FragCoord is the pixel centre (i + 0.5, j + 0.5), the contract's sample point.
    vec2 p = gl_FragCoord.xy;
    if (flip_height > 0.0) p.y = flip_height - p.y;
    vec2 d = p - f_mean;
    float power = 0.5 * (f_conic.x * d.x * d.x + f_conic.z * d.y * d.y) + f_conic.y * d.x * d.y;
    if (power < 0.0) discard;
    float alpha = min(ALPHA_MAX, f_opacity * exp(-power));
    if (alpha < ALPHA_MIN) discard;
    out_colour = vec4(f_value * alpha, alpha);
}
