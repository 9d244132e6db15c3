//! The bundled sample map, generated from code: two rooms joined by a doorway, pillars,
//! a curved arch (a Bezier patch) and a vertex-lit panel, lit by known point lights.
//!
//! Its lightmaps are baked here with q3map2's point-light formula (CONVENTIONS.md):
//! `byte = light * 7500 * cos(theta) / max(16, d)^2` per light (d in Quake units),
//! summed, with hard shadows (a ray to each light against every triangle), then scaled
//! down keeping hue where a channel would exceed 255. The lights are recorded as `light`
//! entities, so the sample is a ground truth for relighting.
//!
//! Luxels follow q3map2's layout (`lightmaps_ydnar`): a face `len` units long gets
//! `ceil(len / 16) + 1` luxels, luxel `i` samples the point `i` steps from the face's
//! corner, and a vertex's lightmap coordinate is `(step + 0.5) / 128`: vertices sit on
//! luxel centres, so bilinear filtering never reads outside the face's block.
//!
//! Everything is deterministic: the same code gives byte-identical files.

use glam::DVec3;
use q3gltf_convert::bsp::{Bsp, DrawVert, Format, Model, OtherCounts, ShaderRef, Surface, SurfaceType, LIGHTMAP_SIZE};
use q3gltf_convert::patch;
use rayon::prelude::*;

/// A point light of the sample, in q3map2 terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleLight {
    /// Quake units.
    pub origin: [f64; 3],
    /// q3map2 `light` key.
    pub light: f64,
    /// `_color`, max channel 1.
    pub color: [f64; 3],
}

/// The lights of the sample.
pub const LIGHTS: [SampleLight; 3] = [
    SampleLight { origin: [256.0, 192.0, 200.0], light: 400.0, color: [1.0, 0.9, 0.75] },
    SampleLight { origin: [768.0, 128.0, 160.0], light: 300.0, color: [0.6, 0.75, 1.0] },
    SampleLight { origin: [860.0, 320.0, 96.0], light: 150.0, color: [1.0, 0.5, 0.3] },
];

/// Size of a lightmap texel (q3map2 `-samplesize`), Quake units.
pub const LUXEL: f64 = 16.0;

/// Generated files, relative to the sample's game directory.
pub struct Sample {
    pub bsp: Bsp,
    pub files: Vec<(String, Vec<u8>)>,
}

struct Quad {
    /// Corner and edge vectors: the face is origin + a*u + b*v, a, b in [0, 1];
    /// u x v points to the front.
    origin: DVec3,
    u: DVec3,
    v: DVec3,
    shader: u32,
    vertex_lit: bool,
}

const SHADERS: [&str; 5] = [
    "textures/sample/wall",
    "textures/sample/floor",
    "textures/sample/pillar",
    "textures/sample/arch",
    "textures/sample/panel",
];

/// Quads of a box seen from inside (room) or outside (pillar); without top and bottom
/// when `caps` is false.
fn box_quads(min: DVec3, max: DVec3, inside: bool, caps: bool, wall: u32, floor: u32, out: &mut Vec<Quad>) {
    let d = max - min;
    let (x, y, z) = (DVec3::X * d.x, DVec3::Y * d.y, DVec3::Z * d.z);
    // Outward-facing quads: (origin, u, v) with u x v outward.
    let faces = [
        (min, y, x, floor, true),    // bottom (-Z)
        (min + z, x, y, floor, true), // top (+Z)
        (min, x, z, wall, false),    // -Y
        (min + y, z, x, wall, false), // +Y
        (min, z, y, wall, false),    // -X
        (min + x, y, z, wall, false), // +X
    ];
    for (o, u, v, sh, cap) in faces {
        if cap && !caps {
            continue;
        }
        let (u, v) = if inside { (v, u) } else { (u, v) };
        out.push(Quad { origin: o, u, v, shader: sh, vertex_lit: false });
    }
}

