#version 330 core
struct DirectionalLight { vec3 color; float intensity; vec3 direction; };
struct Material {
    vec3 emissive_factor; vec4 base_color_factor; float metallic_factor; float roughness_factor;
#ifdef HAS_BASE_COLOR_TEX
    sampler2D base_color_texture;
#endif
};
uniform Material material;
uniform DirectionalLight directional_lights[MAX_DIRECTIONAL_LIGHTS];
uniform int n_directional_lights;
uniform vec3 ambient_light;
in vec3 frag_position;
#ifdef NORMAL_LOC
in vec3 frag_normal;
#endif
#ifdef TEXCOORD_0_LOC
in vec2 uv_0;
#endif
out vec4 frag_color;
void main()
{
    vec3 light = ambient_light;
#ifdef NORMAL_LOC
    vec3 n = normalize(frag_normal);
    for (int i = 0; i < n_directional_lights; i++) {
        float nl = max(dot(n, -normalize(directional_lights[i].direction)), 0.0);
        light += directional_lights[i].color * directional_lights[i].intensity * nl;
    }
#endif
    vec3 base = material.base_color_factor.rgb;
#ifdef HAS_BASE_COLOR_TEX
#ifdef TEXCOORD_0_LOC
    base *= pow(texture(material.base_color_texture, uv_0).rgb, vec3(2.2));  // display -> linear
#endif
#endif
    vec3 colour = clamp(base * light, 0.0, 1.0);
    frag_color = vec4(pow(colour, vec3(1.0 / 2.2)), 1.0);
}
