//! Properties of converted real OpenArena maps (pak1-maps.pk3 and pak6-patch088.pk3),
//! read back through the `gltf` crate and compared with the BSP itself.

mod common;

use q3gltf_convert::bsp::{Bsp, SurfaceType};
use q3gltf_convert::gltf_out;
use q3gltf_convert::material::{self, Visibility};
use q3gltf_convert::patch::{self, PatchInput};
use q3gltf_convert::pipeline::{build_scene, resolve_shaders, LoadedMap, Options};
use q3gltf_convert::units;
use rayon::prelude::*;
use std::collections::HashMap;

type P3 = [f64; 3];
type Key = [[u32; 3]; 3];

fn sub(a: P3, b: P3) -> P3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn cross(a: P3, b: P3) -> P3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn dot(a: P3, b: P3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn norm(a: P3) -> f64 {
    dot(a, a).sqrt()
}
fn f64s(p: [f32; 3]) -> P3 {
    p.map(|x| x as f64)
}

/// Triangle key invariant under rotation of its corners (not under reversal).
fn tri_key(t: [[f32; 3]; 3]) -> Key {
    let b = t.map(|p| p.map(|x| (x + 0.0).to_bits()));
    let rots = [[b[0], b[1], b[2]], [b[1], b[2], b[0]], [b[2], b[0], b[1]]];
    *rots.iter().min().unwrap()
}

/// Output triangles of a GLB: positions, normals at corners, whether the primitive is
/// lightmapped, TEXCOORD_1 per corner.
struct OutTri {
    p: [[f32; 3]; 3],
    n: [[f32; 3]; 3],
    lightmapped: bool,
}

fn read_glb(glb: &[u8]) -> (gltf::Gltf, Vec<OutTri>) {
    let g = gltf::Gltf::from_slice(glb).expect("our GLB parses");
    let blob = g.blob.clone().expect("GLB has a BIN chunk");
    let mut tris = Vec::new();
    for mesh in g.document.meshes() {
        for prim in mesh.primitives() {
            let r = prim.reader(|_| Some(&blob[..]));
            let pos: Vec<[f32; 3]> = r.read_positions().unwrap().collect();
            let nrm: Vec<[f32; 3]> = r.read_normals().unwrap().collect();
            let lightmapped = r.read_tex_coords(1).is_some();
            let idx: Vec<u32> = r.read_indices().unwrap().into_u32().collect();
            for t in idx.chunks_exact(3) {
                tris.push(OutTri {
                    p: [pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]],
                    n: [nrm[t[0] as usize], nrm[t[1] as usize], nrm[t[2] as usize]],
                    lightmapped,
                });
            }
        }
    }
    (g, tris)
}

fn shader_infos(map: &LoadedMap) -> Vec<material::ShaderInfo> {
    let (infos, unreadable) = resolve_shaders(map);
    assert!(unreadable.is_empty(), "{}: {unreadable:?}", map.shown);
    infos
}

/// Surfaces that belong to a model and whose shader is drawn (sky included).
fn drawn_surfaces(bsp: &Bsp, infos: &[material::ShaderInfo]) -> Vec<usize> {
    let mut in_model = vec![false; bsp.surfaces.len()];
    for m in &bsp.models {
        for s in m.first_surface..m.first_surface + m.num_surfaces {
            in_model[s as usize] = true;
        }
    }
    (0..bsp.surfaces.len())
        .filter(|&i| {
            let s = &bsp.surfaces[i];
            in_model[i]
                && matches!(s.kind, SurfaceType::Polygon | SurfaceType::Mesh | SurfaceType::Patch)
                && matches!(infos[s.shader as usize].visibility, Visibility::Drawn | Visibility::Sky)
        })
        .collect()
}

#[derive(Default, Debug)]
struct WindingReport {
    bsp_tris: usize,
    bsp_disagree: usize,
    out_tris: usize,
    out_disagree: usize,
    reversed: usize,
    same_orientation: usize,
    not_in_bsp: usize,
    patch_tris: usize,
    patch_disagree: usize,
}

