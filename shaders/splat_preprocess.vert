// One vertex per Gaussian, run with transform feedback (rasterizer discarded): EWA projection,
// footprint, SH colour / depth / normal. Writes four vec4 per Gaussian that the draw pass
// reads. Rules and constants are those of the torch rasterizer (inceptiongs/constants.py,
// injected as #defines); a culled Gaussian gets opacity 0 and the draw pass collapses it.

uniform sampler2D gaussians;   // GAUSSIAN_TEXELS texels each: mean-anchor+logit, log-scales, quat, SH
uniform mat3 rotation;         // world -> camera
uniform vec3 translation;      // t = rotation * (mean - anchor) + translation
uniform vec3 camera_center;    // camera centre - anchor
uniform vec4 intrinsics;       // fx, fy, cx, cy
uniform vec2 image_size;       // W, H
uniform int mode;              // 0 rgb, 1 depth, 2 normal, 3 alpha
uniform int sh_degree;         // <= SH_DEGREE (the compiled model degree)
uniform float splat_scale;

out vec4 out_screen;   // mean2d.xy, major footprint semi-axis (pixels)
out vec4 out_conic;    // conic a, b, c, opacity (0 = culled)
out vec4 out_value;    // value rgb, camera z
out vec4 out_minor;    // minor footprint semi-axis (pixels), 0, 0

void cull() {
    out_screen = vec4(0.0);
    out_conic = vec4(0.0);
    out_value = vec4(0.0);
    out_minor = vec4(0.0);
}

