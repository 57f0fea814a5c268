// Second pass: applies a lens's distortion to a pinhole render.
// u_map holds, for each pixel of the distorted image, where to sample the pinhole render (pixel units,
// OpenCV convention: pixel centres at integers). Both images are stored top row first.

#if defined VERTEX_SHADER

// One triangle that covers the viewport; no vertex buffer needed.
void main() {
    vec2 corner = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    gl_Position = vec4(corner * 2.0 - 1.0, 0.0, 1.0);
}

#elif defined FRAGMENT_SHADER

uniform sampler2D u_pinhole;
uniform sampler2D u_map;
uniform vec2 u_pinhole_size;
out vec4 f_color;

void main() {
    vec2 where = texelFetch(u_map, ivec2(gl_FragCoord.xy), 0).xy;
    f_color = texture(u_pinhole, (where + 0.5) / u_pinhole_size);
}

#endif
