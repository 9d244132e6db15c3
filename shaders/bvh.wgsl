// Shadow rays through the BVH of relight/src/trace/tree.rs (same layout, same tests; the CPU
// reference is `Tree::occluded` and `visibility::visible_from`).
//
// Node: an interior node's left child is the next node, `right_or_first` its right child;
// a leaf (count > 0) holds triangles right_or_first .. right_or_first + count.

struct Node {
    min: vec3<f32>,
    right_or_first: u32,
    max: vec3<f32>,
    count: u32,
}

// The spare lanes serve q3map2's pieces (relight/src/trace/pieces.rs `Shadow`): the
// trace node of the piece's leaf, its barycentric slack and its coplanar threshold (m^2
// per metre of ray); zero in the mesh's own tree.
struct Tri {
    v0: vec3<f32>,
    leaf: u32,
    e1: vec3<f32>,
    slack: f32,
    e2: vec3<f32>,
    coplanar: f32,
}

const MAX_DEPTH: u32 = 48u;

fn slab(node: Node, o: vec3<f32>, inv: vec3<f32>, t_max: f32) -> bool {
    let t0 = (node.min - o) * inv;
    let t1 = (node.max - o) * inv;
    let tn = min(t0, t1);
    let tf = max(t0, t1);
    let near = max(max(max(tn.x, tn.y), tn.z), 0.0);
    let far = min(min(min(tf.x, tf.y), tf.z), t_max);
    return !(near > far);
}

// Barycentric slack of the shadow rays' hit test: a ray through the edge two triangles
// share hits one of them (the CPU's `trace::bvh::EDGE_SLACK`; first-hit walks pass 0).
const EDGE_SLACK: f32 = 1e-5;

// The node's box as the shadow walk's hit test sees its triangles: grown by twice the
// slack of its largest side, so a ray through an edge on the box's face is not culled
// (the CPU's `slab_shadow`).
fn slab_shadow(node: Node, o: vec3<f32>, inv: vec3<f32>, t_max: f32) -> bool {
    let ext = node.max - node.min;
    let pad = vec3<f32>(2.0 * EDGE_SLACK * max(max(max(ext.x, ext.y), ext.z), 0.0));
    var grown = node;
    grown.min = node.min - pad;
    grown.max = node.max + pad;
    return slab(grown, o, inv, t_max);
}

// Moeller-Trumbore, two-sided, barycentric coordinates within [-slack, 1 + slack];
// returns the ray parameter or -1.
fn intersect(tri: Tri, o: vec3<f32>, d: vec3<f32>, slack: f32) -> f32 {
    let e1 = tri.e1;
    let e2 = tri.e2;
    let p = cross(d, e2);
    let det = dot(e1, p);
    if (det == 0.0) {
        return -1.0;
    }
    let inv = 1.0 / det;
    let s = o - tri.v0;
    let u = dot(s, p) * inv;
    if (u < -slack || u > 1.0 + slack) {
        return -1.0;
    }
    let q = cross(s, e1);
    let v = dot(d, q) * inv;
    if (v < -slack || u + v > 1.0 + slack) {
        return -1.0;
    }
    return dot(e2, q) * inv;
}

// Hits with t in (t_min, t_max) count (t_min >= 0).
fn occluded(o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32) -> bool {
    if (arrayLength(&tris) == 0u) {
        return false;
    }
    let inv = 1.0 / d;
    var stack: array<u32, 48>;
    var sp = 1u;
    stack[0] = 0u;
    while (sp > 0u) {
        sp = sp - 1u;
        let here = stack[sp];
        let node = nodes[here];
        if (!slab_shadow(node, o, inv, t_max)) {
            continue;
        }
        if (node.count > 0u) {
            for (var k = 0u; k < node.count; k = k + 1u) {
                let t = intersect(tris[node.right_or_first + k], o, d, EDGE_SLACK);
                if (t > t_min && t < t_max) {
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
