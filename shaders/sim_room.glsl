// The simulated site's room lit by the projector: projective texturing of the projector image onto the room
// mesh, with the projector's lens distortion, defocus (blur levels chosen by distance), inverse-square and
// cosine fall-off, shadows (shadow map from the projector) and ambient light; Lambertian surfaces.
// Output: linear radiance (cd/m², rgb) and the depth along the viewing camera's optical axis (metres).
// Define DEFERRED to output, instead of the lit colour, what any projector image needs to light this view
// (two render targets): 0: albedo rgb + depth; 1: projector irradiance per unit linear light (lux, 0 where
// unlit), the projector pixel (u, v) this point would receive light from, and the blur σ there (projector
// pixels, including the camera pixel's footprint). u, v are written even where unlit (clamped), so that
// multisample resolving stays continuous across the edges of the projected image and of shadows.

#if defined VERTEX_SHADER

uniform mat4 u_clip_from_room;
uniform mat4 u_projector_from_room;  // room → projector optical frame (OpenCV: x right, y down, z forward)
uniform vec3 u_camera_position;
uniform vec3 u_projector_position;   // room frame
in vec3 in_position;
in vec2 in_local;
// Quantities linear in the room position are computed per vertex: perspective-correct interpolation gives
// them exactly, and llvmpipe then spends ~12 % less on the pass than with a matrix product per pixel.
out vec3 v_to_camera;
out vec3 v_to_projector;
out vec3 v_projector;    // the point in the projector's optical frame
out vec2 v_local;

void main() {
    gl_Position = u_clip_from_room * vec4(in_position, 1.0);
    v_to_camera = u_camera_position - in_position;
    v_to_projector = u_projector_position - in_position;
    v_projector = (u_projector_from_room * vec4(in_position, 1.0)).xyz;
    v_local = in_local;
}

#elif defined FRAGMENT_SHADER

const float PI = 3.14159265358979;
const int MAX_LEVELS = 8;

uniform sampler2D u_albedo;          // linear reflectance, stretched over the surface
uniform vec2 u_uv_scale;
uniform vec2 u_uv_offset;
uniform vec3 u_normal;               // surface normal, room frame
uniform float u_back_albedo;         // reflectance of the back side (< 0: same as front)

uniform vec3 u_camera_axis;
uniform float u_ambient_lux;

uniform int u_projector_on;
uniform vec4 u_projector_fc;         // fx, fy, cx, cy (pixels)
uniform vec2 u_projector_size;       // width, height (pixels)
uniform float u_projector_dist[8];   // OpenCV k1 k2 p1 p2 k3 k4 k5 k6
uniform vec4 u_projector_bounds;     // undistorted normalised x0, y0, x1, y1 the image can reach
uniform float u_projector_intensity; // cd per unit linear pixel value on the axis: Φ·fx·fy / (W·H)
uniform float u_projector_falloff;   // 1 − uniformity: light lost towards the image corners (quadratic)
uniform sampler2DArray u_projector_levels;  // linear light, one layer per blur level
uniform float u_blur_levels[MAX_LEVELS];    // Gaussian σ (projector pixels) of each layer, ascending
uniform int u_n_levels;
uniform float u_defocus_px_m;        // aperture · focal length in pixels (blur circle = this · |1/s − 1/z|)
uniform float u_inverse_focus;       // 1 / focus distance (1/m)
uniform float u_lens_blur_px;
uniform float u_footprint_scale;     // camera pixels per rendered pixel (a supersampled view: 2)

uniform int u_shadows_on;
uniform sampler2D u_shadow_depth;    // projector-axis depth of the nearest surface, pinhole view
uniform vec4 u_shadow_fc;            // fx, fy, cx, cy of that pinhole view
uniform vec2 u_shadow_size;

in vec3 v_to_camera;
in vec3 v_to_projector;
in vec3 v_projector;
in vec2 v_local;
#ifdef DEFERRED
layout(location = 0) out vec4 f_albedo;
layout(location = 1) out vec4 f_projector;
#else
out vec4 f_out;
#endif