fn winding_report(pk3: &str, name: &str) -> WindingReport {
    let map = common::load_from(pk3, name);
    // The BSP's triangles as they are (the overlap cut replaces some: tested below and in
    // tests/python/test_coplanar_overlaps.py).
    let opts = Options { keep_overlaps: true, ..Options::default() };
    let (scene, _) = build_scene(&map, &opts, &|_| {}).unwrap();
    let glb = gltf_out::to_glb(&scene, &gltf_out::WriteOptions::default());
    let (_, out) = read_glb(&glb);
    let bsp = &map.bsp;
    let infos = shader_infos(&map);
    let mut rep = WindingReport::default();
    // BSP triangles (engine order), converted to glTF space but not reversed, each with
    // whether it is a proper triangle (not a sliver whose normal sign is noise).
    let mut bsp_keys: HashMap<Key, Vec<bool>> = HashMap::new();
    for si in drawn_surfaces(bsp, &infos) {
        let s = &bsp.surfaces[si];
        if s.kind == SurfaceType::Patch {
            continue;
        }
        let v = bsp.surface_verts(s);
        for t in bsp.surface_indices(s).chunks_exact(3) {
            let c = [v[t[0] as usize], v[t[1] as usize], v[t[2] as usize]];
            // BSP fronts are clockwise: geometric normal (p2 - p0) x (p1 - p0).
            let p = c.map(|d| f64s(d.xyz));
            let g = cross(sub(p[2], p[0]), sub(p[1], p[0]));
            let longest = [sub(p[1], p[0]), sub(p[2], p[1]), sub(p[0], p[2])].iter().map(|e| dot(*e, *e)).fold(0.0, f64::max);
            // Zero vertex normals are repaired by the converter (glTF needs unit normals),
            // so those triangles say nothing about winding.
            let has_normals = c.iter().all(|d| norm(f64s(d.normal)) > 1e-6);
            // Normals nearly in the triangle's plane neither agree nor disagree.
            let nsum = [0, 1, 2].map(|k| c.iter().map(|d| d.normal[k] as f64 / norm(f64s(d.normal)).max(1e-30)).sum::<f64>());
            let decidable = (dot(g, nsum) / (norm(g) * norm(nsum)).max(1e-300)).abs() > 1e-3;
            let proper = norm(g) > 1e-4 * longest && has_normals && decidable;
            bsp_keys.entry(tri_key(c.map(|d| units::position(d.xyz, opts.scale)))).or_default().push(proper);
            if !proper {
                continue;
            }
            let n = [0, 1, 2].map(|k| c.iter().map(|d| d.normal[k] as f64).sum::<f64>());
            rep.bsp_tris += 1;
            if dot(g, n) <= 0.0 {
                rep.bsp_disagree += 1;
            }
        }
    }
    for t in &out {
        let rev = tri_key([t.p[0], t.p[2], t.p[1]]);
        let same = tri_key(t.p);
        let p = t.p.map(f64s);
        let g = cross(sub(p[1], p[0]), sub(p[2], p[0]));
        let n = [0, 1, 2].map(|k| t.n.iter().map(|d| d[k] as f64).sum::<f64>());
        let degenerate = norm(g) < 1e-12;
        if let Some(proper) = bsp_keys.get_mut(&rev).and_then(|c| c.pop()) {
            rep.reversed += 1;
            // Degeneracy as judged on the BSP triangle (the same triangle, rescaled).
            if proper {
                rep.out_tris += 1;
                if dot(g, n) <= 0.0 {
                    rep.out_disagree += 1;
                }
            }
        } else if bsp_keys.get(&same).is_some_and(|c| !c.is_empty()) {
            rep.same_orientation += 1;
        } else {
            rep.not_in_bsp += 1;
            if !degenerate {
                rep.patch_tris += 1;
                if dot(g, n) <= 0.0 {
                    rep.patch_disagree += 1;
                }
            }
        }
    }
    rep
}

