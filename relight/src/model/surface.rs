//! Surface lights: materials that emit (q3map2's `q3map_surfacelight`), with their own
//! area and shape, written as emissive materials.
//!
//! q3map2 cuts each emitting triangle by axial planes until no extent exceeds the
//! shader's `q3map_lightSubdivide` (default 999 units) and makes each piece ("patch") an
//! area light whose contribution to a sample is the exact point-to-polygon form factor
//! `F` of the patch seen from the sample (`PointToPolygonFormFactor`), times `0.75 value`
//! bytes, where one shadow ray from the sample to the patch's centre (1 unit in front of
//! it) is clear. Samples within 8 units of the patch's plane are pushed forward to 8
//! units for the form factor; samples behind the plane, and coplanar ones facing the same
//! way, get nothing. A backsplash copy of each patch, `backsplash distance` in front of it
//! and facing back, adds `7 x fraction` as much (default 5% at 23 units; none for sky).
//! A two-sided shader (`cull none`/`disable`/`twosided`, e.g. the flames of torches) emits
//! from both faces: samples behind its plane count, a negative form factor counts as its
//! opposite, and its shadow ray then goes to a point 1 unit behind the patch (its
//! backsplash copy stays one-sided). A two-sided receiver (a row of a `cull none`
//! surface) does the same from its side: no culling behind its plane, a negative form
//! factor counts as its opposite with the shadow ray to the point behind the patch.
//!
//! A Lambertian emitter of radiance `L` [W/(m^2 sr)] gives `E = pi L F`; q3map2's value
//! `V` is `L = 0.75 V e_per_byte` ([`q3gltf_convert::units::q3map2_surface_radiance`]).
//! The model keeps, per row and emitting shader ("group") `s`, the basis
//!
//! ```text
//! B_is = pi sum_patches F_ip V_ip      (+ the backsplash patches, weighted 7 x fraction)
//! ```
//!
//! and fits the group's radiance `L_sc`: `E_ic = sum_s L_sc B_is`; gradient `dF/dL_sc =
//! sum_i rho_ic B_is`. With `-fast` (area lights "fast"), a patch adds nothing where it
//! would add at most one byte at the shader's own value.

use glam::Vec3;

use crate::rows::Rows;
use crate::scene::Scene;
use crate::trace::bvh::{Bvh, Occluder};
use crate::trace::visibility::ShadowRay;

/// One emitting shader.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Group {
    /// The shader's name (material names up to convert's `#` suffix).
    pub name: String,
    /// Its materials.
    pub materials: Vec<u32>,
    /// The radiance q3map2's value stands for, W/(m^2 sr) per channel (colour included).
    pub source_rgb: [f32; 3],
    pub patches: usize,
    /// Emitting area, m^2.
    pub area_m2: f64,
    /// Patch surfaces emitting from q3map2's own mesh of them (the scene's
    /// `q3_patch_lights`), and those whose record no longer matches the mesh (they emit
    /// from their triangles).
    pub q3map2_meshes: usize,
    pub meshes_unmatched: usize,
}

/// The surface lights' basis (see the module docs), one sparse row per objective row.
#[derive(Debug, Clone, Default)]
pub struct SurfaceBasis {
    pub groups: Vec<Group>,
    /// `offsets[i]..offsets[i + 1]` index `entries` for row `i`.
    pub offsets: Vec<u32>,
    /// (group, `B_is`).
    pub entries: Vec<(u32, f32)>,
    /// Shadow rays traced to build it.
    pub rays: u64,
}

/// An emitting polygon (q3map2 winding order), its light origin and normal.
#[derive(Debug, Clone)]
pub struct Patch {
    pub group: u32,
    pub verts: Vec<Vec3>,
    pub origin: Vec3,
    pub normal: Vec3,
    /// `n . origin`.
    pub dist: f32,
    /// Multiplier of the group's value (1, or `7 x fraction` for a backsplash).
    pub weight: f32,
    /// Area, m^2 (for the distance cull).
    pub area: f32,
    /// Emits from both faces (a two-sided shader; never a backsplash copy).
    pub two_sided: bool,
}


