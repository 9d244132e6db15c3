// Shadow rays and first hits through the BVH of relight/src/trace/tree.rs (same layout,
// same tests; the CPU references are `Tree::occluded`, `visibility::visible_from` and
// `Tree::first_hit_after`).
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
// (the CPU's `wide::shadow_box`).
fn shadow_box(node: Node) -> Node {
    let ext = node.max - node.min;
    let pad = vec3<f32>(2.0 * EDGE_SLACK * max(max(max(ext.x, ext.y), ext.z), 0.0));
    var grown = node;
    grown.min = node.min - pad;
    grown.max = node.max + pad;
    return grown;
}

// The shadow walk's box test as the CPU's four-wide walk decides it for any ray
// (`Node4::crossed` on the node's `shadow_box`: per axis x, y, z, `near =
// near.max(t0.min(t1))` and `far = far.min(t0.max(t1))` from 0 and `t_max`, Rust's minimum
// and maximum, which drop a NaN): where a component of `d` is zero its products are
// infinite or NaN, which WGSL leaves to the implementation, so they are spelled out
// (`Ext`, below). `finite`: no component of `d` is zero; then the plain `slab`.
fn slab_shadow_any(node: Node, o: vec3<f32>, d: vec3<f32>, inv: vec3<f32>, neg: vec3<bool>, finite: bool, t_max: f32) -> bool {
    let b = shadow_box(node);
    if (finite) {
        return slab(b, o, inv, t_max);
    }
    let lo = b.min;
    let hi = b.max;
    var near = Ext(0.0, 0.0);
    var far = Ext(0.0, t_max);
    for (var a = 0u; a < 3u; a = a + 1u) {
        var t0: Ext;
        var t1: Ext;
        if (d[a] == 0.0) {
            t0 = ext_over_zero(lo[a] - o[a], neg[a]);
            t1 = ext_over_zero(hi[a] - o[a], neg[a]);
        } else {
            t0 = Ext(0.0, (lo[a] - o[a]) * inv[a]);
            t1 = Ext(0.0, (hi[a] - o[a]) * inv[a]);
        }
        near = ext_fmax(near, ext_fmin(t0, t1));
        far = ext_fmin(far, ext_fmax(t0, t1));
    }
    return !ext_lt(far, near);
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
    let neg = signs(d);
    let finite = all(d != vec3<f32>(0.0));
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

// The first-hit walk (the sun's rays, the light-tracing estimator's paths).
//
// A number of the CPU's slab test where a ray component is zero: `c` its class (0
// finite, 1 +inf, -1 -inf, 2 NaN), `v` its value where finite. WGSL leaves infinities
// and NaN to the implementation, so the CPU's arithmetic on them is spelled out here.
struct Ext {
    c: f32,
    v: f32,
}

// `a < b` as IEEE compares (NaN: false).
fn ext_lt(a: Ext, b: Ext) -> bool {
    if (a.c == 2.0 || b.c == 2.0) {
        return false;
    }
    if (a.c != b.c) {
        return a.c < b.c;
    }
    return a.c == 0.0 && a.v < b.v;
}

// `select` for `Ext`: `t` where `c`, else `f`.
fn ext_pick(f: Ext, t: Ext, c: bool) -> Ext {
    if (c) {
        return t;
    }
    return f;
}

// Rust's `f32::min` and `f32::max` for `Ext`: a NaN gives way to the other operand.
fn ext_fmin(a: Ext, b: Ext) -> Ext {
    if (a.c == 2.0) {
        return b;
    }
    if (b.c == 2.0) {
        return a;
    }
    return ext_pick(b, a, ext_lt(a, b));
}

fn ext_fmax(a: Ext, b: Ext) -> Ext {
    if (a.c == 2.0) {
        return b;
    }
    if (b.c == 2.0) {
        return a;
    }
    return ext_pick(b, a, ext_lt(b, a));
}

// `a * (1 / d)` for a finite `a` and a zero `d` of sign `neg`: NaN at `a = 0`.
fn ext_over_zero(a: f32, neg: bool) -> Ext {
    if (a == 0.0) {
        return Ext(2.0, 0.0);
    }
    return Ext(select(-1.0, 1.0, (a > 0.0) != neg), 0.0);
}

// The slab test of the first-hit walk, as the CPU's `slab` decides it (glam's `min`,
// `max`, `max_element` and `min_element`, whose comparisons pass a NaN on or drop it by
// its place, then Rust's `f32::max` and `f32::min`, which drop it): a zero component of
// the ray (a sun along an axis) makes that lane's products infinite or NaN. Such a box
// is kept where the origin lies strictly inside its slab, and where a NaN lane's place
// lets it through; the other lanes' arithmetic is the CPU's to the operation.
fn slab_first(node: Node, o: vec3<f32>, d: vec3<f32>, neg: vec3<bool>, t_max: f32) -> bool {
    if (d.x != 0.0 && d.y != 0.0 && d.z != 0.0) {
        let inv = 1.0 / d;
        let t0 = (node.min - o) * inv;
        let t1 = (node.max - o) * inv;
        let tn = min(t0, t1);
        let tf = max(t0, t1);
        let near = max(max(tn.x, max(tn.y, tn.z)), 0.0);
        let far = min(min(tf.x, min(tf.y, tf.z)), t_max);
        return !(near > far);
    }
    var tn: array<Ext, 3>;
    var tf: array<Ext, 3>;
    for (var a = 0u; a < 3u; a = a + 1u) {
        var t0: Ext;
        var t1: Ext;
        if (d[a] == 0.0) {
            t0 = ext_over_zero(node.min[a] - o[a], neg[a]);
            t1 = ext_over_zero(node.max[a] - o[a], neg[a]);
        } else {
            let inv = 1.0 / d[a];
            t0 = Ext(0.0, (node.min[a] - o[a]) * inv);
            t1 = Ext(0.0, (node.max[a] - o[a]) * inv);
        }
        // glam: `if t0 < t1 { t0 } else { t1 }`, `if t0 > t1 { t0 } else { t1 }`.
        tn[a] = ext_pick(t1, t0, ext_lt(t0, t1));
        tf[a] = ext_pick(t1, t0, ext_lt(t1, t0));
    }
    // max_element: m(x, m(y, z)), m(a, b) = if a > b { a } else { b }; then f32::max(_, 0).
    let yz = ext_pick(tn[2], tn[1], ext_lt(tn[2], tn[1]));
    var near = ext_pick(yz, tn[0], ext_lt(yz, tn[0]));
    if (near.c == 2.0 || ext_lt(near, Ext(0.0, 0.0))) {
        near = Ext(0.0, 0.0);
    }
    // min_element: m(x, m(y, z)), m(a, b) = if a < b { a } else { b }; then f32::min(_, t_max).
    let fyz = ext_pick(tf[2], tf[1], ext_lt(tf[1], tf[2]));
    var far = ext_pick(fyz, tf[0], ext_lt(tf[0], fyz));
    if (far.c == 2.0 || ext_lt(Ext(0.0, t_max), far)) {
        far = Ext(0.0, t_max);
    }
    return !ext_lt(far, near);
}

// A first hit: the ray parameter and the triangle's place in the tree (`NO_HIT`: none).
struct Hit {
    t: f32,
    tri: u32,
}

const NO_HIT: u32 = 0xffffffffu;

// The sign bits of a vector's components: the sign of a zero decides its infinity in the
// slab test. Taken from the bits, as the arithmetic may not keep a zero's sign.
fn signs(v: vec3<f32>) -> vec3<bool> {
    return (bitcast<vec3<u32>>(v) >> vec3<u32>(31u)) != vec3<u32>(0u);
}

// The nearest hit along o + s d with s in (t_min, t_max), exact hit tests, the binary
// tree's order (`Tree::first_hit_after` and the CPU's other first-hit walks, hit for hit
// with ties: the same order, the same tests); `neg`: `signs` of `d`, or of a direction
// `d` is a positive multiple of. A face met from behind (its winding normal along `d`)
// counts only beyond `grace` (`PlaneRay::accepts`; -1: every face counts).
fn first_hit_after(o: vec3<f32>, d: vec3<f32>, neg: vec3<bool>, t_min: f32, t_max: f32, grace: f32) -> Hit {
    var best = Hit(-1.0, NO_HIT);
    if (arrayLength(&tris) == 0u) {
        return best;
    }
    var limit = t_max;
    var stack: array<u32, 48>;
    var sp_ = 1u;
    stack[0] = 0u;
    while (sp_ > 0u) {
        sp_ = sp_ - 1u;
        let here = stack[sp_];
        let node = nodes[here];
        if (!slab_first(node, o, d, neg, limit)) {
            continue;
        }
        if (node.count > 0u) {
            for (var k = 0u; k < node.count; k = k + 1u) {
                let tri = tris[node.right_or_first + k];
                let t = intersect(tri, o, d, 0.0);
                if (t > t_min && t < limit && (t > grace || dot(cross(tri.e1, tri.e2), d) < 0.0)) {
                    limit = t;
                    best = Hit(t, node.right_or_first + k);
                }
            }
        } else if (sp_ + 2u <= MAX_DEPTH) {
            stack[sp_] = node.right_or_first;
            stack[sp_ + 1u] = here + 1u;
            sp_ = sp_ + 2u;
        }
    }
    return best;
}
