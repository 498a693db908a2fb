"""The colour pass's fragment shader, a cheaper drop-in for pyrender's ``mesh.frag``
(a renderer installs it with ``passes.install_mesh_shader``; see ``render_workers.render.renderer``).

It lights with the first directional light only: the renderer adds exactly one, the sun.
"""

from __future__ import annotations

# Drop-in for pyrender's mesh.frag: same inputs and uniform names, cheaper maths.
FAST_MESH_FRAG = """#version 330 core
struct DirectionalLight {
    vec3 color;
    float intensity;
    vec3 direction;
#ifdef DIRECTIONAL_LIGHT_SHADOWS
    sampler2DShadow shadow_map;  // depth compare on: a tap is a 2x2 PCF
    mat4 light_matrix;
#endif
};
struct Material {
    vec3 emissive_factor;
    vec4 base_color_factor;
    float metallic_factor;
    float roughness_factor;
#ifdef HAS_BASE_COLOR_TEX
    sampler2D base_color_texture;
#endif
};
uniform Material material;
uniform DirectionalLight directional_lights[MAX_DIRECTIONAL_LIGHTS];
uniform int n_directional_lights;
uniform vec3 cam_pos;
uniform vec3 ambient_light;
in vec3 frag_position;
#ifdef NORMAL_LOC
in vec3 frag_normal;
#endif
#ifdef COLOR_0_LOC
in vec4 color_multiplier;
#endif
#ifdef TEXCOORD_0_LOC
in vec2 uv_0;
#endif
layout(location = 0) out vec4 frag_color;
// The frame's labels in the same pass (passes.install_forward_pass, "merged"): the node's
// class and instance colour into the second colour attachment; discarded where none is bound.
layout(location = 1) out vec4 frag_seg;
uniform vec3 seg_color;
const float PI = 3.141592653589793;

#ifdef DIRECTIONAL_LIGHT_SHADOWS
uniform vec4 shadow_params;  // strength, normal offset (m), fade start (m), fade end (m)

// Share of the sun that reaches this fragment: 1 lit, 1 - strength in full shadow.
// Without branches: each early return is a select here (same values, bit for bit),
// because on llvmpipe divergent control flow costs more than the few extra ops.
float sun_visibility(sampler2DShadow map, mat4 light_matrix, vec3 n, float nl)
{
    float dist = length(cam_pos - frag_position);
    // normal offset, larger at grazing light, against acne on slopes
    vec3 p = frag_position + n * (shadow_params.y * (2.0 - nl));
    vec3 c = (light_matrix * vec4(p, 1.0)).xyz * 0.5 + 0.5;
    float inside = all(greaterThanEqual(c, vec3(0.0))) && all(lessThanEqual(c, vec3(1.0))) ? 1.0 : 0.0;
    // one tap: the hardware's 2x2 bilinear PCF. Four taps (a 3x3-texel tent) cost
    // ~0.05 CPU-s more per full-HD frame on llvmpipe for a slightly softer edge.
    float lit = texture(map, c);
    // 0 beyond the shadow distance, so a strength of 0 or a far fragment gives 1 exactly
    float fade = clamp((shadow_params.w - dist) / max(shadow_params.w - shadow_params.z, 1e-3), 0.0, 1.0);
    return 1.0 - shadow_params.x * fade * inside * (1.0 - lit);
}
#endif

void main()
{
    vec4 base = material.base_color_factor;
#ifdef COLOR_0_LOC
    base *= color_multiplier;
#endif
#ifdef HAS_BASE_COLOR_TEX
#ifdef TEXCOORD_0_LOC
    base.rgb *= texture(material.base_color_texture, uv_0).rgb;  // grey detail texture, a linear factor
#endif
#endif
    vec3 v = normalize(cam_pos - frag_position);
#ifdef NORMAL_LOC
    vec3 n = normalize(frag_normal);
#else
    vec3 n = v;
#endif
    if (dot(n, v) < 0.0) n = -n;  // two-sided
    float rough = clamp(material.roughness_factor, 0.04, 1.0);
    float metal = clamp(material.metallic_factor, 0.0, 1.0);
    vec3 diffuse = base.rgb * (1.0 - metal) / PI;
    vec3 f0 = mix(vec3(0.04), base.rgb, metal);
    float shininess = clamp(2.0 / (rough * rough * rough * rough) - 2.0, 1.0, 2048.0);
    float fresnel = pow(1.0 - max(dot(n, v), 0.0), 5.0);
    vec3 spec_colour = f0 + (1.0 - f0) * fresnel;
    vec3 color = base.rgb * ambient_light + material.emissive_factor * base.rgb;
    // The sun, the renderer's one directional light, in straight-line code: on llvmpipe a
    // loop over the lights, even one that runs once, made the colour pass ~0.04 CPU-s
    // (a quarter) dearer per full-HD frame. No branch on n.l either: a back-lit
    // fragment gets nl = 0, so it adds exactly nothing, as the loop's `continue` did.
    vec3 l = normalize(-directional_lights[0].direction);
    float nl = max(dot(n, l), 0.0);
    vec3 h = normalize(l + v);
    float spec = pow(max(dot(n, h), 0.0), shininess) * (shininess + 8.0) / (8.0 * PI);
    float sun = 1.0;
#ifdef DIRECTIONAL_LIGHT_SHADOWS
    sun = sun_visibility(directional_lights[0].shadow_map, directional_lights[0].light_matrix, n, nl);
#endif
    color += directional_lights[0].color * directional_lights[0].intensity * nl * sun
             * (diffuse + spec_colour * spec);
    frag_color = vec4(pow(clamp(color, 0.0, 1.0), vec3(1.0 / 2.2)), base.a);
    frag_seg = vec4(seg_color, 1.0);
}
"""
