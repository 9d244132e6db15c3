// Shadow rays from a row to a point, through the mesh's tree or q3map2's pieces. Needs
// bvh.wgsl prepended, and the including shader's bindings `nodes`, `tris` and `bounds`
// (a trace node's half-space and parent, `Bound` below). The CPU references are
// relight/src/trace/pieces.rs `Shadow` and relight/src/trace/visibility.rs.

// The half-space of a trace node's parent plane on the node's side (inside: n . x - d >=
// -leaf_eps) and the parent (NO_PARENT at the root).
struct Bound {
    plane: vec4<f32>,
    parent: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

const NO_PARENT: u32 = 0xffffffffu;

// Whether the segment o + s d, s in (t_min, t_max), passes through the leaf of trace node
// `leaf` (relight/src/trace/pieces.rs `Shadow::passes_leaf` is the reference).
fn passes_leaf(leaf0: u32, o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32, leaf_eps: f32) -> bool {
    var leaf = leaf0;
    var lo = t_min;
    var hi = t_max;
    var guard = 0u;
    loop {
        if (leaf >= arrayLength(&bounds) || guard >= 4096u) {
            break;
        }
        let b = bounds[leaf];
        if (b.parent == NO_PARENT) {
            break;
        }
        let a = dot(b.plane.xyz, o) - b.plane.w + leaf_eps;
        let s = dot(b.plane.xyz, d);
        if (s > 0.0) {
            lo = max(lo, -a / s);
        } else if (s < 0.0) {
            hi = min(hi, -a / s);
        } else if (a < 0.0) {
            return false;
        }
        if (!(lo <= hi)) {
            return false;
        }
        leaf = b.parent;
        guard = guard + 1u;
    }
    return true;
}

// q3map2's test of one piece (`Shadow::hit`): slack and coplanar threshold from the
// triangle, a hit in the slack band only through the piece's leaf.
fn hits_piece(tri: Tri, o: vec3<f32>, d: vec3<f32>, len: f32, t_min: f32, t_max: f32, leaf_eps: f32) -> bool {
    let p = cross(d, tri.e2);
    let det = dot(tri.e1, p);
    if (!(abs(det) >= tri.coplanar * len) || det == 0.0) {
        return false;
    }
    let inv = 1.0 / det;
    let s = o - tri.v0;
    let u = dot(s, p) * inv;
    if (u < -tri.slack || u > 1.0 + tri.slack) {
        return false;
    }
    let q = cross(s, tri.e1);
    let v = dot(d, q) * inv;
    if (v < -tri.slack || u + v > 1.0 + tri.slack) {
        return false;
    }
    let t = dot(tri.e2, q) * inv;
    if (!(t > t_min && t < t_max)) {
        return false;
    }
    if (u < 0.0 || v < 0.0 || u + v > 1.0) {
        return passes_leaf(tri.leaf, o, d, t_min, t_max, leaf_eps);
    }
    return true;
}

// The shadow walk over q3map2's pieces (`Shadow::occluded`).
fn occluded_pieces(o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32, leaf_eps: f32) -> bool {
    if (arrayLength(&tris) == 0u) {
        return false;
    }
    let inv = 1.0 / d;
    let neg = signs(d);
    let finite = all(d != vec3<f32>(0.0));
    let len = length(d);
    var stack: array<u32, 48>;
    var sp = 1u;
    stack[0] = 0u;
    while (sp > 0u) {
        sp = sp - 1u;
        let here = stack[sp];
        let node = nodes[here];
        if (!slab_shadow_any(node, o, d, inv, neg, finite, t_max)) {
            continue;
        }
        if (node.count > 0u) {
            for (var k = 0u; k < node.count; k = k + 1u) {
                if (hits_piece(tris[node.right_or_first + k], o, d, len, t_min, t_max, leaf_eps)) {
                    return true;
                }
            }
        } else if (sp + 2u <= MAX_DEPTH) {
            stack[sp] = node.right_or_first;
            stack[sp + 1u] = here + 1u;
            sp = sp + 2u;
        }
    }
    return false;
}

// How a shadow ray is walked: the sampling's offsets (m) and which tree the bindings hold.
struct ShadowWalk {
    // The ray starts this far along the normal (`Sampling::shadow_offset`).
    offset: f32,
    // Geometry closer than this to the start does not shadow (`Sampling::inhibit`).
    inhibit: f32,
    // Geometry this close to the light does not shadow it (`Sampling::ray_offset`).
    end_margin: f32,
    // q3map2's TRACE_ON_EPSILON, m: a leaf's half-spaces grown by it.
    leaf_eps: f32,
    // 1: the tree holds q3map2's pieces (relight/src/trace/pieces.rs), tested as q3map2
    // tests them; 0: the mesh's triangles.
    pieces: u32,
}

// Whether the light at `light` reaches the sample at `x` (normal `n`, turned as the row
// faces); relight/src/trace/visibility.rs `visible_from` is the reference.
fn visible_from(x: vec3<f32>, n: vec3<f32>, light: vec3<f32>, w: ShadowWalk) -> bool {
    if (dot(n, light - x) <= 0.0) {
        return false;
    }
    let o = x + n * w.offset;
    let d = light - o;
    let len = length(d);
    if (!(len > max(w.offset, w.inhibit))) {
        return true;
    }
    if (w.pieces != 0u) {
        return !occluded_pieces(o, d, w.inhibit / len, 1.0 - w.end_margin / len, w.leaf_eps);
    }
    return !occluded(o, d, w.inhibit / len, 1.0 - w.end_margin / len);
}
