// First hits on the mesh of rays set up on the CPU (`trace::tree::PlaneRay`: the dirt's
// gathers, the bounce's transport): one invocation per ray walks bvh.wgsl's first-hit
// walk over the mesh's own tree, the parameter in (0, 1), a face met from behind taken
// beyond the ray's grace only. The CPU reference is `Tree::first_hit_of`. Out: per ray
// the parameter's bits and the tree's triangle (NO_HIT: none). Needs bvh.wgsl prepended.

struct PlaneRay {
    o: vec3<f32>,
    grace: f32,
    d: vec3<f32>,
    pad: f32,
}

struct FirstHitParams {
    n: u32,
    // Invocations per row of the dispatch's grid (rays past 65535 workgroups go on in y).
    stride: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> fp: FirstHitParams;
@group(0) @binding(1) var<storage, read> nodes: array<Node>;
@group(0) @binding(2) var<storage, read> tris: array<Tri>;
@group(0) @binding(3) var<storage, read> rays: array<PlaneRay>;
@group(0) @binding(4) var<storage, read_write> hits: array<vec2<u32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * fp.stride + gid.x;
    if (i >= fp.n) {
        return;
    }
    let r = rays[i];
    // The signs of the ray's components from its bits, as uploaded.
    let h = first_hit_after(r.o, r.d, signs(r.d), 0.0, 1.0, r.grace);
    hits[i] = vec2<u32>(bitcast<u32>(h.t), h.tri);
}
