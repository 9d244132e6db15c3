// The per-triangle corner sums of the mass-lumped L2 projection (relight/src/target.rs,
// `triangle_sums`, is the CPU reference; the two are written operation for operation alike).
// One invocation per triangle: m^2 quadrature points at the centroids of the m x m equal
// sub-triangles, each with weight area / m^2; per point the albedo (base colour texture,
// sRGB decoded, times the factor) and the lightmap (decoded like CONVENTIONS.md says) are
// looked up bilinearly, and the nearest lightmap texel decides whether the sample is
// censored. Output: 13 floats per corner, 39 per triangle (see target.rs's module docs).

struct TriIn {
    uv0: array<vec2<f32>, 3>,
    uv1: array<vec2<f32>, 3>,
    area: f32,
    order: u32,
    material: u32,
    pad: u32,
}

// Texture `t` occupies words [offset, offset + width * height) of `texels`, one RGBA8
// texel per word (red in the low byte). `wrap`: s in bits 0..8, t in bits 8..16
// (0 repeat, 1 clamp, 2 mirror).
struct TexInfo {
    offset: u32,
    width: u32,
    height: u32,
    wrap: u32,
}

struct MaterialIn {
    albedo_factor: vec4<f32>,
    // Texture indices, or -1.
    albedo_tex: i32,
    lightmap_tex: i32,
    // 2^overbright_bits and the lightmap gamma.
    scale: f32,
    gamma: f32,
}

struct TargetParams {
    triangles: u32,
    // Invocations per row of the 2D dispatch.
    row: u32,
    pad0: u32,
    pad1: u32,
}

const CORNER: u32 = 13u;
const CENSOR: u32 = 254u; // relight/src/target.rs CENSOR_BYTE
// Texel coordinates are clamped to +-2^24 before rounding (CPU: texel::COORD_LIMIT).
const COORD_LIMIT: f32 = 16777216.0;

@group(0) @binding(0) var<uniform> params: TargetParams;
@group(0) @binding(1) var<storage, read> tris: array<TriIn>;
@group(0) @binding(2) var<storage, read> materials: array<MaterialIn>;
@group(0) @binding(3) var<storage, read> textures: array<TexInfo>;
@group(0) @binding(4) var<storage, read> texels: array<u32>;
@group(0) @binding(5) var<storage, read_write> sums: array<f32>;

fn srgb_to_linear(c: f32) -> f32 {
    if (c <= 0.04045) {
        return c / 12.92;
    }
    return pow((c + 0.055) / 1.055, 2.4);
}

fn wrap_index(i: i32, n: u32, mode: u32) -> u32 {
    let m = i32(max(n, 1u));
    if (mode == 1u) {
        return u32(clamp(i, 0, m - 1));
    }
    if (mode == 2u) {
        let p = ((i % (2 * m)) + 2 * m) % (2 * m);
        if (p < m) {
            return u32(p);
        }
        return u32(2 * m - 1 - p);
    }
    return u32(((i % m) + m) % m);
}

fn texel(t: TexInfo, x: i32, y: i32) -> vec4<u32> {
    let xi = wrap_index(x, t.width, t.wrap & 255u);
    let yi = wrap_index(y, t.height, (t.wrap >> 8u) & 255u);
    let w = texels[t.offset + yi * t.width + xi];
    return vec4<u32>(w & 255u, (w >> 8u) & 255u, (w >> 16u) & 255u, w >> 24u);
}

fn coord(u: f32, size: u32) -> f32 {
    return clamp(u * f32(size), -COORD_LIMIT, COORD_LIMIT);
}

fn nearest(t: TexInfo, uv: vec2<f32>) -> vec4<u32> {
    return texel(t, i32(floor(coord(uv.x, t.width))), i32(floor(coord(uv.y, t.height))));
}

// kind 0: sRGB decode; kind 1: lightmap decode with `scale` and `gamma`, from the
// middle of the byte's interval (q3map2 truncates; relight/src/scene.rs Material::decode).
fn decode(v: f32, kind: u32, scale: f32, gamma: f32) -> f32 {
    if (kind == 0u) {
        return srgb_to_linear(v);
    }
    let c = min(clamp(v, 0.0, 1.0) + 0.5 / 255.0, 1.0);
    var g = c;
    if (gamma != 1.0) {
        g = pow(c, gamma);
    }
    return g * scale;
}

