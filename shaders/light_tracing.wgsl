// The thesis's light-tracing estimator: one invocation per (ray, light); bvh.wgsl is
// prepended. The CPU reference is relight/src/light_tracing.rs: the same random numbers,
// the same paths, the same fixed-point deposits.
//
// `irradiance`: every deposit adds round(flux * weight / unit) to its row's channel as a
// 64-bit integer (two u32 words, the carry added when the low word wraps), so the sum does
// not depend on the order the invocations run in.
// `gradient`: each invocation's derivative of sum rho E with respect to its light (flux
// per unit intensity, position), summed per workgroup; one workgroup holds rays of one
// light only (dispatch: x over the rays, y over the lights).

struct TracingParams {
    rays: u32,
    lights: u32,
    bounces: u32,
    seed: u32,
    sample: u32,
    groups_x: u32,
    // W per fixed-point count.
    unit: f32,
    // Segment length that crosses the scene, m.
    reach: f32,
    // Bounce rays start this far off the surface, m.
    offset: f32,
    // Flux per ray per W/sr of intensity: 4 pi / rays.
    per_intensity: f32,
    pad0: f32,
    pad1: f32,
}

struct SplatTri {
    v: vec4<u32>,
    a: vec4<f32>,
    n: vec4<f32>,
    gu: vec4<f32>,
    gv: vec4<f32>,
}

struct SplatVertex {
    albedo: vec3<f32>,
    row: u32,
    inv_area: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
}

// pos: m; rgb: flux per ray, W.
struct TracingLight {
    pos: vec4<f32>,
    rgb: vec4<f32>,
}

@group(0) @binding(0) var<uniform> tp: TracingParams;
@group(0) @binding(1) var<storage, read> nodes: array<Node>;
@group(0) @binding(2) var<storage, read> tris: array<Tri>;
@group(0) @binding(3) var<storage, read> tri_index: array<u32>;
@group(0) @binding(4) var<storage, read> splat_tris: array<SplatTri>;
@group(0) @binding(5) var<storage, read> splat_verts: array<SplatVertex>;
@group(0) @binding(6) var<storage, read> tlights: array<TracingLight>;
@group(0) @binding(7) var<storage, read_write> acc: array<atomic<u32>>;
@group(0) @binding(8) var<storage, read> rho: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> partial: array<f32>;

const NO_ROW: u32 = 0xffffffffu;
const PI: f32 = 3.14159265358979;

