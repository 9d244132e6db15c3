//! Reading a glTF (`.gltf` or `.glb`) into the flat world-space [`Scene`].
//!
//! Accepts what `q3gltf convert` writes and what Blender exports from it: the lightmap is
//! the material's `occlusionTexture` on TEXCOORD_1; `extras` may be missing (then the
//! defaults of CONVENTIONS.md apply: overbright 2, gamma 1); `KHR_lights_punctual` may be
//! in `extensionsRequired`; node order, transforms and vertex order may have changed. Every
//! node transform of the default scene is applied.

use std::path::Path;

use glam::{DMat3, DMat4, DVec3, Vec2, Vec3};
use serde_json::Value;

use crate::error::{Error, Result};
use crate::scene::{InputLight, Lighting, Material, Mesh, Scene, Texture, Wrap};

/// Default `2^overbright` exponent of q3map2 lightmaps (CONVENTIONS.md).
pub const DEFAULT_OVERBRIGHT_BITS: u32 = 2;
/// Refuse meshes larger than this many vertices or triangles (a corrupt or hostile count).
pub const MAX_ELEMENTS: usize = 50_000_000;
/// Largest world coordinate accepted, meters (f64 still resolves 0.1 mm there).
pub const MAX_COORDINATE: f64 = 1e12;

fn extras_of(raw: &Option<Box<serde_json::value::RawValue>>) -> Value {
    raw.as_ref().and_then(|r| serde_json::from_str(r.get()).ok()).unwrap_or(Value::Null)
}

fn wrap(m: gltf::texture::WrappingMode) -> Wrap {
    match m {
        gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
        gltf::texture::WrappingMode::ClampToEdge => Wrap::Clamp,
        gltf::texture::WrappingMode::MirroredRepeat => Wrap::Mirror,
    }
}

fn to_rgba8(path: &Path, d: &gltf::image::Data) -> Result<Vec<u8>> {
    use gltf::image::Format as F;
    let n = d.width as usize * d.height as usize;
    let px = &d.pixels;
    let out: Vec<u8> = match d.format {
        F::R8G8B8A8 => px.clone(),
        F::R8G8B8 => px.chunks_exact(3).flat_map(|c| [c[0], c[1], c[2], 255]).collect(),
        F::R8G8 => px.chunks_exact(2).flat_map(|c| [c[0], c[0], c[0], c[1]]).collect(),
        F::R8 => px.iter().flat_map(|&c| [c, c, c, 255]).collect(),
        F::R16G16B16A16 => px.chunks_exact(2).map(|c| c[1]).collect(),
        F::R16G16B16 => px.chunks_exact(6).flat_map(|c| [c[1], c[3], c[5], 255]).collect(),
        other => return Err(Error::input(path, format!("unsupported image pixel format {other:?}"))),
    };
    if out.len() != n * 4 {
        return Err(Error::input(path, format!("image of {}x{} has {} bytes", d.width, d.height, px.len())));
    }
    Ok(out)
}

