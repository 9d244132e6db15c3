// The lights' irradiance at every row (CPU reference: model::lights::irradiance).
// Needs rows.wgsl and lights.wgsl prepended. One invocation per row.

@group(0) @binding(0) var<uniform> lp: LightParams;
@group(0) @binding(1) var<storage, read> rows: array<Row>;
@group(0) @binding(2) var<storage, read> lights: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> vis: array<u32>;
@group(0) @binding(4) var<storage, read_write> irradiance: array<vec4<f32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * 65535u * 64u;
    if (i >= lp.n) {
        return;
    }
    let r = rows[i];
    var e = vec3<f32>(0.0);
    for (var j = 0u; j < lp.k; j = j + 1u) {
        if (visible(j, i)) {
            let t = light_term(r.pos, facing(r, lights[3u * j].xyz - r.pos), j);
            e = e + lights[3u * j + 1u].xyz * t.g;
        }
    }
    irradiance[i] = vec4<f32>(e, 0.0);
}
