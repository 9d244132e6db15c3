// One problem row, a vertex or a luxel (relight/src/gpu.rs `GpuVertex`): world position and
// normal (m), area A_i (m^2), albedo, target (`goal`), two-sided weight, lower bound, and
// the indirect radiance gathered from the data (scaled by `Params.indirect`).
struct Vertex {
    pos: vec3<f32>,
    area: f32,
    normal: vec3<f32>,
    pad: f32,
    albedo: vec4<f32>,
    goal: vec4<f32>,
    weight: vec4<f32>,
    lower: vec4<f32>,
    indirect: vec4<f32>,
}
