// Terrain chunks: morph in the vertex shader (position and normal), one-sided
// diffuse sun, texture, normal map, exp² fog. Positions reach the GPU
// camera-relative: chunk-local f32 vertex + the chunk origin minus the eye
// (computed in f64 on the CPU).

struct Frame {
    view_proj: mat4x4<f32>,
    // xyz: unit direction toward the sun.
    sun: vec4<f32>,
    // rgb: fog colour (= clear colour), a: fog density ρ_fog (1/m).
    fog: vec4<f32>,
    // x: fog on, y: lighting on, z: wireframe depth pull (clip z per w).
    flags: vec4<f32>,
    // x: wireframe mode (surfaces fill with the fog colour, hiding lines).
    mode: vec4<f32>,
};

struct Chunk {
    // xyz: chunk origin − eye (m), w: morph weight toward the parent.
    origin: vec4<f32>,
    base_colour: vec4<f32>,
    // x: has texture, y: has normal map, z: the normal map reads TEXCOORD_1.
    opts: vec4<f32>,
};

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<uniform> chunk: Chunk;
@group(1) @binding(0) var tex: texture_2d<f32>;
@group(1) @binding(1) var samp: sampler;
@group(1) @binding(2) var normal_tex: texture_2d<f32>;

struct VOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) rel: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) role: f32,
    @location(4) uv1: vec2<f32>,
};

fn place(pos: vec3<f32>, morph: vec3<f32>) -> vec3<f32> {
    // The morph target is the parent surface: base + w·delta.
    return pos + chunk.origin.w * morph + chunk.origin.xyz;
}

// One vertex as both pipelines read it.
struct VIn {
    @location(0) pos: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) morph: vec3<f32>,
    @location(4) role: f32,
    @location(5) parent_normal: vec3<f32>,
    @location(6) uv1: vec2<f32>,
};

fn vertex(v: VIn) -> VOut {
    var out: VOut;
    let p = place(v.pos, v.morph);
    out.clip = frame.view_proj * vec4<f32>(p, 1.0);
    out.rel = p;
    // The parent's normal is linear inside each parent triangle, so at w = 1
    // the interpolated normal is the parent's at every pixel: no shading pop.
    out.normal = mix(v.normal, v.parent_normal, chunk.origin.w);
    out.uv = v.uv;
    out.uv1 = v.uv1;
    out.role = v.role;
    return out;
}

@vertex
fn vs_main(v: VIn) -> VOut {
    return vertex(v);
}

@vertex
fn vs_wire(v: VIn) -> VOut {
    var out = vertex(v);
    // Reversed Z: pull the line toward the eye so the surface does not hide it.
    out.clip.z = out.clip.z + frame.flags.z * out.clip.w;
    return out;
}

fn shade(in: VOut) -> vec4<f32> {
    if (frame.mode.x > 0.5) {
        return vec4<f32>(frame.fog.rgb, 1.0);
    }
    var c = chunk.base_colour.rgb;
    // Sampled outside the branches: uniform control flow for the derivatives.
    let albedo = textureSample(tex, samp, in.uv).rgb;
    let nuv = select(in.uv, in.uv1, chunk.opts.z > 0.5);
    let tn = textureSample(normal_tex, samp, nuv).rgb * 2.0 - 1.0;
    if (chunk.opts.x > 0.5) {
        c = c * albedo;
    }
    if (frame.flags.y > 0.5) {
        var n = normalize(in.normal);
        if (chunk.opts.y > 0.5) {
            // Tangent frame from the vertex: N its normal (+y in the flat
            // frame, the ground's up in the curved one), T the chunk's +x
            // made perpendicular to it, B = N × T (north, −z when flat).
            let t = normalize(vec3<f32>(1.0, 0.0, 0.0) - n * n.x);
            n = normalize(t * tn.x + cross(n, t) * tn.y + n * tn.z);
        }
        // One-sided: a face turned away from the sun gets the ambient term only.
        let diffuse = max(dot(n, frame.sun.xyz), 0.0);
        c = c * (0.3 + 0.8 * diffuse);
    }
    if (frame.flags.x > 0.5) {
        let d = length(in.rel) * frame.fog.a;
        let f = exp2(-1.442695 * d * d);
        c = mix(frame.fog.rgb, c, f);
    }
    return vec4<f32>(c, 1.0);
}

@fragment
fn fs_main(in: VOut) -> @location(0) vec4<f32> {
    return shade(in);
}

struct Capture {
    @location(0) colour: vec4<f32>,
    // xyz: camera-relative position (m), w: 1 surface, 2 skirt (0 = nothing).
    @location(1) position: vec4<f32>,
};

@fragment
fn fs_capture(in: VOut) -> Capture {
    var out: Capture;
    out.colour = shade(in);
    out.position = vec4<f32>(in.rel, 1.0 + in.role);
    return out;
}

@fragment
fn fs_wire(in: VOut) -> @location(0) vec4<f32> {
    return vec4<f32>(0.05, 0.05, 0.08, 1.0);
}

@fragment
fn fs_wire_capture(in: VOut) -> Capture {
    var out: Capture;
    out.colour = vec4<f32>(0.05, 0.05, 0.08, 1.0);
    out.position = vec4<f32>(in.rel, 1.0 + in.role);
    return out;
}
