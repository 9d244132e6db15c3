//! q3map2's area lights, the geometry its surface lights ([`super::surface`]) and its
//! bounce lights ([`super::bounce::pieces`]) share: the cut of a winding into pieces
//! (`RadSubdivideDiffuseLight`, `RadClipWindingEpsilon`) and the exact point-to-polygon
//! form factor (`PointToPolygonFormFactor`).
//!
//! A winding is halved at the middle of its bounds along the first of Quake's x, y, z on
//! which it spans more than the limit (a surface light's `q3map_lightSubdivide`, 256
//! units for a bounce light), and each half again, until no extent passes it; a corner
//! within [`CLIP_EPSILON_UNITS`] of a cut goes to both halves. Corners carry their
//! barycentric coordinates in the triangle they were cut from, interpolated along the
//! cuts as q3map2 interpolates a corner's colour and lightmap coordinates.

use glam::Vec3;

/// A corner this close to a cut's plane goes to both halves (`RADIOSITY_CLIP_EPSILON`).
pub const CLIP_EPSILON_UNITS: f32 = 0.125;
/// glTF's axes in the order q3map2 tries Quake's x, y, z (`(x, y, z)q3 -> (x, z, -y)gltf`;
/// the middle of a span is the same whichever way an axis points).
pub const AXES: [usize; 3] = [0, 2, 1];
/// Cuts deeper than this stop, so a winding makes at most 2^16 pieces: a 256-unit
/// bounce light's cut reaches it on a flat triangle 65536 units across (Quake's whole
/// world), a surface light's with a 16-unit `q3map_lightSubdivide` at 4096 units. A
/// winding of absurd size (a hostile file) ends in fewer, bigger pieces instead of
/// taking all memory.
pub const MAX_DEPTH: usize = 16;

/// A corner of a piece: where it is and its barycentric coordinates in its triangle.
#[derive(Debug, Clone, Copy)]
pub struct Corner {
    pub p: Vec3,
    pub bary: [f32; 3],
}

/// The bounds of a winding.
pub fn bounds(w: &[Corner]) -> (Vec3, Vec3) {
    w.iter().fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), c| (lo.min(c.p), hi.max(c.p)))
}

/// Where q3map2 cuts `w` next (`RadSubdivideDiffuseLight`): the middle of its bounds on the
/// first of Quake's x, y, z along which it spans more than `limit` (m), if any. q3map2
/// compares in Quake units; in meters an extent equal to the limit can round above it,
/// hence the slack.
pub fn split(w: &[Corner], limit: f32) -> Option<(usize, f32)> {
    let (lo, hi) = bounds(w);
    AXES.into_iter().find(|&a| hi[a] - lo[a] > limit * (1.0 + 1e-4)).map(|a| (a, 0.5 * (hi[a] + lo[a])))
}

/// q3map2's cut of an area light's winding (its surface lights', with the shader's
/// `q3map_lightSubdivide`, as its bounce lights'): `w` halved as [`split`] says, each half
/// cut again ([`clip`], corners within `epsilon` of a cut going to both halves), the
/// pieces appended to `out` in q3map2's order (front before back); `limit` and `epsilon`
/// in m. Each cut takes one from `cuts_left`; with none left (or at [`MAX_DEPTH`]) a
/// winding stays whole, so a file's absurd windings or limits cannot make pieces without
/// bound.
pub fn cut(w: &[Vec3], limit: f32, epsilon: f32, cuts_left: &mut usize, out: &mut Vec<Vec<Vec3>>) {
    fn go(w: &[Corner], limit: f32, epsilon: f32, depth: usize, cuts_left: &mut usize, out: &mut Vec<Vec<Vec3>>) {
        if w.len() < 3 {
            return;
        }
        match split(w, limit).filter(|_| depth < MAX_DEPTH && *cuts_left > 0) {
            Some((axis, dist)) => {
                *cuts_left -= 1;
                let (front, back) = clip(w, axis, dist, epsilon);
                go(&front, limit, epsilon, depth + 1, cuts_left, out);
                go(&back, limit, epsilon, depth + 1, cuts_left, out);
            }
            None => out.push(w.iter().map(|c| c.p).collect()),
        }
    }
    let corners: Vec<Corner> = w.iter().map(|&p| Corner { p, bary: [0.0; 3] }).collect();
    go(&corners, limit, epsilon, 0, cuts_left, out);
}