/// Every output triangle is its BSP triangle reversed (counter-clockwise), and the
/// geometric normals agree with the NORMALs exactly as often as the BSP's own winding
/// agrees with the BSP's vertex normals. Patch triangles (not in the BSP) must agree
/// with their interpolated normals on practically every triangle.
#[test]
fn winding_matches_bsp_on_every_map() {
    let maps = common::all_test_maps();
    let reports: Vec<(String, WindingReport)> =
        maps.par_iter().map(|(pk3, m)| (format!("{pk3}:{m}"), winding_report(pk3, m))).collect();
    let mut total_patch = 0;
    for (name, r) in &reports {
        let bsp_frac = r.bsp_disagree as f64 / r.bsp_tris.max(1) as f64;
        if r.bsp_disagree > 0 {
            eprintln!("{name}: {} of {} BSP triangles ({:.2}%) have vertex normals opposite to their winding (kept as they are)", r.bsp_disagree, r.bsp_tris, 100.0 * bsp_frac);
        }
        assert_eq!(r.same_orientation, 0, "{name}: triangles kept in Quake's clockwise order: {r:?}");
        assert_eq!(r.out_tris, r.bsp_tris, "{name}: every non-degenerate BSP triangle appears once: {r:?}");
        assert_eq!(r.out_disagree, r.bsp_disagree, "{name}: winding/normal agreement changed: {r:?}");
        total_patch += r.patch_tris;
        if r.patch_tris > 0 {
            let frac = r.patch_disagree as f64 / r.patch_tris as f64;
            assert!(frac < 0.01, "{name}: {:.2}% of patch triangles face away from their normals: {r:?}", frac * 100.0);
        }
    }
    assert!(total_patch > 1000, "the maps have patches: {total_patch} patch triangles");
}