fn pcg(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

fn rand(j: u32, r: u32, dim: u32) -> f32 {
    let h = pcg(tp.seed ^ pcg(tp.sample ^ pcg(j ^ pcg(r ^ pcg(dim)))));
    return f32(h >> 8u) * (1.0 / 16777216.0);
}

fn sphere(u1: f32, u2: f32) -> vec3<f32> {
    let z = 1.0 - 2.0 * u1;
    let r = sqrt(max(1.0 - z * z, 0.0));
    let phi = 2.0 * PI * u2;
    return vec3<f32>(r * cos(phi), r * sin(phi), z);
}

fn cosine_dir(n: vec3<f32>, u1: f32, u2: f32) -> vec3<f32> {
    let sgn = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (sgn + n.z);
    let b = n.x * n.y * a;
    let t1 = vec3<f32>(1.0 + sgn * n.x * n.x * a, sgn * b, -sgn * n.x);
    let t2 = vec3<f32>(b, sgn + n.y * n.y * a, -n.y);
    let r = sqrt(u1);
    let phi = 2.0 * PI * u2;
    return normalize(t1 * (r * cos(phi)) + t2 * (r * sin(phi)) + n * sqrt(max(1.0 - u1, 0.0)));
}

// Nearest hit along o + s d, s in (0, 1): Bvh::first_hit (bvh.wgsl's walk; the mesh's
// triangle index in `tri`, or a negative `t` where nothing is hit).
fn first_hit(o: vec3<f32>, d: vec3<f32>) -> Hit {
    var h = first_hit_after(o, d, signs(d), 0.0, 1.0, -1.0);
    if (h.tri != NO_HIT) {
        h.tri = tri_index[h.tri];
    }
    return h;
}

fn weights_at(st: SplatTri, x: vec3<f32>) -> vec3<f32> {
    let u = clamp(dot(st.gu.xyz, x - st.a.xyz), 0.0, 1.0);
    let v = clamp(dot(st.gv.xyz, x - st.a.xyz), 0.0, 1.0);
    return vec3<f32>(max(1.0 - u - v, 0.0), u, v);
}

fn add64(i: u32, q: u32) {
    let old = atomicAdd(&acc[2u * i], q);
    if (old > 0xffffffffu - q) {
        atomicAdd(&acc[2u * i + 1u], 1u);
    }
}

struct Grad {
    rgb: vec3<f32>,
    pos: vec3<f32>,
}

// Ray r of light j: deposits (irradiance) or the derivative of sum rho E (gradient).
fn walk(j: u32, r: u32, gradient: bool) -> Grad {
    var g = Grad(vec3<f32>(0.0), vec3<f32>(0.0));
    let light = tlights[j];
    var o = light.pos.xyz;
    var d = sphere(rand(j, r, 0u), rand(j, r, 1u));
    var w = select(light.rgb.xyz, vec3<f32>(tp.per_intensity), gradient);
    for (var leg = 0u; leg <= tp.bounces; leg = leg + 1u) {
        let h = first_hit(o, d * tp.reach);
        if (h.t < 0.0) {
            break;
        }
        let st = splat_tris[h.tri];
        let n = st.n.xyz;
        if (!(dot(n, d) < 0.0)) {
            break;
        }
        let x = o + d * (h.t * tp.reach);
        let bw = weights_at(st, x);
        let sv0 = splat_verts[st.v.x];
        let sv1 = splat_verts[st.v.y];
        let sv2 = splat_verts[st.v.z];
        if (sv0.row == NO_ROW && sv1.row == NO_ROW && sv2.row == NO_ROW) {
            break;
        }
        var gx = vec3<f32>(0.0);
        for (var k = 0u; k < 3u; k = k + 1u) {
            let sv = splat_verts[st.v[k]];
            if (sv.row == NO_ROW) {
                continue;
            }
            if (gradient) {
                let rr = rho[sv.row].xyz;
                let dep = w * sv.inv_area;
                g.rgb = g.rgb + rr * dep * bw[k];
                // light.rgb is the flux per ray: over 4 pi / rays, the intensity.
                let sk = dot(rr * dep, light.rgb.xyz) / tp.per_intensity;
                if (leg == 0u) {
                    if (k == 0u) {
                        gx = gx - (st.gu.xyz + st.gv.xyz) * sk;
                    } else if (k == 1u) {
                        gx = gx + st.gu.xyz * sk;
                    } else {
                        gx = gx + st.gv.xyz * sk;
                    }
                }
            } else if (bw[k] > 0.0) {
                for (var c = 0u; c < 3u; c = c + 1u) {
                    let q = round(w[c] * bw[k] / tp.unit);
                    if (q > 0.0) {
                        add64(3u * sv.row + c, u32(q));
                    }
                }
            }
        }
        if (gradient && leg == 0u) {
            let nd = dot(n, d);
            if (abs(nd) > 1e-6) {
                g.pos = g.pos + (gx - n * (dot(d, gx) / nd));
            }
        }
        if (leg == tp.bounces) {
            break;
        }
        let alb = sv0.albedo * bw.x + sv1.albedo * bw.y + sv2.albedo * bw.z;
        w = w * alb;
        if (all(w == vec3<f32>(0.0))) {
            break;
        }
        o = x + n * tp.offset;
        d = cosine_dir(n, rand(j, r, 2u + 2u * leg), rand(j, r, 3u + 2u * leg));
    }
    return g;
}

@compute @workgroup_size(64)
fn irradiance(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = gid.x;
    let j = gid.y;
    if (r >= tp.rays || j >= tp.lights) {
        return;
    }
    walk(j, r, false);
}

var<workgroup> shared_g: array<f32, 384>;

@compute @workgroup_size(64)
fn gradient(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32, @builtin(workgroup_id) wid: vec3<u32>) {
    let r = gid.x;
    let j = gid.y;
    var g = Grad(vec3<f32>(0.0), vec3<f32>(0.0));
    if (r < tp.rays && j < tp.lights) {
        g = walk(j, r, true);
    }
    shared_g[6u * li + 0u] = g.pos.x;
    shared_g[6u * li + 1u] = g.pos.y;
    shared_g[6u * li + 2u] = g.pos.z;
    shared_g[6u * li + 3u] = g.rgb.x;
    shared_g[6u * li + 4u] = g.rgb.y;
    shared_g[6u * li + 5u] = g.rgb.z;
    workgroupBarrier();
    for (var s = 32u; s > 0u; s = s >> 1u) {
        if (li < s) {
            for (var q = 0u; q < 6u; q = q + 1u) {
                shared_g[6u * li + q] = shared_g[6u * li + q] + shared_g[6u * (li + s) + q];
            }
        }
        workgroupBarrier();
    }
    if (li == 0u && wid.y < tp.lights) {
        let o = 6u * (wid.y * tp.groups_x + wid.x);
        for (var q = 0u; q < 6u; q = q + 1u) {
            partial[o + q] = shared_g[q];
        }
    }
}