/// The emitting groups of a scene and their patches.
pub fn patches(scene: &Scene) -> (Vec<Group>, Vec<Patch>) {
    let u = scene.units_m;
    let e_per_byte = q3gltf_convert::units::e_per_byte(scene.materials.iter().find(|m| m.emitter.is_some()).map_or(2, |m| m.overbright_bits)) as f32;
    let mut groups: Vec<Group> = Vec::new();
    let mut group_of = vec![u32::MAX; scene.materials.len()];
    for (m, mat) in scene.materials.iter().enumerate() {
        let Some(em) = &mat.emitter else { continue };
        let name = mat.name.split('#').next().unwrap_or(&mat.name).to_string();
        let g = match groups.iter().position(|g| g.name == name) {
            Some(g) => g,
            None => {
                let l = q3gltf_convert::units::Q3MAP2_SURFACE_SCALE as f32 * em.value * e_per_byte;
                groups.push(Group { name, materials: Vec::new(), source_rgb: em.color.map(|c| c * l), patches: 0, area_m2: 0.0, q3map2_meshes: 0, meshes_unmatched: 0 });
                groups.len() - 1
            }
        };
        groups[g].materials.push(m as u32);
        group_of[m] = g as u32;
    }
    let mesh = &scene.mesh;
    let mut out = Vec::new();
    let mut cuts_left = CUT_BUDGET;
    // Emitting patches as q3map2 meshed them, where the scene carries its meshes and they
    // still describe the triangles; their triangles then emit nothing themselves.
    let mut taken = vec![false; mesh.triangles.len()];
    if !scene.patch_lights.is_empty() {
        let shader_of_tri: Vec<Option<&str>> = mesh.tri_material.iter().map(|&m| (group_of[m as usize] != u32::MAX).then(|| groups[group_of[m as usize] as usize].name.as_str())).collect();
        let matched = super::patch_mesh::match_triangles(&scene.patch_lights, &mesh.positions, &mesh.triangles, &shader_of_tri, u);
        for (pm, tris) in scene.patch_lights.iter().zip(matched) {
            let Some(g) = groups.iter().position(|g| g.name == pm.shader) else { continue };
            let Some(tris) = tris else {
                groups[g].meshes_unmatched += 1;
                continue;
            };
            let m = mesh.tri_material[tris[0] as usize] as usize;
            for &t in &tris {
                taken[t as usize] = true;
            }
            groups[g].q3map2_meshes += 1;
            for (w, normal) in pm.windings() {
                emit(scene, &mut groups[g], g as u32, m, w, normal, &mut cuts_left, &mut out);
            }
        }
    }
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let m = mesh.tri_material[t] as usize;
        let g = group_of[m];
        if g == u32::MAX || taken[t] {
            continue;
        }
        // Quake's winding: each glTF triangle is its Quake triangle reversed.
        let w = vec![mesh.positions[tri[2] as usize], mesh.positions[tri[1] as usize], mesh.positions[tri[0] as usize]];
        let normal = tri.iter().map(|&v| mesh.normals[v as usize]).sum::<Vec3>().normalize_or_zero();
        if normal == Vec3::ZERO {
            continue;
        }
        emit(scene, &mut groups[g as usize], g, m, w, normal, &mut cuts_left, &mut out);
    }
    (groups, out)
}

/// Cuts of the emitting windings in all, every surface light's together (see
/// [`super::area::cut`]). Real maps make a few hundred to a few thousand patches
/// (oacmpdm1: 784); past the budget, which only a file's absurd windings or
/// `subdivide` reach, the windings left stay whole, so the patches, and the basis's cost
/// of rows times patches, stay bounded.
pub const CUT_BUDGET: usize = 1 << 16;

