// Shadow map of the simulated projector: depth along the projector's optical axis of the nearest surface,
// rendered through the projector's (enlarged, undistorted) pinhole view.

#if defined VERTEX_SHADER

uniform mat4 u_clip_from_room;
uniform mat4 u_projector_from_room;
in vec3 in_position;
in vec2 in_local;
out float v_depth;

void main() {
    gl_Position = u_clip_from_room * vec4(in_position, 1.0);
    v_depth = (u_projector_from_room * vec4(in_position, 1.0)).z;
}

#elif defined FRAGMENT_SHADER

in float v_depth;
out float f_depth;

void main() {
    f_depth = v_depth;
}

#endif
