// One row of the objective (relight/src/gpu/mod.rs `GpuRow`): the sample point and its
// unit normal, m, relative to the scene's origin, and whether it receives light on both
// faces (1.0: a `cull none` surface). The lights' kernels need nothing else.
struct Row {
    pos: vec3<f32>,
    pad0: f32,
    normal: vec3<f32>,
    two_sided: f32,
}

// The normal the row receives light from direction `d` with: its own, or its negation on
// a two-sided row with `d` behind it (relight/src/rows/mod.rs `Rows::facing`).
fn facing(r: Row, d: vec3<f32>) -> vec3<f32> {
    if (r.two_sided > 0.5 && dot(r.normal, d) < 0.0) {
        return -r.normal;
    }
    return r.normal;
}