mat3 quat_to_rotation(vec4 q) {
    // q = (w, x, y, z); normalised with the norm clamped, so a zero (or denormal) quaternion
    // gives the identity instead of NaN.
    q = q / max(length(q), QUAT_NORM_MIN);
    float w = q.x, x = q.y, y = q.z, z = q.w;
    // GLSL matrices are column-major: each vec3 is a column.
    return mat3(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
        2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
        2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
}

vec3 sh_coefficient(vec4 rows[SH_TEXELS], int k) {
    int f = 3 * k;
    return vec3(rows[f / 4][f % 4], rows[(f + 1) / 4][(f + 1) % 4], rows[(f + 2) / 4][(f + 2) % 4]);
}

vec3 sh_colour(vec4 rows[SH_TEXELS], vec3 dir) {
    vec3 c = SH_C0 * sh_coefficient(rows, 0);
#if SH_DEGREE > 0
    if (sh_degree > 0) {
        float x = dir.x, y = dir.y, z = dir.z;
        c += -SH_C1 * y * sh_coefficient(rows, 1) + SH_C1 * z * sh_coefficient(rows, 2)
             - SH_C1 * x * sh_coefficient(rows, 3);
#if SH_DEGREE > 1
        if (sh_degree > 1) {
            float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
            c += SH_C2_0 * xy * sh_coefficient(rows, 4) + SH_C2_1 * yz * sh_coefficient(rows, 5)
                 + SH_C2_2 * (2.0 * zz - xx - yy) * sh_coefficient(rows, 6)
                 + SH_C2_3 * xz * sh_coefficient(rows, 7) + SH_C2_4 * (xx - yy) * sh_coefficient(rows, 8);
#if SH_DEGREE > 2
            if (sh_degree > 2) {
                c += SH_C3_0 * y * (3.0 * xx - yy) * sh_coefficient(rows, 9)
                     + SH_C3_1 * xy * z * sh_coefficient(rows, 10)
                     + SH_C3_2 * y * (4.0 * zz - xx - yy) * sh_coefficient(rows, 11)
                     + SH_C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * sh_coefficient(rows, 12)
                     + SH_C3_4 * x * (4.0 * zz - xx - yy) * sh_coefficient(rows, 13)
                     + SH_C3_5 * z * (xx - yy) * sh_coefficient(rows, 14)
                     + SH_C3_6 * x * (xx - 3.0 * yy) * sh_coefficient(rows, 15);
            }
#endif
        }
#endif
    }
#endif
    return max(c + SH_OFFSET, 0.0);
}

void main() {
    int base = gl_VertexID * GAUSSIAN_TEXELS;
    vec4 mean_logit = fetch_texel(gaussians, base);
    vec3 t = rotation * mean_logit.xyz + translation;
    if (!(t.z >= NEAR_PLANE && t.z <= FAR_PLANE)) { cull(); return; }  // also rejects NaN

    float logit = clamp(mean_logit.w, -OPACITY_LOGIT_ABS_MAX, OPACITY_LOGIT_ABS_MAX);
    float opacity = 1.0 / (1.0 + exp(-logit));
    if (opacity < ALPHA_MIN) { cull(); return; }

    vec3 log_scale = clamp(fetch_texel(gaussians, base + 1).xyz, LOG_SCALE_MIN, LOG_SCALE_MAX);
    mat3 axes = quat_to_rotation(fetch_texel(gaussians, base + 2));
    // Sigma = M M^T with M = R diag(s): built as a product of a matrix with its transpose so
    // it stays symmetric positive semi-definite in float32 at any anisotropy.
    mat3 m = axes * mat3(exp(log_scale.x) * splat_scale, 0.0, 0.0,
                         0.0, exp(log_scale.y) * splat_scale, 0.0,
                         0.0, 0.0, exp(log_scale.z) * splat_scale);

    float fx = intrinsics.x, fy = intrinsics.y, cx = intrinsics.z, cy = intrinsics.w;
    // Jacobian at the mean with t.x/t.z (t.y/t.z) clamped to the image's field of view,
    // widened on each side by (FRUSTUM_CLAMP_MARGIN - 1) * half the image's angular size.
    float inv_z = 1.0 / t.z;  // t.z >= NEAR_PLANE > 0
    float widen_x = (FRUSTUM_CLAMP_MARGIN - 1.0) * 0.5 * image_size.x / fx;
    float widen_y = (FRUSTUM_CLAMP_MARGIN - 1.0) * 0.5 * image_size.y / fy;
    float tx = t.z * clamp(t.x * inv_z, -cx / fx - widen_x, (image_size.x - cx) / fx + widen_x);
    float ty = t.z * clamp(t.y * inv_z, -cy / fy - widen_y, (image_size.y - cy) / fy + widen_y);
    mat3 jacobian = mat3(fx * inv_z, 0.0, 0.0,
                         0.0, fy * inv_z, 0.0,
                         -fx * tx * inv_z * inv_z, -fy * ty * inv_z * inv_z, 0.0);
    // cov2d (before dilation) = T T^T with T = J W R diag(s) (2 x 3, the rows of tm).
    mat3 tm = jacobian * rotation * m;
    vec3 row0 = vec3(tm[0][0], tm[1][0], tm[2][0]);
    vec3 row1 = vec3(tm[0][1], tm[1][1], tm[2][1]);
    float xx = dot(row0, row0), xy = dot(row0, row1), yy = dot(row1, row1);
    // det(T T^T) = |row0 x row1|^2 (Lagrange identity): never negative and free of the
    // xx*yy - xy^2 cancellation that destroys needle-like Gaussians in float32.
    vec3 area = cross(row0, row1);
    float det = dot(area, area) + DILATION_PX * (xx + yy) + DILATION_PX * DILATION_PX;
    float a = xx + DILATION_PX, b = xy, c = yy + DILATION_PX;
    if (!(det >= DET_MIN) || isinf(det)) { cull(); return; }

    vec2 mean2d = vec2(fx * t.x * inv_z + cx, fy * t.y * inv_z + cy);
    // Footprint rule: alpha >= ALPHA_MIN  <=>  power <= log(opacity / ALPHA_MIN) (>= 0 here).
    float level = 2.0 * log(opacity / ALPHA_MIN);
    vec2 extent = sqrt(level * vec2(a, c));
    if (mean2d.x + extent.x <= 0.0 || mean2d.x - extent.x >= image_size.x ||
        mean2d.y + extent.y <= 0.0 || mean2d.y - extent.y >= image_size.y) { cull(); return; }

    vec3 value;
    if (mode == 0) {
        vec4 rows[SH_TEXELS];
        for (int i = 0; i < SH_TEXELS; ++i) rows[i] = fetch_texel(gaussians, base + 3 + i);
        vec3 dir = mean_logit.xyz - camera_center;
        // A mean at the camera centre has no direction: only the view-independent band remains.
        dir = dir / max(length(dir), 1e-30);
        value = sh_colour(rows, dir);
    } else if (mode == 2) {
        // Planar normal: the smallest-scale axis (first on ties), turned to face the camera.
        int k = 0;
        if (log_scale.y < log_scale[k]) k = 1;
        if (log_scale.z < log_scale[k]) k = 2;
        vec3 n = rotation * axes[k];
        value = dot(n, t) > 0.0 ? -n : n;
    } else {
        value = vec3(t.z);
    }
    // Tight quad: the footprint ellipse's own axes (eigenvectors of cov2d), semi-axes
    // sqrt(level * lambda). Its area is 4/pi of the ellipse, where the axis-aligned box of a
    // thin tilted splat can be hundreds of times larger: fragments are the draw's cost.
    float mid = 0.5 * (a + c);
    float lambda1 = mid + sqrt(max(0.25 * (a - c) * (a - c) + b * b, 0.0));
    float lambda2 = det / lambda1;  // lambda1 >= DILATION_PX > 0; stable for thin splats
    vec2 major = a >= c ? vec2(lambda1 - c, b) : vec2(b, lambda1 - a);
    float major_length = length(major);
    major = major_length > 0.0 ? major / major_length : vec2(1.0, 0.0);  // circle: any axis
    out_screen = vec4(mean2d, major * sqrt(level * lambda1));
    out_minor = vec4(vec2(-major.y, major.x) * sqrt(level * max(lambda2, 0.0)), 0.0, 0.0);
    out_conic = vec4(vec3(c, -b, a) / det, opacity);
    out_value = vec4(value, t.z);
}
