// What the rays towards a sun (the sun's, the sky light's suns) share: the rows as they
// need them and the test of a ray exactly along a wall plane. The CPU reference is
// relight/src/trace/visibility.rs `sun_ray`.

// A row as the sun's rays need it: `Row` of rows.wgsl with `SolidAhead`'s bits in the
// spare lane (relight/src/rows/mod.rs).
struct SunRow {
    pos: vec3<f32>,
    ahead: u32,
    normal: vec3<f32>,
    two_sided: f32,
}

// `SolidAhead::along`: the direction runs along one of the planes of the row's solid
// (+x, +y, -z in glTF axes), within f32 rounding.
fn along(ahead: u32, w: vec3<f32>) -> bool {
    return ((ahead & 1u) != 0u && abs(w.x) < 1e-6) || ((ahead & 2u) != 0u && abs(w.y) < 1e-6) || ((ahead & 4u) != 0u && abs(-w.z) < 1e-6);
}

// Where the ray from row `r` towards the sun `w` (unit) starts: its normal turned as a
// two-sided row faces `w`, pushed out by `offset` (m); `ok` false where the sun is behind
// the row, or exactly along a wall plane the row stands on with its brush ahead (where
// `on_epsilon` is not zero).
struct SunStart {
    o: vec3<f32>,
    ok: bool,
}

fn sun_start(r: SunRow, w: vec3<f32>, offset: f32, on_epsilon: f32) -> SunStart {
    var n = r.normal;
    if (r.two_sided > 0.5 && dot(n, w) < 0.0) {
        n = -n;
    }
    if (!(dot(n, w) > 0.0) || (on_epsilon > 0.0 && along(r.ahead, w))) {
        return SunStart(vec3<f32>(0.0), false);
    }
    return SunStart(r.pos + n * offset, true);
}
