// Sun visibility bits: one invocation per (row, direction of the batch; the direction in z). Needs bvh.wgsl
// and sun_rays.wgsl prepended. The CPU reference is `trace::visibility::sun_visible_from` (through
// `trace_sun`): the sun is in front of the row (its normal as it faces the sun), not
// exactly along a wall plane the row stands on with its brush ahead, and the ray from the
// row's shadow origin towards the sun, as long as the scene, first meets a sky triangle
// of the mesh (or nothing, in a scene without sky surfaces). Bit i of word
// dir * words + i / 32 is set when the row sees the sun.

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

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * sp.stride + gid.x;
    let j = gid.z;
    if (i >= sp.n || j >= sp.dirs) {
        return;
    }
    let w = dirs[j].xyz;
    let start = sun_start(rows[i], w, sp.shadow_offset, sp.on_epsilon);
    if (!start.ok) {
        return;
    }
    // The signs from the direction (the ray is the direction times a length).
    let hit = first_hit_after(start.o, w * sp.reach, signs(w), sp.t_min, 1.0, -1.0);
    var seen = sp.open != 0u;
    if (hit.tri != NO_HIT) {
        seen = sky[hit.tri] != 0u;
    }
    if (seen) {
        atomicOr(&bits[j * sp.words + (i >> 5u)], 1u << (i & 31u));
    }
}