/// One emitting winding (q3map2's order) of material `m` in group `g`: cut as q3map2
/// cuts it (from `cuts_left`), each piece a patch (and its backsplash copy).
#[allow(clippy::too_many_arguments)]
fn emit(scene: &Scene, group: &mut Group, g: u32, m: usize, w: Vec<Vec3>, normal: Vec3, cuts_left: &mut usize, out: &mut Vec<Patch>) {
    let u = scene.units_m;
    let em = scene.materials[m].emitter.as_ref().expect("grouped materials emit");
    let mut pieces = Vec::new();
    super::area::cut(&w, em.subdivide * u, super::area::CLIP_EPSILON_UNITS * u, cuts_left, &mut pieces);
    for piece in pieces {
        let area = super::area::polygon_area(&piece);
        // q3map2 drops pieces under one square unit.
        if !(area >= u * u) {
            continue;
        }
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for p in &piece {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        let origin = 0.5 * (lo + hi) + normal * (crate::scene::q3map2::AREA_ORIGIN_OFFSET_UNITS * u);
        group.patches += 1;
        group.area_m2 += area as f64;
        let (frac, dist) = em.backsplash;
        if frac > 0.0 {
            let off = normal * (dist * u);
            let verts: Vec<Vec3> = piece.iter().rev().map(|p| *p + off).collect();
            let o = origin + off;
            out.push(Patch { group: g, verts, origin: o, normal: -normal, dist: (-normal).dot(o), weight: 7.0 * frac, area, two_sided: false });
        }
        let two_sided = scene.materials[m].double_sided;
        out.push(Patch { group: g, dist: normal.dot(origin), verts: piece, origin, normal, weight: 1.0, area, two_sided });
    }
}

/// Below this many bytes (at the group's own value) a patch's upper bound skips the
/// ray: the basis is exact above it, a numerical cut of ours (q3map2 has none without
/// `-fast`).
pub const SKIP_BYTES: f32 = 0.01;

/// Builds the basis for `rows`. `fast`: q3map2's `-fast` cut of area lights.
pub fn basis(scene: &Scene, rows: &Rows, bvh: &Bvh, fast: bool) -> SurfaceBasis {
    basis_from(patches(scene), scene, rows, bvh, fast)
}

/// What a row gets from a patch where its shadow ray to it passes: the form factor
/// computed before the ray, or (one-sided both ways) to compute after it, from the
/// pushed sample point.
#[derive(Debug, Clone, Copy)]
enum Passed {
    FormFactor(f32),
    FormFactorAt(Vec3),
}

/// [`basis`] of patches made beforehand: from the mesh as read, when `scene`'s mesh has
/// been subdivided since (q3map2 cut the map's own surfaces, and a subdivided emitter's
/// many small patches would make the cost grow with rows times patches).
pub fn basis_from(emitters: (Vec<Group>, Vec<Patch>), scene: &Scene, rows: &Rows, bvh: &Bvh, fast: bool) -> SurfaceBasis {
    let (mut groups, patches) = emitters;
    if patches.is_empty() {
        return SurfaceBasis { groups, offsets: vec![0; rows.len() + 1], ..Default::default() };
    }
    let u = scene.units_m;
    let bytes_per_ff = bytes_per_form_factor(scene, &groups, &patches);
    // q3map2's distances as a device reads them too ([`Request`]).
    let request = Request { patches: &patches, bytes_per_ff: &bytes_per_ff, groups: groups.len(), units_m: u, fast };
    let (push, behind, s) = (request.push_m(), request.behind_m(), &rows.sampling);
    // Rows in blocks of neighbours, patch by patch ([`by_neighbour_blocks`]); per patch
    // what stopped the previous row's ray to it, tried after what stopped this row's
    // previous ray (the answer is the walk's). A row's state: its (group, B) entries, its
    // rays, and the occluder of its previous ray (neighbouring patches are mostly hidden
    // by the same wall).
    //
    // [`by_neighbour_blocks`]: crate::trace::visibility::by_neighbour_blocks
    type Row = (Vec<(u32, f32)>, u64, Occluder);
    let add = |acc: &mut Vec<(u32, f32)>, group: u32, v: f32| match acc.iter_mut().find(|(g, _)| *g == group) {
        Some(e) => e.1 += v,
        None => acc.push((group, v)),
    };
    // Row `i`'s shadow ray to patch `k`, where q3map2 traces one, and what the row gets
    // where the ray passes.
    let ray_to = |i: usize, k: usize| -> Option<(ShadowRay, Passed)> {
        let (x, n, two_sided) = (rows.pos[i], rows.normal[i], rows.two_sided[i]);
        let (p, bpf) = (&patches[k], bytes_per_ff[k]);
        // The light origin behind the sample's plane: nothing (a two-sided row looks
        // both ways).
        if !two_sided && (p.origin - x).dot(n) < 0.0 {
            return None;
        }
        // q3map2's tests are in whole Quake units on map geometry that sits on them:
        // compare in units, with a little slack for the rounding of meters.
        let d = p.normal.dot(x) - p.dist;
        let du = d / u;
        if du < 3.0 - 1e-3 && ((!p.two_sided && du < -1.0 - 1e-3) || (du > -3.0 + 1e-3 && n.dot(p.normal) > 0.9)) {
            return None;
        }
        // Upper bound of the form factor from the distance to the origin.
        let r2 = (p.origin - x).length_squared();
        if p.area / (std::f32::consts::PI * r2) * bpf < SKIP_BYTES && r2 > 4.0 * p.area {
            return None;
        }
        let pushed = if d > -push && d < push { x + p.normal * (push - d) } else { x };
        // One-sided both ways, without `-fast`: the ray first. Most rays are stopped
        // (oacmpdm4: 62 of 97 M), and then the form factor, which only the rays
        // that get through need, is never computed; the entries are the same.
        if !(p.two_sided || two_sided || fast) {
            return Some((ShadowRay { x, n, target: p.origin }, Passed::FormFactorAt(pushed)));
        }
        let mut ff = super::area::form_factor(pushed, n, &p.verts);
        // Seen from behind a two-sided patch, or by a two-sided row from behind its own
        // plane: the opposite form factor, and the shadow ray goes to a point 1 unit
        // behind the patch (q3map2 either way).
        let mut target = p.origin;
        if ff < 0.0 && (p.two_sided || two_sided) {
            ff = -ff;
            target = p.origin - p.normal * behind;
        }
        if !(ff > 0.0) {
            return None;
        }
        if fast && ff * bpf <= crate::scene::q3map2::FALLOFF_TOLERANCE_BYTES {
            return None;
        }
        Some((ShadowRay { x, n: rows.facing(i, target - x), target }, Passed::FormFactor(ff)))
    };
    // A block's rays to one patch, walked together (`visible_together`), each row's
    // previous ray's occluder tried first, then the previous row's ray's to this patch.
    let block_to_patch = |block: std::ops::Range<usize>, k: usize, states: &mut [Row]| {
        const N: usize = crate::trace::visibility::HINT_ROWS;
        let (mut rays, mut passed, mut own, mut at) = ([ShadowRay { x: Vec3::ZERO, n: Vec3::ZERO, target: Vec3::ZERO }; N], [Passed::FormFactor(0.0); N], [Occluder::default(); N], [0usize; N]);
        let mut m = 0;
        for (j, i) in block.enumerate() {
            if let Some((ray, then)) = ray_to(i, k) {
                (rays[m], passed[m], own[m], at[m]) = (ray, then, states[j].2, j);
                states[j].1 += 1;
                m += 1;
            }
        }
        let mut visible = [false; N];
        crate::trace::visibility::visible_together(bvh, &rays[..m], s, &mut own[..m], &mut Occluder::default(), &mut visible[..m]);
        let p = &patches[k];
        for r in 0..m {
            let state = &mut states[at[r]];
            state.2 = own[r];
            if !visible[r] {
                continue;
            }
            let ff = match passed[r] {
                Passed::FormFactor(ff) => ff,
                Passed::FormFactorAt(pushed) => super::area::form_factor(pushed, rays[r].n, &p.verts),
            };
            if ff > 0.0 {
                add(&mut state.0, p.group, std::f32::consts::PI * ff * p.weight);
            }
        }
    };
    let per_row = crate::trace::visibility::by_neighbour_block_sources(rows.len(), patches.len(), |_| -> Row { (Vec::new(), 0, Default::default()) }, block_to_patch);
    let mut b = SurfaceBasis { offsets: Vec::with_capacity(rows.len() + 1), ..Default::default() };
    b.offsets.push(0);
    for (acc, rays, _) in per_row {
        b.entries.extend(acc);
        b.offsets.push(b.entries.len() as u32);
        b.rays += rays;
    }
    round_areas(&mut groups);
    b.groups = groups;
    b
}

/// Bytes per unit of form factor, per patch: `0.75 V` of the brightest channel, times the
/// patch's weight (what [`SKIP_BYTES`] and `-fast` compare with).
pub fn bytes_per_form_factor(scene: &Scene, groups: &[Group], patches: &[Patch]) -> Vec<f32> {
    let ob = scene.materials.iter().find(|m| m.emitter.is_some()).map_or(2, |m| m.overbright_bits);
    let e_per_byte = q3gltf_convert::units::e_per_byte(ob) as f32;
    patches.iter().map(|p| p.weight * groups[p.group as usize].source_rgb.iter().copied().fold(0.0, f32::max) / e_per_byte).collect()
}

/// Groups that reach no row stay listed (the report says so) but fit to nothing; their
/// areas are reported to the square millimetre.
fn round_areas(groups: &mut [Group]) {
    for g in groups {
        g.area_m2 = (g.area_m2 * 1e6).round() / 1e6;
    }
}

/// What a backend with its own kernel for the basis computes ([`basis_from`]'s sums, on
/// the device): per row, every group's `B_is`, and the shadow rays traced.
#[derive(Debug, Clone)]
pub struct Sums {
    /// `rows x groups`, row-major.
    pub per_row: Vec<f32>,
    pub rays: u64,
}

/// Everything a device needs to build the basis as [`basis_from`] does: the patches, their
/// [`bytes_per_form_factor`], and q3map2's distances in meters.
#[derive(Debug, Clone, Copy)]
pub struct Request<'a> {
    pub patches: &'a [Patch],
    pub bytes_per_ff: &'a [f32],
    pub groups: usize,
    /// Meters per Quake unit.
    pub units_m: f32,
    /// q3map2's `-fast` cut of area lights.
    pub fast: bool,
}