/// `RadClipWindingEpsilon`: `w` cut by the plane `p[axis] = dist` into its front
/// (`p[axis] > dist`) and back; corners within `epsilon` go to both, and a winding wholly
/// on one side (on-plane corners aside) goes to that side alone.
pub fn clip(w: &[Corner], axis: usize, dist: f32, epsilon: f32) -> (Vec<Corner>, Vec<Corner>) {
    let d: Vec<f32> = w.iter().map(|c| c.p[axis] - dist).collect();
    let side = |x: f32| if x > epsilon { 0 } else if x < -epsilon { 1 } else { 2 };
    let (fronts, backs) = d.iter().fold((0, 0), |(f, b), &x| match side(x) {
        0 => (f + 1, b),
        1 => (f, b + 1),
        _ => (f, b),
    });
    if fronts == 0 {
        return (Vec::new(), w.to_vec());
    }
    if backs == 0 {
        return (w.to_vec(), Vec::new());
    }
    let (mut front, mut back) = (Vec::with_capacity(w.len() + 2), Vec::with_capacity(w.len() + 2));
    for i in 0..w.len() {
        let (a, sa) = (w[i], side(d[i]));
        let next = (i + 1) % w.len();
        let sb = side(d[next]);
        match sa {
            2 => {
                front.push(a);
                back.push(a);
                continue;
            }
            0 => front.push(a),
            _ => back.push(a),
        }
        if sb == 2 || sb == sa {
            continue;
        }
        let b = w[next];
        let den = d[i] - d[next];
        let f = if den != 0.0 { d[i] / den } else { 0.5 };
        let mid = Corner { p: a.p + (b.p - a.p) * f, bary: [0, 1, 2].map(|k| a.bary[k] + (b.bary[k] - a.bary[k]) * f) };
        front.push(mid);
        back.push(mid);
    }
    (front, back)
}

/// A planar polygon's area (its fan's triangles).
pub fn polygon_area(w: &[Vec3]) -> f32 {
    (2..w.len()).map(|i| 0.5 * (w[i - 1] - w[0]).cross(w[i] - w[0]).length()).sum()
}

