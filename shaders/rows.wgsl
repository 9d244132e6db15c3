// One row of the objective (relight/src/gpu/mod.rs `GpuRow`): the sample point and its
// unit normal, m, relative to the scene's origin. The lights' kernels need nothing else.
struct Row {
    pos: vec3<f32>,
    pad0: f32,
    normal: vec3<f32>,
    pad1: f32,
}
