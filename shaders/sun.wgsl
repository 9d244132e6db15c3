// Sun visibility bits: one invocation per (row, direction of the batch; the direction in z). Needs bvh.wgsl
// prepended. The CPU reference is `trace::visibility::sun_visible_from` (through
// `trace_sun`): the sun is in front of the row (its normal as it faces the sun), not
// exactly along a wall plane the row stands on with its brush ahead, and the ray from the
// row's shadow origin towards the sun, as long as the scene, first meets a sky triangle
// of the mesh (or nothing, in a scene without sky surfaces). Bit i of word
// dir * words + i / 32 is set when the row sees the sun.

// A row as the sun's rays need it: `Row` of rows.wgsl with `SolidAhead`'s bits in the
// spare lane (relight/src/rows/mod.rs).
struct SunRow {
    pos: vec3<f32>,
    ahead: u32,
    normal: vec3<f32>,
    two_sided: f32,
}

struct SunParams {
    n: u32,
    dirs: u32,
    words: u32,
    // 1: the scene has no sky surface, and a ray that meets nothing sees the sun.
    open: u32,
    // Invocations per row of the dispatch's grid (rows past 65535 workgroups go on in y).
    stride: u32,
    shadow_offset: f32,
    // The first hit counts beyond this fraction of the ray (`Sampling::inhibit / reach`).
    t_min: f32,
    // The ray's length, m (`Tree::reach`).
    reach: f32,
    // `Sampling::on_epsilon`, m: where it is zero the wall planes are not consulted.
    on_epsilon: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> sp: SunParams;
@group(0) @binding(1) var<storage, read> rows: array<SunRow>;
@group(0) @binding(2) var<storage, read> nodes: array<Node>;
@group(0) @binding(3) var<storage, read> tris: array<Tri>;
// One flag per triangle of the tree, in the tree's order: 1 for a sky surface.
@group(0) @binding(4) var<storage, read> sky: array<u32>;
@group(0) @binding(5) var<storage, read> dirs: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> bits: array<atomic<u32>>;

// `SolidAhead::along`: the direction runs along one of the planes of the row's solid
// (+x, +y, -z in glTF axes), within f32 rounding.
fn along(ahead: u32, w: vec3<f32>) -> bool {
    return ((ahead & 1u) != 0u && abs(w.x) < 1e-6) || ((ahead & 2u) != 0u && abs(w.y) < 1e-6) || ((ahead & 4u) != 0u && abs(-w.z) < 1e-6);
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * sp.stride + gid.x;
    let j = gid.z;
    if (i >= sp.n || j >= sp.dirs) {
        return;
    }
    let r = rows[i];
    let w = dirs[j].xyz;
    var n = r.normal;
    if (r.two_sided > 0.5 && dot(n, w) < 0.0) {
        n = -n;
    }
    if (!(dot(n, w) > 0.0) || (sp.on_epsilon > 0.0 && along(r.ahead, w))) {
        return;
    }
    let o = r.pos + n * sp.shadow_offset;
    // The signs from the direction (the ray is the direction times a length).
    let hit = first_hit_after(o, w * sp.reach, signs(w), sp.t_min, 1.0, -1.0);
    var seen = sp.open != 0u;
    if (hit.tri != NO_HIT) {
        seen = sky[hit.tri] != 0u;
    }
    if (seen) {
        atomicOr(&bits[j * sp.words + (i >> 5u)], 1u << (i & 31u));
    }
}