/// q3map2's point-to-polygon form factor (`PointToPolygonFormFactor`): the signed
/// fraction of the cosine-weighted hemisphere of `normal` at `point` that the polygon
/// covers, positive when its winding faces the point.
pub fn form_factor(point: Vec3, normal: Vec3, verts: &[Vec3]) -> f32 {
    let n = verts.len();
    // The directions to the corners, on the stack for the windings q3map2's cuts make
    // (called for every row and patch: no allocation there).
    let mut on_stack = [Vec3::ZERO; 16];
    let mut on_heap = Vec::new();
    let dirs: &mut [Vec3] = if n <= on_stack.len() {
        &mut on_stack[..n]
    } else {
        on_heap.resize(n, Vec3::ZERO);
        &mut on_heap
    };
    for (d, v) in dirs.iter_mut().zip(verts) {
        *d = (*v - point).normalize_or_zero();
    }
    let mut total = 0.0f64;
    for i in 0..n {
        let (a, b) = (dirs[i], dirs[(i + 1) % n]);
        let tri = a.cross(b);
        let len = tri.length();
        if len < 1e-4 {
            continue;
        }
        let angle = (a.dot(b).clamp(-1.0, 1.0) as f64).acos();
        total += normal.dot(tri / len) as f64 * angle;
    }
    (total / std::f64::consts::TAU) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corner(x: f32, y: f32, z: f32, bary: [f32; 3]) -> Corner {
        Corner { p: Vec3::new(x, y, z), bary }
    }

    #[test]
    fn a_cut_splits_a_triangle_and_interpolates_its_corners() {
        let w = [corner(0.0, 0.0, 0.0, [1.0, 0.0, 0.0]), corner(4.0, 0.0, 0.0, [0.0, 1.0, 0.0]), corner(0.0, 0.0, 4.0, [0.0, 0.0, 1.0])];
        let (front, back) = clip(&w, 0, 2.0, 0.01);
        assert_eq!((front.len(), back.len()), (3, 4));
        // The new corners lie on the plane, with the barycentrics of where they are.
        for c in front.iter().chain(&back) {
            let p = w[0].p * c.bary[0] + w[1].p * c.bary[1] + w[2].p * c.bary[2];
            assert!((p - c.p).length() < 1e-5, "{c:?}");
        }
        assert!(front.iter().all(|c| c.p.x >= 2.0 - 1e-5) && back.iter().all(|c| c.p.x <= 2.0 + 1e-5));
        // Areas add up.
        let area = |w: &[Corner]| -> f32 { (2..w.len()).map(|i| 0.5 * (w[i - 1].p - w[0].p).cross(w[i].p - w[0].p).length()).sum() };
        assert!((area(&front) + area(&back) - 8.0).abs() < 1e-4);
    }

    /// The form factor of a large square right above a point is the cosine-weighted
    /// fraction of the hemisphere it covers: for a square of half-width `a` at height `h`,
    /// compare with the analytic value of the four corner rectangles.
    #[test]
    fn form_factor_matches_the_analytic_square() {
        // Analytic point-to-rectangle form factor (receiver parallel, at a corner).
        fn corner(a: f64, b: f64, h: f64) -> f64 {
            let (x, y) = (a / h, b / h);
            let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
            (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / (2.0 * std::f64::consts::PI)
        }
        let (a, h) = (1.5f32, 1.0f32);
        // Seen from below (y up), facing the point: winding clockwise seen from above.
        let sq = [Vec3::new(-a, h, -a), Vec3::new(-a, h, a), Vec3::new(a, h, a), Vec3::new(a, h, -a)];
        let ff = form_factor(Vec3::ZERO, Vec3::Y, &sq);
        let want = 4.0 * corner(a as f64, a as f64, h as f64);
        assert!((ff as f64 - want).abs() < 1e-4, "{ff} vs {want}");
        let rev: Vec<Vec3> = sq.iter().rev().copied().collect();
        assert!((form_factor(Vec3::ZERO, Vec3::Y, &rev) + ff).abs() < 1e-6, "the other winding is negative");
        // A huge square covers nearly the whole hemisphere.
        let big: Vec<Vec3> = sq.iter().map(|p| Vec3::new(p.x * 1e4, p.y, p.z * 1e4)).collect();
        assert!((form_factor(Vec3::ZERO, Vec3::Y, &big) - 1.0).abs() < 1e-3);
    }

    /// A regular polygon right above a point lies between its inscribed and its
    /// circumscribed disc (form factor `r^2 / (r^2 + h^2)` each), with few corners (on
    /// the stack) or many (past the stack's 16, on the heap).
    #[test]
    fn form_factor_of_regular_polygons_lies_between_their_discs() {
        let (r, h) = (1.2f64, 0.8f64);
        let disc = |r: f64| r * r / (r * r + h * h);
        for n in [5usize, 16, 17, 24, 40] {
            // Seen from below, facing the point: the angle decreasing round the winding.
            let verts: Vec<Vec3> = (0..n)
                .map(|k| {
                    let t = -std::f64::consts::TAU * k as f64 / n as f64;
                    Vec3::new((r * t.cos()) as f32, h as f32, (r * t.sin()) as f32)
                })
                .collect();
            let ff = form_factor(Vec3::ZERO, Vec3::Y, &verts) as f64;
            let inner = disc(r * (std::f64::consts::PI / n as f64).cos());
            assert!(inner - 1e-5 < ff && ff < disc(r) + 1e-5, "{n} corners: {ff} not within [{inner}, {}]", disc(r));
        }
    }

    #[test]
    fn subdivision_cuts_to_the_limit_and_keeps_the_area() {
        let w = vec![Vec3::ZERO, Vec3::new(0.0, 0.0, 3.0), Vec3::new(5.0, 0.0, 0.0)];
        let mut out = Vec::new();
        cut(&w, 1.0, 0.0, &mut { usize::MAX }, &mut out);
        assert!(out.len() > 10);
        for p in &out {
            let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            for v in p {
                lo = lo.min(*v);
                hi = hi.max(*v);
            }
            assert!((hi - lo).max_element() <= 1.0 + 1e-5);
        }
        let total: f32 = out.iter().map(|p| polygon_area(p)).sum();
        assert!((total - polygon_area(&w)).abs() < 1e-4, "{total}");
    }

    /// A triangle far bigger than Quake's world is cut into at most 2^MAX_DEPTH pieces,
    /// and they still cover it.
    #[test]
    fn an_absurd_winding_stops_at_the_depth_cap() {
        let w = [Vec3::ZERO, Vec3::new(1e7, 0.0, 0.0), Vec3::new(0.0, 0.0, 1e7)];
        let mut out = Vec::new();
        cut(&w, 1.0, 0.01, &mut { usize::MAX }, &mut out);
        assert!(out.len() <= 1 << MAX_DEPTH && out.len() > 1000, "{} pieces", out.len());
        let total: f64 = out.iter().map(|p| polygon_area(p) as f64).sum();
        assert!((total / polygon_area(&w) as f64 - 1.0).abs() < 1e-3, "{total}");
    }

    /// Cuts stop when the budget does: one piece more per cut, the rest left whole.
    #[test]
    fn cuts_stop_at_the_budget() {
        let w = [Vec3::ZERO, Vec3::new(1e4, 0.0, 0.0), Vec3::new(0.0, 0.0, 1e4)];
        let (mut out, mut left) = (Vec::new(), 1000);
        cut(&w, 1.0, 0.01, &mut left, &mut out);
        assert_eq!(left, 0);
        assert!(out.len() <= 1001 && out.len() > 500, "{} pieces", out.len());
        let total: f64 = out.iter().map(|p| polygon_area(p) as f64).sum();
        assert!((total / polygon_area(&w) as f64 - 1.0).abs() < 1e-3, "{total}");
    }

    /// q3map2 tries Quake's x, y, z in that order: glTF's x, z, y. A triangle across
    /// glTF's y and z is first cut along z (Quake's y), and its front half comes first.
    #[test]
    fn cuts_follow_quakes_axes() {
        let w = [Vec3::ZERO, Vec3::new(0.0, 4.0, 0.0), Vec3::new(0.0, 0.0, 4.0)];
        let mut out = Vec::new();
        cut(&w, 3.0, 0.01, &mut { usize::MAX }, &mut out);
        assert!(out.len() >= 2);
        assert!(out[0].iter().all(|p| p.z >= 2.0 - 1e-5), "the first piece is the front of the cut at z = 2: {:?}", out[0]);
        // An extent equal to the limit is not cut (q3map2 compares in units, `>`).
        let mut whole = Vec::new();
        cut(&[Vec3::ZERO, Vec3::new(3.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 3.0)], 3.0, 0.01, &mut { usize::MAX }, &mut whole);
        assert_eq!(whole.len(), 1);
    }

    #[test]
    fn a_winding_on_one_side_of_a_cut_stays_whole() {
        let w = [corner(2.0, 0.0, 0.0, [1.0, 0.0, 0.0]), corner(4.0, 0.0, 0.0, [0.0, 1.0, 0.0]), corner(2.0, 0.0, 4.0, [0.0, 0.0, 1.0])];
        // Two corners on the plane (within epsilon), one in front: all front.
        let (front, back) = clip(&w, 0, 2.05, 0.125);
        assert_eq!((front.len(), back.len()), (3, 0));
        let (front, back) = clip(&w, 0, 5.0, 0.125);
        assert_eq!((front.len(), back.len()), (0, 3));
    }
}