vec2 distort(vec2 xy) {
    float r2 = dot(xy, xy);
    float r4 = r2 * r2;
    float r6 = r4 * r2;
    float k1 = u_projector_dist[0], k2 = u_projector_dist[1], p1 = u_projector_dist[2];
    float p2 = u_projector_dist[3], k3 = u_projector_dist[4], k4 = u_projector_dist[5];
    float k5 = u_projector_dist[6], k6 = u_projector_dist[7];
    float radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6);
    return vec2(xy.x * radial + 2.0 * p1 * xy.x * xy.y + p2 * (r2 + 2.0 * xy.x * xy.x),
                xy.y * radial + p1 * (r2 + 2.0 * xy.y * xy.y) + 2.0 * p2 * xy.x * xy.y);
}

void main() {
    vec3 to_camera = v_to_camera;
    float camera_side = dot(u_normal, to_camera);
    vec3 albedo = texture(u_albedo, v_local * u_uv_scale + u_uv_offset).rgb;
    if (camera_side < 0.0 && u_back_albedo >= 0.0) {
        albedo = vec3(u_back_albedo);
    }

    // Projector: every quantity is computed unconditionally (texture derivatives need uniform control
    // flow) and masked at the end.
    vec3 q = v_projector;
    float z = max(q.z, 1e-6);
    vec2 xy = q.xy / z;
    vec2 pixel = u_projector_fc.xy * distort(xy) + u_projector_fc.zw;
    vec2 st = (pixel + 0.5) / u_projector_size;

    float sigma_defocus = u_defocus_px_m * abs(u_inverse_focus - 1.0 / z) / 4.0;
    float sigma = sqrt(u_lens_blur_px * u_lens_blur_px + sigma_defocus * sigma_defocus);
#ifndef DEFERRED
    float layer = 0.0;
    for (int i = 0; i < MAX_LEVELS - 1; ++i) {
        if (i + 1 < u_n_levels && sigma > u_blur_levels[i]) {
            float span = u_blur_levels[i + 1] - u_blur_levels[i];
            layer = float(i) + clamp((sigma - u_blur_levels[i]) / span, 0.0, 1.0);
        }
    }
    int l0 = int(floor(layer));
    int l1 = min(l0 + 1, u_n_levels - 1);
    vec3 c0 = texture(u_projector_levels, vec3(st, float(l0))).rgb;
    vec3 c1 = texture(u_projector_levels, vec3(st, float(l1))).rgb;
    vec3 light = mix(c0, c1, layer - float(l0));
#endif

    vec3 to_projector = v_to_projector;
    float d2 = dot(to_projector, to_projector);
    float projector_side = dot(u_normal, to_projector);
    float cos_incidence = abs(projector_side) / sqrt(d2);
    float lit = float(u_projector_on == 1) * float(q.z > 1e-6)
        * float(projector_side * camera_side > 0.0)
        * float(all(greaterThanEqual(xy, u_projector_bounds.xy)) && all(lessThanEqual(xy, u_projector_bounds.zw)))
        * float(all(greaterThanEqual(st, vec2(0.0))) && all(lessThanEqual(st, vec2(1.0))));
    if (u_shadows_on == 1) {
        vec2 sp = u_shadow_fc.xy * xy + u_shadow_fc.zw;
        ivec2 texel = ivec2(floor(sp + 0.5));
        texel = clamp(texel, ivec2(0), ivec2(u_shadow_size) - 1);
        float occluder = texelFetch(u_shadow_depth, texel, 0).r;
        lit *= float(z <= occluder * 1.002 + 0.002);
    }
    vec2 from_centre = (pixel - 0.5 * (u_projector_size - 1.0)) / (0.5 * u_projector_size);
    float intensity = u_projector_intensity * pow(1.0 + dot(xy, xy), 1.5)
        * (1.0 - 0.5 * u_projector_falloff * dot(from_centre, from_centre));
    float depth = dot(-to_camera, u_camera_axis);

#ifdef DEFERRED
    // A camera pixel integrates the projector image over its footprint: a box of that width has σ ≈ w/√12.
    vec2 footprint = u_footprint_scale * max(abs(dFdx(pixel)), abs(dFdy(pixel)));
    float sigma_pixel = 0.2887 * max(footprint.x, footprint.y);
    float sigma_total = sqrt(sigma * sigma + sigma_pixel * sigma_pixel);
    f_albedo = vec4(albedo, depth);
    f_projector = vec4(lit * intensity * cos_incidence / d2, clamp(pixel, vec2(-1000.0), u_projector_size + 1000.0),
                       sigma_total);
#else
    vec3 irradiance = vec3(u_ambient_lux) + lit * intensity * cos_incidence / d2 * light;
    f_out = vec4(albedo * irradiance / PI, depth);
#endif
}

#endif