impl<'a> Request<'a> {
    /// Samples nearer a patch's plane than this are pushed out to it for the form factor, m.
    pub fn push_m(&self) -> f32 {
        crate::scene::q3map2::AREA_PUSH_UNITS * self.units_m
    }
    /// The shadow ray's target behind a two-sided patch lies this far behind its origin, m.
    pub fn behind_m(&self) -> f32 {
        2.0 * crate::scene::q3map2::AREA_ORIGIN_OFFSET_UNITS * self.units_m
    }
}

/// The basis from a device's [`Sums`] (the entries of a row in group order, zeros left
/// out, as [`basis_from`] leaves out the groups whose patches add nothing).
pub fn basis_from_sums(emitters: (Vec<Group>, Vec<Patch>), sums: &Sums, rows: usize) -> SurfaceBasis {
    let (mut groups, _) = emitters;
    let ng = groups.len();
    let mut b = SurfaceBasis { offsets: Vec::with_capacity(rows + 1), rays: sums.rays, ..Default::default() };
    b.offsets.push(0);
    for i in 0..rows {
        let row = sums.per_row.get(i * ng..(i + 1) * ng).unwrap_or(&[]);
        b.entries.extend(row.iter().enumerate().filter(|(_, v)| **v != 0.0).map(|(g, v)| (g as u32, *v)));
        b.offsets.push(b.entries.len() as u32);
    }
    round_areas(&mut groups);
    b.groups = groups;
    b
}

