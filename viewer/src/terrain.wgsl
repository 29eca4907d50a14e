// Terrain chunks: morph in the vertex shader, diffuse sun, texture, exp² fog.
// Positions reach the GPU camera-relative: chunk-local f32 vertex + the
// chunk origin minus the eye (computed in f64 on the CPU).

struct Frame {
    view_proj: mat4x4<f32>,
    // xyz: unit direction toward the sun.
    sun: vec4<f32>,
    // rgb: fog colour (= clear colour), a: fog density ρ_fog (1/m).
    fog: vec4<f32>,
    // x: fog on, y: lighting on, z: wireframe depth pull (clip z per w).
    flags: vec4<f32>,
};

struct Chunk {
    // xyz: chunk origin − eye (m), w: morph weight toward the parent.
    origin: vec4<f32>,
    base_colour: vec4<f32>,
    // x: has texture.
    opts: vec4<f32>,
};

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<uniform> chunk: Chunk;
@group(1) @binding(0) var tex: texture_2d<f32>;
@group(1) @binding(1) var samp: sampler;

struct VOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) rel: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) role: f32,
};

fn place(pos: vec3<f32>, morph_dy: f32) -> vec3<f32> {
    // The morph target is the parent surface: base + w·delta (y only).
    return pos + vec3<f32>(0.0, chunk.origin.w * morph_dy, 0.0) + chunk.origin.xyz;
}

// One vertex as both pipelines read it.
struct VIn {
    @location(0) pos: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) morph_dy: f32,
    @location(4) role: f32,
};

fn vertex(v: VIn) -> VOut {
    var out: VOut;
    let p = place(v.pos, v.morph_dy);
    out.clip = frame.view_proj * vec4<f32>(p, 1.0);
    out.rel = p;
    out.normal = v.normal;
    out.uv = v.uv;
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
    var c = chunk.base_colour.rgb;
    if (chunk.opts.x > 0.5) {
        c = c * textureSample(tex, samp, in.uv).rgb;
    }
    if (frame.flags.y > 0.5) {
        let n = normalize(in.normal);
        // Two-sided: skirts are seen from both sides.
        let diffuse = abs(dot(n, frame.sun.xyz));
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
