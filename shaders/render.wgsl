// dispdec render: flat-shaded meshes, positions already in clip space (the CPU fits each mesh
// into its slot of the image with a fixed orthographic camera). Two-sided lighting, so a mesh
// wound inward (the horse) shades like one wound outward.

struct VsOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) normal: vec3<f32>,
    @location(1) color: vec3<f32>,
};

@vertex
fn vs_main(@location(0) position: vec3<f32>, @location(1) normal: vec3<f32>, @location(2) color: vec3<f32>) -> VsOut {
    var out: VsOut;
    out.pos = vec4<f32>(position, 1.0);
    out.normal = normal;
    out.color = color;
    return out;
}

@fragment
fn fs_main(in: VsOut) -> @location(0) vec4<f32> {
    let light = normalize(vec3<f32>(0.35, 0.55, 0.75));
    let k = abs(dot(normalize(in.normal), light));
    return vec4<f32>(in.color * (0.18 + 0.82 * k), 1.0);
}
