// The surface lights' basis (relight/src/model/surface.rs `basis_from` is the reference):
// one invocation per row, the patches of one chunk in order. For each patch q3map2 would
// trace a ray for, the row counts the ray; where the ray passes it adds pi F weight to its
// group's sum, F the point-to-polygon form factor of the patch seen from the row. The sums
// of a row are its own (no atomics); chunks of patches add to them in patch order, as the
// CPU does. Needs rows.wgsl, bvh.wgsl and shadow.wgsl prepended.

struct SurfaceParams {
    // Rows of this dispatch: rows row0 .. row0 + n, written from sums[0].
    n: u32,
    row0: u32,
    // Patches first .. first + count.
    first: u32,
    count: u32,
    // Sums per row (the groups).
    groups: u32,
    // Invocations per row of the dispatch grid (gx * 64).
    stride: u32,
    // 1: q3map2's -fast (a patch adding at most the falloff tolerance is skipped).
    fast: u32,
    pieces: u32,
    // Meters per Quake unit.
    units: f32,
    // Samples nearer the patch's plane than this are pushed out to it for F, m.
    push: f32,
    // The shadow ray's target behind a two-sided patch: its origin minus this along the
    // normal, m.
    behind: f32,
    // Below this many bytes a patch's upper bound skips the ray.
    skip_bytes: f32,
    // q3map2's falloff tolerance in bytes (with -fast).
    tolerance_bytes: f32,
    shadow_offset: f32,
    inhibit: f32,
    end_margin: f32,
    leaf_eps: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
}

// relight/src/gpu/surface.rs `GpuPatch`.
struct Patch {
    origin: vec3<f32>,
    // n . origin
    dist: f32,
    normal: vec3<f32>,
    // Multiplier of the group's value (1, or 7 x the backsplash fraction).
    weight: f32,
    // m^2.
    area: f32,
    // Bytes per unit of form factor (the brightest channel's, times weight).
    bytes_per_ff: f32,
    group: u32,
    two_sided: u32,
    first_vert: u32,
    verts: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> sp: SurfaceParams;
@group(0) @binding(1) var<storage, read> rows: array<Row>;
@group(0) @binding(2) var<storage, read> nodes: array<Node>;
@group(0) @binding(3) var<storage, read> tris: array<Tri>;
@group(0) @binding(4) var<storage, read> bounds: array<Bound>;
@group(0) @binding(5) var<storage, read> patches: array<Patch>;
@group(0) @binding(6) var<storage, read> corners: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> sums: array<f32>;
@group(0) @binding(8) var<storage, read_write> rays: array<u32>;

const PI: f32 = 3.14159265358979;
const TAU: f32 = 6.28318530717959;

fn unit_or_zero(v: vec3<f32>) -> vec3<f32> {
    let l = length(v);
    if (l > 0.0 && l < 3.0e38) {
        return v * (1.0 / l);
    }
    return vec3<f32>(0.0);
}

// q3map2's point-to-polygon form factor (relight/src/model/area.rs `form_factor`): the
// signed fraction of the cosine-weighted hemisphere of `n` at `x` the polygon covers.
fn form_factor(x: vec3<f32>, n: vec3<f32>, p: Patch) -> f32 {
    var total = 0.0;
    var a = unit_or_zero(corners[p.first_vert].xyz - x);
    let first = a;
    for (var i = 0u; i < p.verts; i = i + 1u) {
        var b = first;
        if (i + 1u < p.verts) {
            b = unit_or_zero(corners[p.first_vert + i + 1u].xyz - x);
        }
        let t = cross(a, b);
        let len = length(t);
        if (len >= 1e-4) {
            total = total + dot(n, t / len) * acos(clamp(dot(a, b), -1.0, 1.0));
        }
        a = b;
    }
    return total / TAU;
}

// What row `r` gets from patch `p`: x, 1 where q3map2 traces a ray (0: culled before it);
// y, pi F weight where the ray passes and F > 0, else 0.
fn from_patch(r: Row, p: Patch, walk: ShadowWalk) -> vec2<f32> {
    let x = r.pos;
    let n = r.normal;
    let two_sided_row = r.two_sided > 0.5;
    // The light origin behind the sample's plane: nothing (a two-sided row looks both
    // ways).
    if (!two_sided_row && dot(p.origin - x, n) < 0.0) {
        return vec2<f32>(0.0);
    }
    // q3map2's tests in whole Quake units, with slack for the rounding of meters.
    let d = dot(p.normal, x) - p.dist;
    let du = d / sp.units;
    if (du < 3.0 - 1e-3 && ((p.two_sided == 0u && du < -1.0 - 1e-3) || (du > -3.0 + 1e-3 && dot(n, p.normal) > 0.9))) {
        return vec2<f32>(0.0);
    }
    // Upper bound of the form factor from the distance to the origin.
    let to = p.origin - x;
    let r2 = dot(to, to);
    if (p.area / (PI * r2) * p.bytes_per_ff < sp.skip_bytes && r2 > 4.0 * p.area) {
        return vec2<f32>(0.0);
    }
    var pushed = x;
    if (d > -sp.push && d < sp.push) {
        pushed = x + p.normal * (sp.push - d);
    }
    // One-sided both ways, without -fast: the ray first, the form factor only where it
    // passes (as the CPU does; the same entries).
    if (!(p.two_sided != 0u || two_sided_row || sp.fast != 0u)) {
        if (!visible_from(x, n, p.origin, walk)) {
            return vec2<f32>(1.0, 0.0);
        }
        return vec2<f32>(1.0, PI * max(form_factor(pushed, n, p), 0.0) * p.weight);
    }
    var ff = form_factor(pushed, n, p);
    // Seen from behind a two-sided patch, or by a two-sided row from behind its own plane:
    // the opposite form factor, and the ray to a point behind the patch.
    var aim = p.origin;
    if (ff < 0.0) {
        ff = -ff;
        aim = p.origin - p.normal * sp.behind;
    }
    if (!(ff > 0.0)) {
        return vec2<f32>(0.0);
    }
    if (sp.fast != 0u && ff * p.bytes_per_ff <= sp.tolerance_bytes) {
        return vec2<f32>(0.0);
    }
    if (!visible_from(x, facing(r, aim - x), aim, walk)) {
        return vec2<f32>(1.0, 0.0);
    }
    return vec2<f32>(1.0, PI * ff * p.weight);
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let local = gid.x + gid.y * sp.stride;
    if (local >= sp.n) {
        return;
    }
    let r = rows[sp.row0 + local];
    let walk = ShadowWalk(sp.shadow_offset, sp.inhibit, sp.end_margin, sp.leaf_eps, sp.pieces);
    var traced = 0u;
    for (var k = sp.first; k < sp.first + sp.count; k = k + 1u) {
        let p = patches[k];
        let got = from_patch(r, p, walk);
        traced = traced + u32(got.x);
        if (got.y > 0.0) {
            let at = local * sp.groups + p.group;
            sums[at] = sums[at] + got.y;
        }
    }
    rays[local] = rays[local] + traced;
}