/// Splits a wall in the plane x = const around a doorway y in [y0, y1], z in [0, top].
fn cut_door(q: Quad, y0: f64, y1: f64, top: f64) -> Vec<Quad> {
    let (ymin, zmin) = (q.origin.y.min(q.origin.y + q.u.y + q.v.y), q.origin.z.min(q.origin.z + q.u.z + q.v.z));
    let (ymax, zmax) = (q.origin.y.max(q.origin.y + q.u.y + q.v.y), q.origin.z.max(q.origin.z + q.u.z + q.v.z));
    // Pieces as (y range, z range); each keeps the wall's orientation.
    let pieces = [((ymin, y0), (zmin, zmax)), ((y1, ymax), (zmin, zmax)), ((y0, y1), (top, zmax))];
    let mut out = Vec::new();
    for ((ya, yb), (za, zb)) in pieces {
        if yb - ya <= 0.0 || zb - za <= 0.0 {
            continue;
        }
        // Map the piece's corner and extents onto the wall's own u, v directions.
        let along = |w: DVec3| if w.y != 0.0 { DVec3::Y * (yb - ya) * w.y.signum() } else { DVec3::Z * (zb - za) * w.z.signum() };
        let (u, v) = (along(q.u), along(q.v));
        let start = |w: DVec3, lo: DVec3| if w.y < 0.0 || w.z < 0.0 { lo - w } else { lo };
        let lo = DVec3::new(q.origin.x, ya, za);
        let origin = start(v, start(u, lo));
        out.push(Quad { origin, u, v, shader: q.shader, vertex_lit: q.vertex_lit });
    }
    out
}

/// Triangles used for shadow rays.
struct Occluders {
    tris: Vec<[DVec3; 3]>,
}

impl Occluders {
    /// True if the segment from `a` to `b` hits a triangle (Moller-Trumbore).
    fn blocked(&self, a: DVec3, b: DVec3) -> bool {
        let dir = b - a;
        self.tris.iter().any(|t| {
            let e1 = t[1] - t[0];
            let e2 = t[2] - t[0];
            let p = dir.cross(e2);
            let det = e1.dot(p);
            if det.abs() < 1e-12 {
                return false;
            }
            let inv = 1.0 / det;
            let s = a - t[0];
            let uu = s.dot(p) * inv;
            if !(0.0..=1.0).contains(&uu) {
                return false;
            }
            let q = s.cross(e1);
            let vv = dir.dot(q) * inv;
            if vv < 0.0 || uu + vv > 1.0 {
                return false;
            }
            let t = e2.dot(q) * inv;
            t > 1e-6 && t < 1.0 - 1e-6
        })
    }
}

/// q3map2's point-light sum at a surface point, as RGB bytes before clamping.
pub fn irradiance_bytes(p: DVec3, n: DVec3, lights: &[SampleLight], occ: Option<&dyn Fn(DVec3, DVec3) -> bool>) -> [f64; 3] {
    let mut sum = [0.0; 3];
    for l in lights {
        let lo = DVec3::from_array(l.origin);
        let to = lo - p;
        let d = to.length();
        if d <= 0.0 {
            continue;
        }
        let cos = n.dot(to / d);
        if cos <= 0.0 {
            continue;
        }
        if let Some(blocked) = occ {
            if blocked(p + n * 0.125, lo) {
                continue;
            }
        }
        let v = l.light * 7500.0 * cos / d.max(16.0).powi(2);
        for k in 0..3 {
            sum[k] += v * l.color[k];
        }
    }
    sum
}

/// Bytes as q3map2 stores them: rounded, and scaled down keeping hue when a channel
/// exceeds 255.
pub fn clamp_bytes(c: [f64; 3]) -> [u8; 3] {
    let max = c.iter().copied().fold(0.0, f64::max);
    let s = if max > 255.0 { 255.0 / max } else { 1.0 };
    c.map(|x| (x * s).round().clamp(0.0, 255.0) as u8)
}

/// Rectangle allocator over 128x128 pages (shelf packing, 1 texel gap).
struct Pages {
    pages: Vec<Vec<u8>>,
    x: usize,
    y: usize,
    shelf: usize,
}

impl Pages {
    /// Copies a `w`-wide block of texels to (px, py) of a page.
    fn blit(&mut self, page: usize, px: usize, py: usize, w: usize, texels: &[[u8; 3]]) {
        for (k, t) in texels.iter().enumerate() {
            let (i, j) = (k % w, k / w);
            let o = ((py + j) * LIGHTMAP_SIZE + px + i) * 3;
            self.pages[page][o..o + 3].copy_from_slice(t);
        }
    }

    fn alloc(&mut self, w: usize, h: usize) -> (usize, usize, usize) {
        assert!(w < LIGHTMAP_SIZE && h < LIGHTMAP_SIZE);
        if self.pages.is_empty() || self.x + w > LIGHTMAP_SIZE {
            self.x = 0;
            self.y += self.shelf + 1;
            self.shelf = 0;
        }
        if self.pages.is_empty() || self.y + h > LIGHTMAP_SIZE {
            self.pages.push(vec![0u8; LIGHTMAP_SIZE * LIGHTMAP_SIZE * 3]);
            self.x = 0;
            self.y = 0;
            self.shelf = 0;
        }
        let r = (self.pages.len() - 1, self.x, self.y);
        self.x += w + 1;
        self.shelf = self.shelf.max(h);
        r
    }
}

