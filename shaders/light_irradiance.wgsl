// The lights' irradiance at every row (CPU reference: model::lights::irradiance).
// Needs rows.wgsl and lights.wgsl prepended. One invocation per row. The lights go in
// tiles of 64: each invocation asks one light of the tile whether it reaches any row of
// the workgroup (`group_bits`), and the rows then visit only those, in order, so a light
// shadowed from the group or traced short of it costs one flag read, not a term; the
// sums are those of visiting every light (a light that reaches no row added nothing).

@group(0) @binding(0) var<uniform> lp: LightParams;
@group(0) @binding(1) var<storage, read> rows: array<Row>;
@group(0) @binding(2) var<storage, read> lights: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> vis: array<u32>;
@group(0) @binding(4) var<storage, read_write> irradiance: array<vec4<f32>>;

const WG: u32 = 64u;
// For the tile's 64 lights: whether each reaches a row of this workgroup.
var<workgroup> reaches: array<u32, 64>;

@compute @workgroup_size(64)
fn main(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let wg = wid.x + wid.y * 65535u;
    let i = wg * WG + lid;
    let live = i < lp.n;
    var r: Row;
    if (live) {
        r = rows[i];
    }
    var e = vec3<f32>(0.0);
    for (var t0 = 0u; t0 < lp.k; t0 = t0 + WG) {
        var b = 0u;
        if (t0 + lid < lp.k) {
            b = group_bits(t0 + lid, wg);
        }
        reaches[lid] = b;
        workgroupBarrier();
        let end = min(WG, lp.k - t0);
        for (var q = 0u; q < end; q = q + 1u) {
            let j = t0 + q;
            if (reaches[q] != 0u && live && visible(j, i)) {
                let t = light_term(r.pos, facing(r, lights[3u * j].xyz - r.pos), j);
                e = e + lights[3u * j + 1u].xyz * t.g;
            }
        }
        workgroupBarrier();
    }
    if (live) {
        irradiance[i] = vec4<f32>(e, 0.0);
    }
}
