// One problem vertex (relight/src/gpu.rs `GpuVertex`): world position and normal (m),
// vertex area A_i (m^2), projected albedo, target (`goal`), two-sided weight and lower bound.
struct Vertex {
    pos: vec3<f32>,
    area: f32,
    normal: vec3<f32>,
    pad: f32,
    albedo: vec4<f32>,
    goal: vec4<f32>,
    weight: vec4<f32>,
    lower: vec4<f32>,
}