fn bilinear(t: TexInfo, uv: vec2<f32>, kind: u32, scale: f32, gamma: f32) -> vec3<f32> {
    let fx = coord(uv.x, t.width) - 0.5;
    let fy = coord(uv.y, t.height) - 0.5;
    let x0 = floor(fx);
    let y0 = floor(fy);
    let tx = fx - x0;
    let ty = fy - y0;
    let xi = i32(x0);
    let yi = i32(y0);
    var out = vec3<f32>(0.0);
    let offs = array<vec2<i32>, 4>(vec2<i32>(0, 0), vec2<i32>(1, 0), vec2<i32>(0, 1), vec2<i32>(1, 1));
    let ws = array<f32, 4>((1.0 - tx) * (1.0 - ty), tx * (1.0 - ty), (1.0 - tx) * ty, tx * ty);
    for (var k = 0u; k < 4u; k++) {
        let s = texel(t, xi + offs[k].x, yi + offs[k].y);
        for (var c = 0u; c < 3u; c++) {
            out[c] += ws[k] * decode(f32(s[c]) / 255.0, kind, scale, gamma);
        }
    }
    return out;
}

// Barycentric coordinates of sample s of order m (target.rs `lattice_point`).
fn lattice_point(m: u32, s_in: u32) -> vec3<f32> {
    let mf = f32(m);
    let upright = m * (m + 1u) / 2u;
    var s = s_in;
    var off = 1.0 / 3.0;
    var rows = m;
    if (s >= upright) {
        s = s - upright;
        off = 2.0 / 3.0;
        rows = m - 1u;
    }
    var i = 0u;
    loop {
        if (i >= rows || s < rows - i) {
            break;
        }
        s = s - (rows - i);
        i = i + 1u;
    }
    let u = (f32(i) + off) / mf;
    let v = (f32(s) + off) / mf;
    return vec3<f32>(1.0 - u - v, u, v);
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = gid.x + gid.y * params.row;
    if (t >= params.triangles) {
        return;
    }
    let tri = tris[t];
    var acc: array<f32, 39>;
    for (var k = 0u; k < 39u; k++) {
        acc[k] = 0.0;
    }
    if (tri.area > 0.0 && tri.order > 0u) {
        let mat = materials[tri.material];
        let m = tri.order;
        let n = m * m;
        let wq = tri.area / f32(n);
        for (var s = 0u; s < n; s++) {
            let w = lattice_point(m, s);
            let uv0 = tri.uv0[0] * w[0] + tri.uv0[1] * w[1] + tri.uv0[2] * w[2];
            let uv1 = tri.uv1[0] * w[0] + tri.uv1[1] * w[1] + tri.uv1[2] * w[2];
            var albedo = vec3<f32>(1.0);
            if (mat.albedo_tex >= 0) {
                albedo = bilinear(textures[mat.albedo_tex], uv0, 0u, 1.0, 1.0);
            }
            albedo = albedo * mat.albedo_factor.xyz;
            var e = vec3<f32>(0.0);
            var censored = false;
            if (mat.lightmap_tex >= 0) {
                let lt = textures[mat.lightmap_tex];
                e = bilinear(lt, uv1, 1u, mat.scale, mat.gamma);
                let near = nearest(lt, uv1);
                censored = near.x >= CENSOR || near.y >= CENSOR || near.z >= CENSOR;
            }
            for (var k = 0u; k < 3u; k++) {
                let o = k * CORNER;
                let phi = wq * w[k];
                for (var c = 0u; c < 3u; c++) {
                    let r = albedo[c] * e[c];
                    if (censored) {
                        acc[o + 6u + c] += phi * r;
                    } else {
                        acc[o + c] += phi * r;
                        acc[o + 3u + c] += phi;
                    }
                    acc[o + 9u + c] += phi * albedo[c];
                }
                acc[o + 12u] += phi;
            }
        }
    }
    for (var k = 0u; k < 39u; k++) {
        sums[t * 39u + k] = acc[k];
    }
}