fn texture(kind: usize) -> Vec<u8> {
    let img = image::RgbImage::from_fn(64, 64, |x, y| {
        let c: [u8; 3] = match kind {
            0 => {
                // bricks
                let row = y / 16;
                let off = if row % 2 == 0 { 0 } else { 16 };
                let mortar = y % 16 == 0 || (x + off) % 32 == 0;
                if mortar { [150, 150, 145] } else { [170, 90 + (x * 7 % 13) as u8, 70] }
            }
            1 => {
                if (x / 16 + y / 16) % 2 == 0 { [200, 200, 190] } else { [90, 95, 100] }
            }
            2 => {
                if (x / 8) % 2 == 0 { [220, 220, 220] } else { [120, 140, 170] }
            }
            3 => [(100 + x * 2) as u8, (100 + y * 2) as u8, 160],
            _ => [230, 230, 80],
        };
        image::Rgb(c)
    });
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Tga).expect("TGA encoding of a small image");
    out
}

const SHADER_SCRIPT: &str = "// Shaders of the q3gltf sample map (generated by samples/src/lib.rs).
textures/sample/wall
{
\t{
\t\tmap $lightmap
\t}
\t{
\t\tmap textures/sample/wall.tga
\t\tblendFunc filter
\t}
}

textures/sample/panel
{
\tcull none
\tsurfaceparm nolightmap
\t{
\t\tmap textures/sample/panel.tga
\t\trgbGen vertex
\t}
}
";