/// Nearest-texel sample of the atlas at a vertex's TEXCOORD_1 equals the BSP lightmap
/// texel at the vertex's original lightmap coordinate.
#[test]
fn atlas_texel_at_texcoord1_is_the_bsp_texel() {
    let mut checked_maps = 0;
    let mut total_checked = 0usize;
    for (pk3, name) in common::all_test_maps() {
        let map = common::load_from(pk3, &name);
        let bsp = &map.bsp;
        if bsp.lightmaps.is_empty() {
            continue;
        }
        // At the BSP's own vertices (the overlap cut adds interpolated ones).
        let opts = Options { keep_overlaps: true, ..Options::default() };
        let (scene, summary) = build_scene(&map, &opts, &|_| {}).unwrap();
        let glb = gltf_out::to_glb(&scene, &gltf_out::WriteOptions::default());
        let g = gltf::Gltf::from_slice(&glb).unwrap();
        let blob = g.blob.clone().unwrap();
        // Expected texels per (position, uv0) of BSP vertices on lightmapped surfaces.
        let step = if summary.deluxe { 2 } else { 1 };
        let mut expect: HashMap<([u32; 3], [u32; 2]), Vec<[u8; 3]>> = HashMap::new();
        for s in &bsp.surfaces {
            if s.kind == SurfaceType::Patch || s.lightmap < 0 || s.lightmap as usize >= bsp.lightmaps.len() || s.lightmap % step != 0 {
                continue;
            }
            if !matches!(s.kind, SurfaceType::Polygon | SurfaceType::Mesh) {
                continue;
            }
            let page = &bsp.lightmaps[s.lightmap as usize];
            for v in bsp.surface_verts(s) {
                let key = (units::position(v.xyz, opts.scale).map(|x| (x + 0.0).to_bits()), v.st.map(|x| (x + 0.0).to_bits()));
                let e = expect.entry(key).or_default();
                // Texel under the coordinate; on a texel edge, both neighbours.
                let cands = |c: f32| {
                    let x = c as f64 * 128.0;
                    let mut v = vec![x.floor()];
                    if (x - x.round()).abs() < 1e-3 {
                        v.push(x.round() - 1.0);
                        v.push(x.round());
                    }
                    v.into_iter().map(|t| t.clamp(0.0, 127.0) as usize).collect::<Vec<_>>()
                };
                for ty in cands(v.lightmap[1]) {
                    for tx in cands(v.lightmap[0]) {
                        let o = (ty * 128 + tx) * 3;
                        e.push([page[o], page[o + 1], page[o + 2]]);
                    }
                }
            }
        }
        // Positions of patch vertices: a patch vertex can coincide with a polygon vertex
        // (same st) while having its own lightmap coordinate.
        let infos = shader_infos(&map);
        let pids: Vec<usize> = drawn_surfaces(bsp, &infos).into_iter().filter(|&i| bsp.surfaces[i].kind == SurfaceType::Patch).collect();
        let inputs: Vec<PatchInput> = pids
            .iter()
            .map(|&i| PatchInput::of(bsp, &bsp.surfaces[i]))
            .collect();
        let on_patch: std::collections::HashSet<[u32; 3]> = patch::tessellate_all(&inputs, opts.patch_tolerance, usize::MAX)
            .unwrap()
            .iter()
            .flat_map(|t| t.verts.iter().map(|v| units::position(v.xyz, opts.scale).map(|x| (x + 0.0).to_bits())))
            .collect();
        let mut checked = 0usize;
        let mut decoded: HashMap<usize, image::RgbImage> = HashMap::new();
        for mesh in g.document.meshes() {
            for prim in mesh.primitives() {
                let r = prim.reader(|_| Some(&blob[..]));
                let Some(uv1) = r.read_tex_coords(1) else { continue };
                let occ = prim.material().occlusion_texture().expect("lightmapped primitives reference the atlas as occlusion");
                assert_eq!(occ.tex_coord(), 1);
                let img_index = occ.texture().source().index();
                let img = decoded.entry(img_index).or_insert_with(|| {
                    let gltf::image::Source::View { view, .. } = g.document.images().nth(img_index).unwrap().source() else { panic!("GLB image not in a view") };
                    let bytes = &blob[view.offset()..view.offset() + view.length()];
                    image::load_from_memory(bytes).unwrap().to_rgb8()
                });
                let pos: Vec<[f32; 3]> = r.read_positions().unwrap().collect();
                let uv0: Vec<[f32; 2]> = r.read_tex_coords(0).unwrap().into_f32().collect();
                for ((p, t0), t1) in pos.iter().zip(&uv0).zip(uv1.into_f32()) {
                    let key = (p.map(|x| (x + 0.0).to_bits()), t0.map(|x| (x + 0.0).to_bits()));
                    if on_patch.contains(&key.0) {
                        continue;
                    }
                    let Some(cands) = expect.get(&key) else { continue };
                    let x = ((t1[0] as f64 * img.width() as f64).floor() as u32).min(img.width() - 1);
                    let y = ((t1[1] as f64 * img.height() as f64).floor() as u32).min(img.height() - 1);
                    let got = img.get_pixel(x, y).0;
                    assert!(cands.contains(&got), "{pk3}:{name}: texel {got:?} at uv1 {t1:?} is none of {cands:?}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 0 || expect.is_empty(), "{pk3}:{name}: no lightmapped vertex checked");
        total_checked += checked;
        checked_maps += 1;
    }
    eprintln!("{total_checked} lightmapped vertices on {checked_maps} maps checked");
    assert!(checked_maps > 50 && total_checked > 100_000);
}

fn tri_area(p: [[f32; 3]; 3]) -> f64 {
    let p = p.map(f64s);
    0.5 * norm(cross(sub(p[1], p[0]), sub(p[2], p[0])))
}

/// The lightmapped area of the glTF equals that of the BSP's lightmapped faces (patches
/// counted through their tessellation), within 1e-4 relative, with the overlaps kept;
/// cutting them (the default) takes away exactly the area it reports removed.
#[test]
fn lightmapped_area_is_preserved() {
    let maps = common::all_test_maps();
    let removed_total: f64 = maps.par_iter().map(|(pk3, name)| {
        let map = common::load_from(pk3, name);
        let opts = Options { keep_overlaps: true, ..Options::default() };
        let (scene, summary) = build_scene(&map, &opts, &|_| {}).unwrap();
        let glb = gltf_out::to_glb(&scene, &gltf_out::WriteOptions::default());
        let (_, out) = read_glb(&glb);
        let a_out: f64 = out.iter().filter(|t| t.lightmapped).map(|t| tri_area(t.p)).sum();
        let (cut_scene, cut_summary) = build_scene(&map, &Options::default(), &|_| {}).unwrap();
        let (_, cut) = read_glb(&gltf_out::to_glb(&cut_scene, &gltf_out::WriteOptions::default()));
        let (a_all, a_cut) = (out.iter().map(|t| tri_area(t.p)).sum::<f64>(), cut.iter().map(|t| tri_area(t.p)).sum::<f64>());
        let removed = cut_summary.surfaces.overlaps.area_removed_m2;
        assert!(
            ((a_all - a_cut) - removed).abs() <= 1e-6 * a_all + 1e-6,
            "{pk3}:{name}: the cut took {} m2, it reports {removed} m2",
            a_all - a_cut
        );
        let bsp = &map.bsp;
        let infos = shader_infos(&map);
        let step = if summary.deluxe { 2 } else { 1 };
        let lit = |l: i32| l >= 0 && (l as usize) < bsp.lightmaps.len().max(1) && l % step == 0;
        let s2 = opts.scale * opts.scale;
        let mut a_bsp = 0.0;
        let drawn = drawn_surfaces(bsp, &infos);
        let mut patches = Vec::new();
        for &si in &drawn {
            let s = &bsp.surfaces[si];
            if !lit(s.lightmap) || bsp.lightmaps.is_empty() {
                continue;
            }
            if s.kind == SurfaceType::Patch {
                patches.push(si);
                continue;
            }
            let v = bsp.surface_verts(s);
            for t in bsp.surface_indices(s).chunks_exact(3) {
                a_bsp += s2 * tri_area([v[t[0] as usize].xyz, v[t[1] as usize].xyz, v[t[2] as usize].xyz]);
            }
        }
        // Patches as tessellated together with all drawn patches (stitching couples them).
        let all_patches: Vec<usize> = drawn.iter().copied().filter(|&i| bsp.surfaces[i].kind == SurfaceType::Patch).collect();
        let inputs: Vec<PatchInput> = all_patches
            .iter()
            .map(|&i| PatchInput::of(bsp, &bsp.surfaces[i]))
            .collect();
        let tess = patch::tessellate_all(&inputs, opts.patch_tolerance, usize::MAX).unwrap();
        for (i, t) in all_patches.iter().zip(&tess) {
            if patches.contains(i) {
                for c in t.indices.chunks_exact(3) {
                    a_bsp += s2 * tri_area([t.verts[c[0] as usize].xyz, t.verts[c[1] as usize].xyz, t.verts[c[2] as usize].xyz]);
                }
            }
        }
        let rel = (a_out - a_bsp).abs() / a_bsp.max(1e-12);
        if a_bsp > 0.0 {
            assert!(rel < 1e-4, "{pk3}:{name}: lightmapped area {a_out} m2 vs BSP {a_bsp} m2 (rel {rel:e})");
        } else {
            assert_eq!(a_out, 0.0, "{pk3}:{name}: lightmapped triangles in a map without lightmaps");
        }
        removed
    }).sum();
    assert!(removed_total > 100.0, "the maps have overlapping faces: {removed_total} m2 cut");
}

/// Patch tessellation on real maps: no T-junctions or cracks between neighbouring
/// patches (every boundary vertex lying on another patch's boundary is one of its
/// vertices, bit for bit), and the triangles stay within the tolerance of the true
/// Bezier surface.
#[test]
fn patches_are_crack_free_and_within_tolerance() {
    let tolerance = 4.0;
    let mut shared_vertices = 0usize;
    let mut max_dev: f64 = 0.0;
    for (pk3, name) in common::all_test_maps() {
        let map = common::load_from(pk3, &name);
        let bsp = &map.bsp;
        let infos = shader_infos(&map);
        let ids: Vec<usize> = drawn_surfaces(bsp, &infos).into_iter().filter(|&i| bsp.surfaces[i].kind == SurfaceType::Patch).collect();
        if ids.is_empty() {
            continue;
        }
        let inputs: Vec<PatchInput> = ids
            .iter()
            .map(|&i| PatchInput::of(bsp, &bsp.surfaces[i]))
            .collect();
        let tess = patch::tessellate_all(&inputs, tolerance, usize::MAX).unwrap();

        // Boundary edges of every patch: edges used by exactly one of its triangles.
        let boundary = |t: &patch::Tessellated| -> Vec<([f32; 3], [f32; 3])> {
            let mut count: HashMap<(u32, u32), usize> = HashMap::new();
            for tri in t.indices.chunks_exact(3) {
                for k in 0..3 {
                    let (a, b) = (tri[k], tri[(k + 1) % 3]);
                    *count.entry((a.min(b), a.max(b))).or_default() += 1;
                }
            }
            count.into_iter().filter(|(_, n)| *n == 1).map(|((a, b), _)| (t.verts[a as usize].xyz, t.verts[b as usize].xyz)).collect()
        };
        let edges: Vec<Vec<([f32; 3], [f32; 3])>> = tess.iter().map(boundary).collect();
        // Spatial hash of boundary edges, cell = 16 units.
        let cell = |p: P3| [(p[0] / 16.0).floor() as i64, (p[1] / 16.0).floor() as i64, (p[2] / 16.0).floor() as i64];
        let mut grid: HashMap<[i64; 3], Vec<(usize, [f32; 3], [f32; 3])>> = HashMap::new();
        for (pi, es) in edges.iter().enumerate() {
            for &(a32, b32) in es {
                let (a, b) = (f64s(a32), f64s(b32));
                let (ca, cb) = (cell(a), cell(b));
                for x in ca[0].min(cb[0])..=ca[0].max(cb[0]) {
                    for y in ca[1].min(cb[1])..=ca[1].max(cb[1]) {
                        for z in ca[2].min(cb[2])..=ca[2].max(cb[2]) {
                            grid.entry([x, y, z]).or_default().push((pi, a32, b32));
                        }
                    }
                }
            }
        }
        for (pi, es) in edges.iter().enumerate() {
            let verts: std::collections::BTreeSet<[u32; 3]> = es.iter().flat_map(|e| [e.0, e.1]).map(|v| v.map(f32::to_bits)).collect();
            for v in verts {
                let v = v.map(f32::from_bits);
                let p = f64s(v);
                for &(pj, a, b) in grid.get(&cell(p)).into_iter().flatten() {
                    if pj == pi {
                        continue;
                    }
                    if v == a || v == b {
                        shared_vertices += 1;
                        continue;
                    }
                    // Distance from v to the inside of segment ab.
                    let (a, b) = (f64s(a), f64s(b));
                    let ab = sub(b, a);
                    let len2 = dot(ab, ab);
                    if len2 < 1e-12 {
                        continue;
                    }
                    let t = dot(sub(p, a), ab) / len2;
                    if t <= 1e-6 || t >= 1.0 - 1e-6 {
                        continue;
                    }
                    let q = [a[0] + ab[0] * t, a[1] + ab[1] * t, a[2] + ab[2] * t];
                    let d = norm(sub(p, q));
                    assert!(d > 1e-3, "{pk3}:{name}: T-junction: vertex {v:?} of patch {pi} lies inside an edge of patch {pj}");
                }
            }
        }

        // Deviation: sample the true surface inside each grid cell and compare with the
        // cell's two triangles, evaluated at the same parameters (the tessellation is
        // piecewise linear in parameter space).
        for (inp, t) in inputs.iter().zip(&tess) {
            let (w, h) = (t.width, t.height);
            for r in 0..h - 1 {
                for c in 0..w - 1 {
                    let (u0, u1, v0, v1) = (t.u_params[c], t.u_params[c + 1], t.v_params[r], t.v_params[r + 1]);
                    let corner = |rr: usize, cc: usize| f64s(t.verts[rr * w + cc].xyz);
                    let (p00, p01, p10, p11) = (corner(r, c), corner(r, c + 1), corner(r + 1, c), corner(r + 1, c + 1));
                    for (a, b) in [(0.5, 0.0), (0.0, 0.5), (0.5, 0.5), (1.0 / 3.0, 1.0 / 3.0), (2.0 / 3.0, 2.0 / 3.0), (0.5, 1.0), (1.0, 0.5), (0.2, 0.7), (0.7, 0.2)] {
                        let truth = patch::surface_point(inp, u0 + a * (u1 - u0), v0 + b * (v1 - v0));
                        // Triangles (p00, p10, p01) and (p01, p10, p11) split along the diagonal.
                        let lin = if a + b <= 1.0 {
                            [0, 1, 2].map(|k| p00[k] + a * (p01[k] - p00[k]) + b * (p10[k] - p00[k]))
                        } else {
                            [0, 1, 2].map(|k| p11[k] + (1.0 - a) * (p10[k] - p11[k]) + (1.0 - b) * (p01[k] - p11[k]))
                        };
                        let d = norm(sub(truth, lin));
                        max_dev = max_dev.max(d);
                        // The converter bounds the deviation on a 5x5 lattice per cell;
                        // between lattice points a quadratic error can exceed it slightly.
                        assert!(d <= 1.1 * tolerance, "{pk3}:{name}: patch deviates {d} units from the true surface");
                    }
                }
            }
        }
    }
    eprintln!("largest patch deviation: {max_dev:.3} units (tolerance {tolerance}); shared boundary vertices: {shared_vertices}");
    assert!(shared_vertices > 1000, "neighbouring patches exist in the test maps: {shared_vertices}");
}

/// The same input gives byte-identical output, as .gltf (all files) and .glb.
#[test]
fn output_is_deterministic() {
    let base = std::env::temp_dir().join(format!("q3gltf-det-{}", std::process::id()));
    let mut outs = Vec::new();
    for run in 0..2 {
        let dir = base.join(format!("run{run}"));
        std::fs::create_dir_all(&dir).unwrap();
        let opts = Options { game_dirs: vec![common::baseoa().to_path_buf()], entity_lights: true, ..Options::default() };
        for ext in ["gltf", "glb"] {
            q3gltf_convert::convert(&q3gltf_convert::MapSource::Name("oa_dm5".into()), &dir.join(format!("m.{ext}")), &opts, &|_| {}).unwrap();
        }
        let mut files: Vec<(String, Vec<u8>)> = Vec::new();
        let mut stack = vec![dir.clone()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    files.push((p.strip_prefix(&dir).unwrap().display().to_string(), std::fs::read(&p).unwrap()));
                }
            }
        }
        files.sort();
        outs.push(files);
    }
    assert!(outs[0].len() > 5);
    assert_eq!(outs[0].len(), outs[1].len());
    for (a, b) in outs[0].iter().zip(&outs[1]) {
        assert_eq!(a.0, b.0);
        assert!(a.1 == b.1, "{} differs between runs", a.0);
    }
    std::fs::remove_dir_all(&base).unwrap();
}
