// Forward model, objective and gradient (relight/src/model.rs is the CPU reference and
// documents the math). One invocation per problem vertex; each workgroup reduces its
// vertices' contributions and writes one block of partial sums:
//   block[wg * stride + 8 * j + 0..6]        = dF/dp_j (3), dF/dI_j (3)
//   block[wg * stride + 8 * K + 0..6]        = dF/dw (3), dF/dS (3) of the sun
//   block[wg * stride + 8 * (K + 1) + 0..8]  = F, sum A w (x - t)^2, dF/da (3), dF/dk (3)
// Needs problem.wgsl prepended.

struct Params {
    n: u32,
    k: u32,
    words: u32,
    stride: u32,
    ambient: vec4<f32>,
    indirect: vec4<f32>,
    // xyz: unit direction towards the sun; w: 1 when the model has a sun.
    sun_dir: vec4<f32>,
    // Irradiance at normal incidence, W/m^2.
    sun_rgb: vec4<f32>,
    eps: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
}

@group(0) @binding(0) var<uniform> prm: Params;
@group(0) @binding(1) var<storage, read> verts: array<Vertex>;
@group(0) @binding(2) var<storage, read> lights: array<vec4<f32>>; // pos, rgb per light
@group(0) @binding(3) var<storage, read> vis: array<u32>;
@group(0) @binding(4) var<storage, read_write> partial: array<f32>;
@group(0) @binding(5) var<storage, read> sun_vis: array<u32>;

const WG: u32 = 64u;
const PI: f32 = 3.14159265358979;
var<workgroup> red_a: array<vec4<f32>, 64>;
var<workgroup> red_b: array<vec4<f32>, 64>;

struct G {
    g: f32,
    dg: vec3<f32>,
}

fn geometry_term(x: vec3<f32>, n: vec3<f32>, p: vec3<f32>, eps: f32) -> G {
    let d = p - x;
    let s = dot(n, d);
    let r2 = dot(d, d);
    if (!(s > 0.0) || !(r2 > 0.0)) {
        return G(0.0, vec3<f32>(0.0));
    }
    let r = sqrt(r2);
    let e2 = eps * eps;
    if (r2 > e2) {
        let r3 = r2 * r;
        return G(s / r3, n / r3 - d * (3.0 * s / (r3 * r2)));
    }
    return G(s / (r * e2), n / (r * e2) - d * (s / (r2 * r * e2)));
}

fn visible(j: u32, i: u32) -> bool {
    return ((vis[j * prm.words + (i >> 5u)] >> (i & 31u)) & 1u) == 1u;
}

fn sun_visible(i: u32) -> bool {
    return prm.sun_dir.w > 0.5 && ((sun_vis[i >> 5u] >> (i & 31u)) & 1u) == 1u;
}

// Sums `a` and `b` over the workgroup and stores the 8 sums at `partial[o..o + 8]`
// (a.xyzw, then b.xyzw). Every invocation of the workgroup must call it.
fn reduce_store(lid: u32, a: vec4<f32>, b: vec4<f32>, o: u32) {
    red_a[lid] = a;
    red_b[lid] = b;
    reduce(lid);
    if (lid == 0u) {
        for (var q = 0u; q < 4u; q = q + 1u) {
            partial[o + q] = red_a[0][q];
            partial[o + 4u + q] = red_b[0][q];
        }
    }
    workgroupBarrier();
}

fn reduce(lid: u32) {
    for (var s = WG / 2u; s > 0u; s = s >> 1u) {
        workgroupBarrier();
        if (lid < s) {
            red_a[lid] = red_a[lid] + red_a[lid + s];
            red_b[lid] = red_b[lid] + red_b[lid + s];
        }
    }
    workgroupBarrier();
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let i = gid.x;
    let lid = lid3.x;
    let live = i < prm.n;
    var v: Vertex;
    if (live) {
        v = verts[i];
    }
    // Irradiance (before 1/pi) per channel: the sun, then the point lights.
    var e = vec3<f32>(0.0);
    var cos_sun = 0.0;
    if (live && sun_visible(i)) {
        cos_sun = max(dot(v.normal, prm.sun_dir.xyz), 0.0);
        e = prm.sun_rgb.xyz * cos_sun;
    }
    if (live) {
        for (var j = 0u; j < prm.k; j = j + 1u) {
            if (visible(j, i)) {
                let gt = geometry_term(v.pos, v.normal, lights[2u * j].xyz, prm.eps);
                e = e + lights[2u * j + 1u].xyz * gt.g;
            }
        }
    }
    var rho_a = vec3<f32>(0.0);
    var f = 0.0;
    var num = 0.0;
    var ga = vec3<f32>(0.0);
    var gk = vec3<f32>(0.0);
    if (live) {
        for (var c = 0u; c < 3u; c = c + 1u) {
            let a = v.albedo[c];
            let o = v.indirect[c];
            let x = a * (e[c] / PI + prm.ambient[c]) + prm.indirect[c] * o;
            let w = v.weight[c];
            let two = x - v.goal[c];
            let one = min(x - v.lower[c], 0.0);
            f = f + 0.5 * v.area * (w * two * two + (1.0 - w) * one * one);
            num = num + v.area * w * two * two;
            let rho = v.area * (w * two + (1.0 - w) * one);
            rho_a[c] = rho * a / PI;
            ga[c] = rho * a;
            gk[c] = rho * o;
        }
    }
    let base = wid.x * prm.stride;
    for (var j = 0u; j < prm.k; j = j + 1u) {
        var gp = vec3<f32>(0.0);
        var gi = vec3<f32>(0.0);
        if (live && visible(j, i)) {
            let gt = geometry_term(v.pos, v.normal, lights[2u * j].xyz, prm.eps);
            gi = rho_a * gt.g;
            gp = gt.dg * dot(rho_a, lights[2u * j + 1u].xyz);
        }
        reduce_store(lid, vec4<f32>(gp, gi.x), vec4<f32>(gi.yz, 0.0, 0.0), base + 8u * j);
    }
    // The sun's gradient.
    var gw = vec3<f32>(0.0);
    var gs = vec3<f32>(0.0);
    if (live && cos_sun > 0.0) {
        gs = rho_a * cos_sun;
        gw = v.normal * dot(rho_a, prm.sun_rgb.xyz);
    }
    reduce_store(lid, vec4<f32>(gw, gs.x), vec4<f32>(gs.yz, 0.0, 0.0), base + 8u * prm.k);
    reduce_store(lid, vec4<f32>(f, num, ga.xy), vec4<f32>(ga.z, gk), base + 8u * (prm.k + 1u));
}
