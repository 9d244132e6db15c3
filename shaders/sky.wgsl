// The sky light's visibility: one invocation per (row, sky sun of the batch; the sun in
// z). Needs bvh.wgsl, shadow.wgsl and sun_rays.wgsl prepended. The CPU reference is
// relight/src/trace/visibility.rs `sky_visible_from` (through `model::sky::basis`): the
// sun is in front of the row and not along a wall plane it stands on (`sun_start`), and
// the ray from the row's shadow origin towards it, as long as the scene, crosses a sky
// triangle of the mesh and no opaque surface anywhere on its way (q3map2 traces the whole
// way, not to the first hit). Two passes over the same bindings:
//
// - pass 0, the crossing: `nodes` and `tris` hold the mesh's tree and `sky` its flags; a
//   row's bit is set where its ray hits a sky triangle (exact hit tests, no slack);
// - pass 1, the blocking: `nodes` and `tris` hold the shadow rays' tree (q3map2's pieces,
//   or the mesh's tree with its flags); a row's bit is set where pass 0 set it (every row,
//   in a scene without sky surfaces) and nothing opaque stops its ray (the shadow walk's
//   edge slack on the mesh's triangles, q3map2's tests on its pieces).
//
// Bit i of word dir * words + i / 32 is the row's.

struct SkyParams {
    n: u32,
    dirs: u32,
    words: u32,
    // 1: the scene has no sky surface (pass 1 takes every row as crossing).
    open: u32,
    // Invocations per row of the dispatch's grid (rows past 65535 workgroups go on in y).
    stride: u32,
    // 0: the crossing, 1: the blocking.
    pass_: u32,
    // 1: pass 1's tree holds q3map2's pieces.
    pieces: u32,
    shadow_offset: f32,
    // Hits count beyond this fraction of the ray (`Sampling::inhibit / reach`).
    t_min: f32,
    // The ray's length, m (`Tree::reach`).
    reach: f32,
    // `Sampling::on_epsilon`, m: where it is zero the wall planes are not consulted.
    on_epsilon: f32,
    // q3map2's TRACE_ON_EPSILON, m (the pieces' leaves).
    leaf_eps: f32,
}

@group(0) @binding(0) var<uniform> sp: SkyParams;
@group(0) @binding(1) var<storage, read> rows: array<SunRow>;
@group(0) @binding(2) var<storage, read> nodes: array<Node>;
@group(0) @binding(3) var<storage, read> tris: array<Tri>;
@group(0) @binding(4) var<storage, read> bounds: array<Bound>;
// One flag per triangle of the mesh's tree, in the tree's order: 1 for a sky surface.
@group(0) @binding(5) var<storage, read> sky: array<u32>;
@group(0) @binding(6) var<storage, read> dirs: array<vec4<f32>>;
// Pass 0's bits (pass 1 reads them).
@group(0) @binding(7) var<storage, read> crossed: array<u32>;
@group(0) @binding(8) var<storage, read_write> bits: array<atomic<u32>>;

// Whether the segment o + s d, s in (t_min, t_max), hits a triangle of the tree whose sky
// flag is `want`, the barycentric range widened by `slack` (`Tree::hits_where`).
fn hits_where(o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32, slack: f32, want: u32) -> bool {
    if (arrayLength(&tris) == 0u) {
        return false;
    }
    let inv = 1.0 / d;
    let neg = signs(d);
    let finite = all(d != vec3<f32>(0.0));
    var stack: array<u32, 48>;
    var sp_ = 1u;
    stack[0] = 0u;
    while (sp_ > 0u) {
        sp_ = sp_ - 1u;
        let here = stack[sp_];
        let node = nodes[here];
        if (!slab_shadow_any(node, o, d, inv, neg, finite, t_max)) {
            continue;
        }
        if (node.count > 0u) {
            for (var k = 0u; k < node.count; k = k + 1u) {
                let at = node.right_or_first + k;
                if (select(0u, 1u, sky[at] != 0u) != want) {
                    continue;
                }
                let t = intersect(tris[at], o, d, slack);
                if (t > t_min && t < t_max) {
                    return true;
                }
            }
        } else if (sp_ + 2u <= MAX_DEPTH) {
            stack[sp_] = node.right_or_first;
            stack[sp_ + 1u] = here + 1u;
            sp_ = sp_ + 2u;
        }
    }
    return false;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * sp.stride + gid.x;
    let j = gid.z;
    if (i >= sp.n || j >= sp.dirs) {
        return;
    }
    let word = j * sp.words + (i >> 5u);
    let bit = 1u << (i & 31u);
    if (sp.pass_ == 1u && sp.open == 0u && (crossed[word] & bit) == 0u) {
        return;
    }
    let w = dirs[j].xyz;
    let start = sun_start(rows[i], w, sp.shadow_offset, sp.on_epsilon);
    if (!start.ok) {
        return;
    }
    let d = w * sp.reach;
    var seen: bool;
    if (sp.pass_ == 0u) {
        seen = hits_where(start.o, d, sp.t_min, 1.0, 0.0, 1u);
    } else if (sp.pieces != 0u) {
        seen = !occluded_pieces(start.o, d, sp.t_min, 1.0, sp.leaf_eps);
    } else {
        seen = !hits_where(start.o, d, sp.t_min, 1.0, EDGE_SLACK, 0u);
    }
    if (seen) {
        atomicOr(&bits[word], bit);
    }
}
