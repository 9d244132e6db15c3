// Point and spot lights: the geometry term, q3map2's spot cone and falloff cut.
// relight/src/model/lights.rs is the CPU reference and documents the math.
// Needs rows.wgsl prepended; the including kernel declares `lp: LightParams`,
// `lights: array<vec4<f32>>` (3 per light) and `vis: array<u32>`.

struct LightParams {
    n: u32,
    k: u32,
    words: u32,
    // Rows per block of the gradient's second reduction stage.
    block: u32,
    // q3map2's distance clamp, m.
    eps: f32,
    // Falloff tolerance, W/m^2 (0: none).
    falloff: f32,
    // A spot's soft edge, m.
    ramp: f32,
    pad: f32,
}

// A light as stored: lights[3j] = (position, 1 if a spot), lights[3j + 1] = (rgb,
// radius_by_dist), lights[3j + 2] = (axis, the slot of its visibility bits in `vis`, a
// whole number).
struct Term {
    g: f32,
    dp: vec3<f32>,
    da: vec3<f32>,
    dr: f32,
}

fn zero_term() -> Term {
    return Term(0.0, vec3<f32>(0.0), vec3<f32>(0.0), 0.0);
}

// The visibility bits of light `j` over the 64 rows of workgroup `wg` (its two words, 0
// past the last row): 0 where the light reaches none of them, whether its shadows or the
// reach it was traced to (beyond which its falloff cut takes every term) stop it.
fn group_bits(j: u32, wg: u32) -> u32 {
    let slot = u32(lights[3u * j + 2u].w);
    let w = 2u * wg;
    var bits = 0u;
    if (w < lp.words) {
        bits = vis[slot * lp.words + w];
    }
    if (w + 1u < lp.words) {
        bits = bits | vis[slot * lp.words + w + 1u];
    }
    return bits;
}

fn visible(j: u32, i: u32) -> bool {
    let slot = u32(lights[3u * j + 2u].w);
    return ((vis[slot * lp.words + (i >> 5u)] >> (i & 31u)) & 1u) == 1u;
}

fn light_term(x: vec3<f32>, n: vec3<f32>, j: u32) -> Term {
    let p = lights[3u * j].xyz;
    let d = p - x;
    let s = dot(n, d);
    let r2 = dot(d, d);
    if (!(s > 0.0) || !(r2 > 0.0)) {
        return zero_term();
    }
    let r = sqrt(r2);
    let e2 = lp.eps * lp.eps;
    var g0: f32;
    var dg0: vec3<f32>;
    if (r2 > e2) {
        let r3 = r2 * r;
        g0 = s / r3;
        dg0 = n / r3 - d * (3.0 * s / (r3 * r2));
    } else {
        g0 = s / (r * e2);
        dg0 = n / (r * e2) - d * (s / (r2 * r * e2));
    }
    var t = Term(g0, dg0, vec3<f32>(0.0), 0.0);
    if (lights[3u * j].w > 0.5) {
        let axis = lights[3u * j + 2u].xyz;
        let rbd = lights[3u * j + 1u].w;
        let u = x - p;
        let along = dot(u, axis);
        if (!(along > 0.0)) {
            return zero_term();
        }
        let w = u - axis * along;
        let rho = length(w);
        let big_r = rbd * along;
        if (!(rho < big_r)) {
            return zero_term();
        }
        if (rho > big_r - lp.ramp && lp.ramp > 0.0) {
            let c = (big_r - rho) / lp.ramp;
            var w_hat = vec3<f32>(0.0);
            if (rho > 0.0) {
                w_hat = w / rho;
            }
            let dcp = (w_hat - axis * rbd) / lp.ramp;
            let dca = (u * rbd + w_hat * along) / lp.ramp;
            t = Term(g0 * c, dg0 * c + dcp * g0, dca * g0, along / lp.ramp * g0);
        }
    }
    let rgb = lights[3u * j + 1u].xyz;
    if (lp.falloff > 0.0 && max(rgb.x, max(rgb.y, rgb.z)) * t.g <= lp.falloff) {
        return zero_term();
    }
    return t;
}
