// Unlit textured mesh: what a projector emits or what an albedo map shows needs no lighting model.
// Defines: HAS_TEXTURE (sample u_texture at the vertex UVs) or vertex colours otherwise.

#if defined VERTEX_SHADER

uniform mat4 u_clip_from_world;
in vec3 in_position;
#ifdef HAS_TEXTURE
in vec2 in_uv;
out vec2 v_uv;
#else
in vec4 in_color;
out vec4 v_color;
#endif

void main() {
    gl_Position = u_clip_from_world * vec4(in_position, 1.0);
#ifdef HAS_TEXTURE
    v_uv = in_uv;
#else
    v_color = in_color;
#endif
}

#elif defined FRAGMENT_SHADER

#ifdef HAS_TEXTURE
uniform sampler2D u_texture;
in vec2 v_uv;
#else
in vec4 v_color;
#endif
out vec4 f_color;

void main() {
#ifdef HAS_TEXTURE
    f_color = texture(u_texture, v_uv);
#else
    f_color = v_color;
#endif
}

#endif
