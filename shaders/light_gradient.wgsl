// The lights' gradients for rho_i = dF/dE_i (CPU reference: model::lights::gradient).
// Needs rows.wgsl and lights.wgsl prepended. One invocation per row; each workgroup
// reduces its rows and writes, per light, 12 floats of partial sums:
//   partial[(wg * k + j) * 12 + 0..12] = dF/dp (3), dF/dI (3), dF/daxis (3), dF/dr, 0, 0
// The second entry point sums `lp.block` workgroups' partials per light and component
// (the CPU adds the blocks in f64). The lights go in tiles of 64, each invocation asking
// one whether it reaches any row of the workgroup (`group_bits`): one that reaches none
// writes zeros, the reduction of its rows' zero terms, without the reduction.

@group(0) @binding(0) var<uniform> lp: LightParams;
@group(0) @binding(1) var<storage, read> rows: array<Row>;
@group(0) @binding(2) var<storage, read> lights: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> vis: array<u32>;
@group(0) @binding(4) var<storage, read> rho: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> partial: array<f32>;
@group(0) @binding(6) var<storage, read_write> blocks: array<f32>;

const WG: u32 = 64u;
var<workgroup> red: array<array<vec4<f32>, 3>, 64>;
// For a tile of 64 lights: whether each reaches a row of this workgroup (`group_bits`).
// A light that reaches none skips the reduction: its partial sums are zeros, as the
// reduction of the rows' zero terms would give.
var<workgroup> reaches: array<u32, 64>;

@compute @workgroup_size(64)
fn main(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let wg = wid.x + wid.y * 65535u;
    let i = wg * WG + lid;
    let live = i < lp.n;
    var r: Row;
    var rh = vec3<f32>(0.0);
    if (live) {
        r = rows[i];
        rh = rho[i].xyz;
    }
    for (var t0 = 0u; t0 < lp.k; t0 = t0 + WG) {
        var bits = 0u;
        if (t0 + lid < lp.k) {
            bits = group_bits(t0 + lid, wg);
        }
        reaches[lid] = bits;
        let end = min(WG, lp.k - t0);
        for (var m = 0u; m < end; m = m + 1u) {
            let j = t0 + m;
            // (A barrier too: every flag of the tile is written before any is read.)
            if (workgroupUniformLoad(&reaches[m]) == 0u) {
                if (lid == 0u) {
                    let o = (wg * lp.k + j) * 12u;
                    for (var z = 0u; z < 12u; z = z + 1u) {
                        partial[o + z] = 0.0;
                    }
                }
                continue;
            }
            var a = vec4<f32>(0.0);
            var b = vec4<f32>(0.0);
            var c = vec4<f32>(0.0);
            if (live && visible(j, i) && any(rh != vec3<f32>(0.0))) {
                let t = light_term(r.pos, facing(r, lights[3u * j].xyz - r.pos), j);
                if (t.g != 0.0) {
                    let s = dot(rh, lights[3u * j + 1u].xyz);
                    let gi = rh * t.g;
                    a = vec4<f32>(t.dp * s, gi.x);
                    b = vec4<f32>(gi.yz, t.da.xy * s);
                    c = vec4<f32>(t.da.z * s, t.dr * s, 0.0, 0.0);
                }
            }
            red[lid][0] = a;
            red[lid][1] = b;
            red[lid][2] = c;
            for (var st = WG / 2u; st > 0u; st = st >> 1u) {
                workgroupBarrier();
                if (lid < st) {
                    for (var q = 0u; q < 3u; q = q + 1u) {
                        red[lid][q] = red[lid][q] + red[lid + st][q];
                    }
                }
            }
            workgroupBarrier();
            if (lid == 0u) {
                let o = (wg * lp.k + j) * 12u;
                for (var q = 0u; q < 3u; q = q + 1u) {
                    for (var e = 0u; e < 4u; e = e + 1u) {
                        partial[o + 4u * q + e] = red[0][q][e];
                    }
                }
            }
            workgroupBarrier();
        }
        // The next tile's flags are written only once every invocation has read these.
        workgroupBarrier();
    }
}

// One invocation per (block, light, component): sums the block's workgroups.
@compute @workgroup_size(64)
fn reduce_blocks(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = gid.x + gid.y * 65535u * 64u;
    let per_block = lp.k * 12u;
    let groups = (lp.n + WG - 1u) / WG;
    let nblocks = (groups + lp.block - 1u) / lp.block;
    if (idx >= nblocks * per_block) {
        return;
    }
    let blk = idx / per_block;
    let jq = idx % per_block;
    var s = 0.0;
    let end = min(groups, (blk + 1u) * lp.block);
    for (var g = blk * lp.block; g < end; g = g + 1u) {
        s = s + partial[g * per_block + jq];
    }
    blocks[idx] = s;
}