/// Reads the file and flattens the default scene.
pub fn read(path: &Path) -> Result<Scene> {
    let (doc, buffers, images) = gltf::import(path).map_err(|e| Error::input(path, e.to_string()))?;

    let mut textures = Vec::new();
    let mut tex_of_image = Vec::new();
    for img in &images {
        tex_of_image.push(textures.len());
        textures.push(Texture {
            width: img.width,
            height: img.height,
            rgba8: to_rgba8(path, img)?,
            wrap_s: Wrap::Repeat,
            wrap_t: Wrap::Repeat,
        });
    }
    // A glTF texture is an image plus a sampler; give each (image, sampler) pair its own entry.
    let mut texture_index = std::collections::HashMap::new();
    let mut tex_ref = |t: gltf::texture::Texture| -> usize {
        let s = t.sampler();
        let key = (t.source().index(), wrap(s.wrap_s()), wrap(s.wrap_t()));
        *texture_index.entry(key).or_insert_with(|| {
            let base = &textures[tex_of_image[key.0]];
            if base.wrap_s == key.1 && base.wrap_t == key.2 {
                tex_of_image[key.0]
            } else {
                let mut copy = base.clone();
                copy.wrap_s = key.1;
                copy.wrap_t = key.2;
                textures.push(copy);
                textures.len() - 1
            }
        })
    };

    let scene_extras = doc.default_scene().or_else(|| doc.scenes().next()).map(|s| extras_of(s.extras())).unwrap_or(Value::Null);
    let scene_ob = scene_extras.get("q3_overbright_bits").and_then(Value::as_u64).map(|v| v.min(8) as u32);

    let mut materials: Vec<Material> = Vec::new();
    for m in doc.materials() {
        let ex = extras_of(m.extras());
        let name = m.name().unwrap_or("").to_string();
        let pbr = m.pbr_metallic_roughness();
        let albedo = pbr.base_color_texture().filter(|i| i.tex_coord() == 0).map(|i| tex_ref(i.texture()));
        let lightmap = m.occlusion_texture().filter(|o| o.tex_coord() == 1).map(|o| tex_ref(o.texture()));
        let declared = ex.get("q3_lighting").and_then(Value::as_str);
        let lighting = match declared {
            Some("lightmap") if lightmap.is_some() => Lighting::Lightmap,
            Some("vertex") => Lighting::Vertex,
            Some("none") => Lighting::None,
            _ if lightmap.is_some() => Lighting::Lightmap,
            // Blender drops extras unless asked; the material name keeps convert's suffix.
            _ if name.contains("#vertex") => Lighting::Vertex,
            _ => Lighting::None,
        };
        materials.push(Material {
            name,
            albedo,
            albedo_factor: pbr.base_color_factor(),
            lighting,
            lightmap,
            overbright_bits: ex.get("q3_overbright_bits").and_then(Value::as_u64).map(|v| v.min(8) as u32).or(scene_ob).unwrap_or(DEFAULT_OVERBRIGHT_BITS),
            lightmap_gamma: ex.get("q3_lightmap_gamma").and_then(Value::as_f64).filter(|g| g.is_finite() && *g > 0.0).unwrap_or(1.0) as f32,
        });
    }
    let default_material = materials.len();
    materials.push(Material {
        name: "(default)".into(),
        albedo: None,
        albedo_factor: [1.0; 4],
        lighting: Lighting::None,
        lightmap: None,
        overbright_bits: scene_ob.unwrap_or(DEFAULT_OVERBRIGHT_BITS),
        lightmap_gamma: 1.0,
    });

    let mut mesh = Mesh::default();
    let mut lights = Vec::new();
    let mut skipped = Vec::new();
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => doc.nodes().collect(),
    };
    // World positions in f64 until the origin is known (see `Scene::origin`).
    let mut world_pos: Vec<DVec3> = Vec::new();
    let mut stack: Vec<(gltf::Node, DMat4, usize)> = roots.into_iter().map(|n| (n, DMat4::IDENTITY, 0)).collect();
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > 256 {
            return Err(Error::input(path, "node hierarchy deeper than 256 (a cycle?)"));
        }
        let world = parent * DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(f64::from)));
        for c in node.children() {
            stack.push((c, world, depth + 1));
        }
        if let Some(light) = node.light() {
            if let gltf::khr_lights_punctual::Kind::Point = light.kind() {
                let ex = extras_of(node.extras());
                let lex = extras_of(light.extras());
                let locked = ex.get("locked").and_then(Value::as_bool).or_else(|| lex.get("locked").and_then(Value::as_bool)).unwrap_or(false);
                lights.push(InputLight {
                    node: node.index(),
                    name: node.name().or(light.name()).unwrap_or("").to_string(),
                    position: Vec3::ZERO, // made relative to the origin below
                    world_position: world.transform_point3(DVec3::ZERO),
                    color: light.color(),
                    intensity_cd: light.intensity(),
                    locked,
                    parent_world: parent,
                });
            }
        }
        let Some(m) = node.mesh() else { continue };
        let normal_matrix = DMat3::from_mat4(world).inverse().transpose();
        let flip = DMat3::from_mat4(world).determinant() < 0.0;
        for prim in m.primitives() {
            let what = || format!("mesh {:?} primitive {}", m.name().unwrap_or(""), prim.index());
            if prim.mode() != gltf::mesh::Mode::Triangles {
                skipped.push(format!("{}: mode {:?} is not triangles", what(), prim.mode()));
                continue;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos) = reader.read_positions() else {
                skipped.push(format!("{}: no POSITION", what()));
                continue;
            };
            let pos: Vec<Vec3> = pos.map(Vec3::from).collect();
            let n = pos.len();
            if world_pos.len() + n > MAX_ELEMENTS {
                return Err(Error::unsupported(path, format!("more than {MAX_ELEMENTS} vertices")));
            }
            let normals: Option<Vec<Vec3>> = reader.read_normals().map(|it| it.map(Vec3::from).collect());
            let uv0: Option<Vec<Vec2>> = reader.read_tex_coords(0).map(|it| it.into_f32().map(Vec2::from).collect());
            let uv1: Option<Vec<Vec2>> = reader.read_tex_coords(1).map(|it| it.into_f32().map(Vec2::from).collect());
            let colors: Option<Vec<[f32; 3]>> = reader.read_colors(0).map(|it| it.into_rgb_f32().collect());
            let indices: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..n as u32).collect(),
            };
            let len_ok = |k: usize| k == n;
            if !normals.as_ref().map_or(true, |v| len_ok(v.len()))
                || !uv0.as_ref().map_or(true, |v| len_ok(v.len()))
                || !uv1.as_ref().map_or(true, |v| len_ok(v.len()))
                || !colors.as_ref().map_or(true, |v| len_ok(v.len()))
            {
                return Err(Error::input(path, format!("{}: attribute counts differ from POSITION's {n}", what())));
            }
            if let Some(bad) = indices.iter().find(|&&i| i as usize >= n) {
                return Err(Error::input(path, format!("{}: index {bad} out of range (vertex count {n})", what())));
            }
            let mut mat = prim.material().index().unwrap_or(default_material);
            if materials[mat].lighting == Lighting::Lightmap && uv1.is_none() {
                skipped.push(format!("{}: lightmapped material without TEXCOORD_1: no target", what()));
                mat = default_material;
            }
            if materials[mat].lighting == Lighting::Vertex && colors.is_none() {
                skipped.push(format!("{}: vertex-lit material without COLOR_0: no target", what()));
                mat = default_material;
            }
            let base = world_pos.len() as u32;
            for (k, p) in pos.iter().enumerate() {
                let wp = world.transform_point3(p.as_dvec3());
                if !wp.is_finite() || wp.abs().max_element() > MAX_COORDINATE {
                    return Err(Error::input(path, format!("{}: vertex {k} has a non-finite or absurd position ({wp})", what())));
                }
                world_pos.push(wp);
                let nw = normals.as_ref().map(|v| (normal_matrix * v[k].as_dvec3()).normalize_or_zero().as_vec3()).unwrap_or(Vec3::ZERO);
                mesh.normals.push(if nw.is_finite() { nw } else { Vec3::ZERO });
                mesh.uv0.push(uv0.as_ref().map(|v| v[k]).filter(|u| u.is_finite()).unwrap_or(Vec2::ZERO));
                mesh.uv1.push(uv1.as_ref().map(|v| v[k]).filter(|u| u.is_finite()).unwrap_or(Vec2::ZERO));
                mesh.colors.push(colors.as_ref().map(|v| v[k]).unwrap_or([1.0; 3]));
                mesh.v_material.push(mat as u32);
            }
            for t in indices.chunks_exact(3) {
                let tri = if flip { [t[0], t[2], t[1]] } else { [t[0], t[1], t[2]] };
                mesh.tri_source.push(mesh.triangles.len() as u32);
                mesh.triangles.push(tri.map(|i| base + i));
                mesh.tri_material.push(mat as u32);
            }
        }
    }
    if mesh.triangles.is_empty() {
        return Err(Error::unsupported(path, "the scene has no triangles"));
    }
    let (lo, hi) = world_pos.iter().fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    let origin = ((lo + hi) * 0.5).round();
    mesh.positions = world_pos.iter().map(|p| (*p - origin).as_vec3()).collect();
    for l in &mut lights {
        l.position = (l.world_position - origin).as_vec3();
    }
    repair_normals(&mut mesh);
    mesh.reweld();
    lights.sort_by_key(|l| l.node);
    Ok(Scene { mesh, materials, textures, lights, origin, skipped })
}

/// Vertices without a usable normal get the area-weighted normal of their triangles.
fn repair_normals(mesh: &mut Mesh) {
    let mut acc = vec![Vec3::ZERO; mesh.positions.len()];
    let mut need = false;
    for tri in &mesh.triangles {
        let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
        let n = (b - a).cross(c - a);
        for &v in tri {
            if mesh.normals[v as usize] == Vec3::ZERO {
                acc[v as usize] += n;
                need = true;
            }
        }
    }
    if need {
        for (n, a) in mesh.normals.iter_mut().zip(acc) {
            if *n == Vec3::ZERO {
                *n = a.normalize_or(Vec3::Y);
            }
        }
    }
}