/// Generates the sample map.
pub fn generate() -> Sample {
    // Geometry, Quake units: room A [0,512]x[0,384]x[0,256] and room B
    // [576,1024]x[0,448]x[0,224], joined by a corridor [512,576]x[128,256]x[0,160]
    // through doorways in both walls; three pillars from floor to ceiling.
    let mut quads = Vec::new();
    box_quads(DVec3::new(0.0, 0.0, 0.0), DVec3::new(512.0, 384.0, 256.0), true, true, 0, 1, &mut quads);
    box_quads(DVec3::new(576.0, 0.0, 0.0), DVec3::new(1024.0, 448.0, 224.0), true, true, 0, 1, &mut quads);
    box_quads(DVec3::new(512.0, 128.0, 0.0), DVec3::new(576.0, 256.0, 160.0), true, true, 0, 1, &mut quads);
    let is_wall_at = |q: &Quad, x: f64| q.u.x == 0.0 && q.v.x == 0.0 && q.origin.x == x;
    let mut walls = Vec::new();
    for q in quads {
        let corridor = q.origin.y >= 128.0 && q.origin.y + q.u.y + q.v.y <= 256.0 && q.origin.z + q.u.z + q.v.z <= 160.0;
        if (is_wall_at(&q, 512.0) || is_wall_at(&q, 576.0)) && corridor {
            continue; // the corridor's open ends
        }
        if is_wall_at(&q, 512.0) || is_wall_at(&q, 576.0) {
            walls.extend(cut_door(q, 128.0, 256.0, 160.0));
        } else {
            walls.push(q);
        }
    }
    let mut quads = walls;
    for (x, y) in [(160.0, 128.0), (352.0, 256.0), (800.0, 224.0)] {
        box_quads(DVec3::new(x, y, 0.0), DVec3::new(x + 32.0, y + 32.0, 224.0), false, false, 2, 2, &mut quads);
    }
    // A vertex-lit panel standing in room B.
    quads.push(Quad {
        origin: DVec3::new(700.0, 400.0, 32.0),
        u: DVec3::new(96.0, 0.0, 0.0),
        v: DVec3::new(0.0, 0.0, 96.0),
        shader: 4,
        vertex_lit: true,
    });

    // The arch: a 3x5 patch over the corridor entrance in room A, bulging into the room.
    let arch_ctrl: Vec<DVec3> = {
        let mut c = Vec::new();
        for row in 0..3 {
            let x = 500.0 - [0.0, 40.0, 0.0][row];
            let z = 160.0 + 48.0 * row as f64;
            for col in 0..5 {
                let y = 128.0 + 32.0 * col as f64;
                let bulge = [0.0, 24.0, 32.0, 24.0, 0.0][col];
                c.push(DVec3::new(x - bulge * (row == 1) as i32 as f64, y, z));
            }
        }
        c
    };

    // Occluders: every quad as two triangles and the arch finely tessellated.
    let mut tris = Vec::new();
    for q in &quads {
        let (a, b, c, d) = (q.origin, q.origin + q.u, q.origin + q.u + q.v, q.origin + q.v);
        tris.push([a, b, c]);
        tris.push([a, c, d]);
    }
    let arch_verts: Vec<DrawVert> = arch_ctrl.iter().map(|p| DrawVert { xyz: p.as_vec3().to_array(), normal: [1.0, 0.0, 0.0], ..Default::default() }).collect();
    let arch_input = patch::PatchInput { width: 5, height: 3, ctrl: &arch_verts };
    {
        let n = 16;
        for i in 0..n {
            for j in 0..n {
                let p = |a: usize, b: usize| DVec3::from_array(patch::surface_point(&arch_input, 2.0 * a as f64 / n as f64, b as f64 / n as f64));
                tris.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
                tris.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
            }
        }
    }
    let occ = Occluders { tris };
    let blocked = |a: DVec3, b: DVec3| occ.blocked(a, b);

    let mut pages = Pages { pages: Vec::new(), x: 0, y: 0, shelf: 0 };
    let mut verts: Vec<DrawVert> = Vec::new();
    let mut indices: Vec<u32> = Vec::new();
    let mut surfaces: Vec<Surface> = Vec::new();

    for q in &quads {
        let n = q.u.cross(q.v).normalize();
        // Luxel counts along u and v (q3map2: ceil(len / samplesize) + 1; our faces are
        // multiples of 16 units, so luxels are exactly LUXEL apart).
        let (w, h) = ((q.u.length() / LUXEL).ceil() as usize + 1, (q.v.length() / LUXEL).ceil() as usize + 1);
        let mut s = Surface::new(q.shader, SurfaceType::Polygon);
        s.first_vert = verts.len() as u32;
        s.num_verts = 4;
        s.first_index = indices.len() as u32;
        s.num_indexes = 6;
        // Corners (a, b) in [0, 1]^2, clockwise seen from the front: 0, v, u+v, u.
        let corners = [(0.0, 0.0), (0.0, 1.0), (1.0, 1.0), (1.0, 0.0)];
        let (page, px, py) = if q.vertex_lit { (usize::MAX, 0, 0) } else { pages.alloc(w, h) };
        for (a, b) in corners {
            let p = q.origin + q.u * a + q.v * b;
            let st = if n.z.abs() > 0.5 { [p.x / 64.0, -p.y / 64.0] } else if n.x.abs() > 0.5 { [p.y / 64.0, -p.z / 64.0] } else { [p.x / 64.0, -p.z / 64.0] };
            let color = if q.vertex_lit { clamp_bytes(irradiance_bytes(p, n, &LIGHTS, Some(&blocked))) } else { [255; 3] };
            verts.push(DrawVert {
                xyz: p.as_vec3().to_array(),
                st: [st[0] as f32, st[1] as f32],
                lightmap: [((px as f64 + 0.5 + a * (w - 1) as f64) / LIGHTMAP_SIZE as f64) as f32, ((py as f64 + 0.5 + b * (h - 1) as f64) / LIGHTMAP_SIZE as f64) as f32],
                normal: n.as_vec3().to_array(),
                color: [color[0], color[1], color[2], 255],
            });
        }
        indices.extend_from_slice(&[0, 1, 2, 0, 2, 3]);
        if q.vertex_lit {
            s.lightmap = -3;
        } else {
            s.lightmap = page as i32;
            (s.lightmap_x, s.lightmap_y, s.lightmap_w, s.lightmap_h) = (px as i32, py as i32, w as i32, h as i32);
            s.lightmap_origin = q.origin.as_vec3().to_array();
            s.lightmap_vecs = [(q.u / (w - 1) as f64).as_vec3().to_array(), (q.v / (h - 1) as f64).as_vec3().to_array(), n.as_vec3().to_array()];
            // Bake: luxel (i, j) samples origin + i/(w-1) u + j/(h-1) v.
            let texels: Vec<[u8; 3]> = (0..w * h)
                .into_par_iter()
                .map(|k| {
                    let (i, j) = (k % w, k / w);
                    let p = q.origin + q.u * (i as f64 / (w - 1) as f64) + q.v * (j as f64 / (h - 1) as f64);
                    clamp_bytes(irradiance_bytes(p, n, &LIGHTS, Some(&blocked)))
                })
                .collect();
            pages.blit(page, px, py, w, &texels);
        }
        surfaces.push(s);
    }

    // The arch patch: lightmap coordinates linear in the patch parameters.
    {
        // q3map2 patch layout: luxels spread evenly over the patch parameters, control
        // rows and columns on luxel centres.
        let (w, h) = (17usize, 9usize);
        let (page, px, py) = pages.alloc(w, h);
        let mut s = Surface::new(3, SurfaceType::Patch);
        s.first_vert = verts.len() as u32;
        s.num_verts = 15;
        s.patch_w = 5;
        s.patch_h = 3;
        s.lightmap = page as i32;
        (s.lightmap_x, s.lightmap_y, s.lightmap_w, s.lightmap_h) = (px as i32, py as i32, w as i32, h as i32);
        let normal_at = |u: f64, v: f64| -> DVec3 {
            let su = (u.floor() as usize).min(1);
            let du = DVec3::from_array(patch::derivative(&arch_input, su, u - su as f64, 0, v, 0));
            let dv = DVec3::from_array(patch::derivative(&arch_input, su, u - su as f64, 0, v, 1));
            // Clockwise fronts: the front normal is dv x du (see patch::surface_normal).
            dv.cross(du).normalize_or_zero()
        };
        for row in 0..3 {
            for col in 0..5 {
                let p = arch_ctrl[row * 5 + col];
                let (a, b) = (col as f64 / 4.0, row as f64 / 2.0);
                let n = normal_at(2.0 * a, b);
                verts.push(DrawVert {
                    xyz: p.as_vec3().to_array(),
                    st: [(p.y / 64.0) as f32, (-p.z / 64.0) as f32],
                    lightmap: [((px as f64 + 0.5 + a * (w - 1) as f64) / LIGHTMAP_SIZE as f64) as f32, ((py as f64 + 0.5 + b * (h - 1) as f64) / LIGHTMAP_SIZE as f64) as f32],
                    normal: n.as_vec3().to_array(),
                    color: [255; 4],
                });
            }
        }
        let texels: Vec<[u8; 3]> = (0..w * h)
            .into_par_iter()
            .map(|k| {
                let (i, j) = (k % w, k / w);
                let (u, v) = (2.0 * i as f64 / (w - 1) as f64, j as f64 / (h - 1) as f64);
                let p = DVec3::from_array(patch::surface_point(&arch_input, u, v));
                clamp_bytes(irradiance_bytes(p, normal_at(u, v), &LIGHTS, Some(&blocked)))
            })
            .collect();
        pages.blit(page, px, py, w, &texels);
        surfaces.push(s);
    }

    let mut entities = String::from("{\n\"classname\" \"worldspawn\"\n\"message\" \"q3gltf sample\"\n}\n");
    for l in &LIGHTS {
        entities.push_str(&format!(
            "{{\n\"classname\" \"light\"\n\"origin\" \"{} {} {}\"\n\"light\" \"{}\"\n\"_color\" \"{} {} {}\"\n}}\n",
            l.origin[0], l.origin[1], l.origin[2], l.light, l.color[0], l.color[1], l.color[2]
        ));
    }
    entities.push_str("{\n\"classname\" \"info_player_deathmatch\"\n\"origin\" \"64 64 40\"\n\"angle\" \"45\"\n}\n");

    let bsp = Bsp {
        format: Format::Ibsp(46),
        entities,
        shaders: SHADERS.iter().map(|n| ShaderRef { name: n.to_string(), surface_flags: 0, content_flags: 1 }).collect(),
        models: vec![Model {
            mins: [0.0, 0.0, 0.0],
            maxs: [1024.0, 448.0, 256.0],
            first_surface: 0,
            num_surfaces: surfaces.len() as u32,
            first_brush: 0,
            num_brushes: 0,
        }],
        verts,
        indices,
        surfaces,
        lightmaps: pages.pages,
        collision: Default::default(),
            other: OtherCounts::default(),
    };
    let mut files = vec![("maps/sample.bsp".to_string(), bsp.to_bytes()), ("scripts/sample.shader".to_string(), SHADER_SCRIPT.as_bytes().to_vec())];
    for (k, name) in ["wall", "floor", "pillar", "arch", "panel"].iter().enumerate() {
        files.push((format!("textures/sample/{name}.tga"), texture(k)));
    }
    Sample { bsp, files }
}
