// Visibility bits: one invocation per (row, light of the batch).
// Needs rows.wgsl, bvh.wgsl and shadow.wgsl prepended. Bit i of word light*words + i/32
// is set when the light is in front of vertex i and the shadow ray reaches it.

struct TraceParams {
    n: u32,
    lights: u32,
    words: u32,
    ray_offset: f32,
    inhibit: f32,
    // 1: the tree holds q3map2's pieces (relight/src/trace/pieces.rs), tested as q3map2
    // tests them; 0: the mesh's triangles.
    pieces: u32,
    // q3map2's TRACE_ON_EPSILON, m: a leaf's half-spaces grown by it.
    leaf_eps: f32,
    // Geometry this close to the light does not shadow it, m.
    end_margin: f32,
}

@group(0) @binding(0) var<uniform> tp: TraceParams;
@group(0) @binding(1) var<storage, read> verts: array<Row>;
@group(0) @binding(2) var<storage, read> nodes: array<Node>;
@group(0) @binding(3) var<storage, read> tris: array<Tri>;
@group(0) @binding(4) var<storage, read> light_pos: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> bits: array<atomic<u32>>;
@group(0) @binding(6) var<storage, read> bounds: array<Bound>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    let j = gid.y;
    if (i >= tp.n || j >= tp.lights) {
        return;
    }
    let v = verts[i];
    // light_pos[j].w: the reach; farther rows get no bit (relight/src/trace/visibility.rs).
    let d = v.pos - light_pos[j].xyz;
    if (dot(d, d) <= light_pos[j].w * light_pos[j].w && visible_from(v.pos, facing(v, light_pos[j].xyz - v.pos), light_pos[j].xyz, ShadowWalk(tp.ray_offset, tp.inhibit, tp.end_margin, tp.leaf_eps, tp.pieces))) {
        atomicOr(&bits[j * tp.words + (i >> 5u)], 1u << (i & 31u));
    }
}
