// Per-pixel Gaussian weight with the compositing rule of the torch rasterizer.
//
// FRONT_TO_BACK (needs GL_EXT_shader_framebuffer_fetch; Gaussians drawn near to far): the
// shader reads the pixel so far and composites exactly like the torch rasterizer, stop rule
// included: colour.rgb accumulates T * alpha * value, colour.a holds T, stored negated once
// the pixel is finished (T * (1 - alpha) would fall below TRANSMITTANCE_MIN), after which
// every later fragment is dropped. Blending is off.
// Otherwise (Gaussians drawn far to near): premultiplied output for "over" blending
// (ONE, ONE_MINUS_SRC_ALPHA); such a pixel cannot stop early (see docs/rendering.md).
#ifdef FRONT_TO_BACK
#extension GL_EXT_shader_framebuffer_fetch : require
inout vec4 out_colour;
#else
out vec4 out_colour;
#endif

uniform float flip_height;     // 0: pixel y = gl_FragCoord.y; H: pixel y = H - gl_FragCoord.y

flat in vec2 f_mean;
flat in vec3 f_conic;
flat in float f_opacity;
flat in vec3 f_value;

void main() {
#ifdef FRONT_TO_BACK
    float transmittance = out_colour.a;
    if (transmittance < 0.0) discard;  // finished pixel
#endif
    // gl_FragCoord is the pixel centre (i + 0.5, j + 0.5), the contract's sample point.
    vec2 p = gl_FragCoord.xy;
    if (flip_height > 0.0) p.y = flip_height - p.y;
    vec2 d = p - f_mean;
    float power = 0.5 * (f_conic.x * d.x * d.x + f_conic.z * d.y * d.y) + f_conic.y * d.x * d.y;
    if (power < 0.0) discard;
    float alpha = min(ALPHA_MAX, f_opacity * exp(-power));
    if (alpha < ALPHA_MIN) discard;
#ifdef FRONT_TO_BACK
    float next = transmittance * (1.0 - alpha);
    if (next < TRANSMITTANCE_MIN) {
        out_colour.a = -transmittance;
        return;
    }
    out_colour = vec4(out_colour.rgb + transmittance * alpha * f_value, next);
#else
    out_colour = vec4(f_value * alpha, alpha);
#endif
}