impl SurfaceBasis {
    pub fn row(&self, i: usize) -> &[(u32, f32)] {
        &self.entries[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Adds `sum_s L_s B_is` for the groups' radiances `l` (a group set to `None` is off).
    pub fn add_irradiance(&self, l: &[Option<[f32; 3]>], e: &mut [[f64; 3]]) {
        use rayon::prelude::*;
        e.par_iter_mut().enumerate().for_each(|(i, ei)| {
            for &(g, b) in self.row(i) {
                if let Some(Some(rgb)) = l.get(g as usize) {
                    for c in 0..3 {
                        ei[c] += rgb[c] as f64 * b as f64;
                    }
                }
            }
        });
    }

    /// `dF/dL_s` per group.
    pub fn gradient(&self, rho: &[[f64; 3]]) -> Vec<[f64; 3]> {
        let mut g = vec![[0.0f64; 3]; self.groups.len()];
        for (i, r) in rho.iter().enumerate() {
            for &(s, b) in self.row(i) {
                for c in 0..3 {
                    g[s as usize][c] += r[c] * b as f64;
                }
            }
        }
        g
    }

    /// Rows that see group `s`.
    pub fn reach(&self, s: usize) -> usize {
        (0..self.offsets.len().saturating_sub(1)).filter(|&i| self.row(i).iter().any(|&(g, _)| g as usize == s)).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A two-sided emitter (`cull none`) standing in the middle of a room lights the wall
    /// behind it as the wall in front (the room is symmetric about it); a one-sided one
    /// lights the wall behind it not at all.
    #[test]
    fn a_two_sided_emitter_lights_both_sides_alike() {
        use crate::scene::{Emitter, Material};
        let (mut mesh, rows) = crate::testutil::room(6);
        // A 1 m square in the plane x = 2 (the room spans x in [0, 4]), facing +x.
        let (y0, y1, z0, z1) = (0.75f32, 1.75f32, 1.0f32, 2.0f32);
        let base = mesh.positions.len() as u32;
        for p in [Vec3::new(2.0, y0, z0), Vec3::new(2.0, y1, z0), Vec3::new(2.0, y1, z1), Vec3::new(2.0, y0, z1)] {
            mesh.positions.push(p);
            mesh.normals.push(Vec3::X);
            mesh.uv0.push(glam::Vec2::ZERO);
            mesh.uv1.push(glam::Vec2::ZERO);
            mesh.colors.push([1.0; 3]);
            mesh.v_material.push(1);
        }
        mesh.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        let n = mesh.triangles.len() as u32;
        mesh.tri_source.extend([n - 2, n - 1]);
        mesh.tri_material.extend([1, 1]);
        mesh.reweld();
        let flame = Emitter { value: 2000.0, color: [1.0, 0.6, 0.3], subdivide: 16.0, backsplash: (0.0, 23.0) };
        let basis_with = |double_sided: bool| {
            let emitting = Material { emitter: Some(flame.clone()), double_sided, ..crate::testutil::material("flame") };
            let scene = crate::testutil::scene(mesh.clone(), vec![crate::testutil::material("wall"), emitting]);
            let bvh = Bvh::build(&scene.mesh);
            let b = basis(&scene, &rows, &bvh, false);
            (0..rows.len()).map(|i| b.row(i).iter().map(|e| e.1 as f64).sum::<f64>()).collect::<Vec<f64>>()
        };
        // The walls x = 0 (behind the emitter) and x = 4 (in front), row by row.
        let rows_ref = &rows;
        let wall = |x: f32| (0..rows_ref.len()).filter(move |&i| (rows_ref.pos[i].x - x).abs() < 1e-5 && rows_ref.normal[i].x.abs() > 0.9);
        let pairs: Vec<(usize, usize)> = wall(0.0)
            .filter_map(|i| wall(4.0).find(|&k| (rows.pos[k].y - rows.pos[i].y).abs() < 1e-5 && (rows.pos[k].z - rows.pos[i].z).abs() < 1e-5).map(|k| (i, k)))
            .collect();
        assert!(pairs.len() >= 25, "{} pairs", pairs.len());
        let (one, two) = (basis_with(false), basis_with(true));
        let lit = pairs.iter().filter(|&&(_, front)| one[front] > 1e-4).count();
        assert!(lit >= 25, "the emitter lights {lit} rows of the wall in front");
        for &(behind, front) in &pairs {
            assert_eq!(one[behind], 0.0, "one-sided: the wall behind is dark");
            assert!((two[front] - one[front]).abs() <= 1e-6 * one[front].max(1e-3), "the front is the same either way");
            assert!((two[behind] - two[front]).abs() <= 2e-3 * two[front].max(1e-3), "behind {} vs front {}", two[behind], two[front]);
        }
    }

    /// A file's emitter far larger than a map (the room's walls scaled to 400 m, 15 748
    /// units, subdivided every 8 units: four million pieces a wall) is cut until the
    /// shared budget is spent, and no further: its patches stay bounded.
    #[test]
    fn a_huge_emitter_stops_at_the_cut_budget() {
        use crate::scene::{Emitter, Material};
        let (mut mesh, _) = crate::testutil::room(2);
        mesh.positions.iter_mut().for_each(|p| *p *= 100.0);
        let big = Emitter { value: 100.0, color: [1.0; 3], subdivide: 8.0, backsplash: (0.0, 23.0) };
        let emitting = Material { emitter: Some(big), ..crate::testutil::material("wall") };
        let mut scene = crate::testutil::scene(mesh, vec![emitting]);
        scene.mesh.tri_material.iter_mut().for_each(|m| *m = 0);
        let (groups, patches) = super::patches(&scene);
        let tris = scene.mesh.triangles.len();
        // Each cut makes one more piece.
        assert!(patches.len() <= CUT_BUDGET + tris, "{} patches", patches.len());
        assert!(patches.len() > CUT_BUDGET / 2, "the budget was spent: {} patches", patches.len());
        assert_eq!(groups.len(), 1);
    }

}
