//! BSP file format: IBSP 46 (Quake III, OpenArena), IBSP 47 (RTCW, ET, Quake Live) and
//! Raven's RBSP 1 (JK2, JKA, SoF2; lightmap style 0 only).
//!
//! [`Bsp::parse`] turns untrusted bytes into owned, validated records. Every lump's offset
//! and length are checked against the file before anything is read, element counts come
//! from lump lengths (never from a field inside the file), and every cross reference that
//! the converter follows (surface to vertices, indices, shader; model to surfaces; patch
//! grid sizes) is checked here, so later stages index without further checks.
//!
//! [`Bsp::to_bytes`] writes the same records back as an IBSP 46 or RBSP 1 file. The
//! sample generator and the bad-input tests use it; lumps we do not model are written
//! empty.

use std::fmt;

/// Errors from reading a BSP file. The caller adds the file name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BspError {
    #[error("file is {0} bytes, too short for a BSP header")]
    TooShort(usize),
    #[error("not a Quake III BSP file (magic {0:?}, expected \"IBSP\" or \"RBSP\")")]
    BadMagic(String),
    #[error("unsupported BSP version {version} for {magic} (supported: IBSP 46, IBSP 47, RBSP 1)")]
    UnsupportedVersion { magic: String, version: i32 },
    #[error("lump {lump} ({name}) at offset {offset} with length {length} lies outside the {file_len}-byte file")]
    LumpOutOfFile { lump: usize, name: &'static str, offset: i64, length: i64, file_len: usize },
    #[error("lump {lump} ({name}) has length {length}, not a multiple of its {elem}-byte records")]
    LumpSize { lump: usize, name: &'static str, length: usize, elem: usize },
    #[error("{0}")]
    Invalid(String),
}

/// Which dialect of the format a file uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// `IBSP` with the given version (46 or 47).
    Ibsp(i32),
    /// Raven `RBSP` version 1.
    Rbsp,
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Format::Ibsp(v) => write!(f, "IBSP {v}"),
            Format::Rbsp => write!(f, "RBSP 1"),
        }
    }
}

/// Lump indices of the Quake III layout (RBSP adds lump 17, the light array).
pub mod lump {
    pub const ENTITIES: usize = 0;
    pub const SHADERS: usize = 1;
    pub const PLANES: usize = 2;
    pub const NODES: usize = 3;
    pub const LEAFS: usize = 4;
    pub const LEAF_SURFACES: usize = 5;
    pub const LEAF_BRUSHES: usize = 6;
    pub const MODELS: usize = 7;
    pub const BRUSHES: usize = 8;
    pub const BRUSH_SIDES: usize = 9;
    pub const DRAW_VERTS: usize = 10;
    pub const DRAW_INDEXES: usize = 11;
    pub const FOGS: usize = 12;
    pub const SURFACES: usize = 13;
    pub const LIGHTMAPS: usize = 14;
    pub const LIGHT_GRID: usize = 15;
    pub const VISIBILITY: usize = 16;
    pub const NAMES: [&str; 17] = [
        "entities", "shaders", "planes", "nodes", "leafs", "leaf surfaces", "leaf brushes",
        "models", "brushes", "brush sides", "draw vertices", "draw indexes", "fogs",
        "surfaces", "lightmaps", "light grid", "visibility",
    ];
}

/// Side of one lightmap page stored in lump 14, in texels.
pub const LIGHTMAP_SIZE: usize = 128;
/// Bytes of one RGB lightmap page in lump 14.
pub const LIGHTMAP_BYTES: usize = LIGHTMAP_SIZE * LIGHTMAP_SIZE * 3;

/// Surface flags (`surfaceFlags` of a shader record) that the converter reads.
pub mod surf {
    pub const SKY: i32 = 0x4;
    pub const LIGHTFILTER: i32 = 0x8000;
    pub const ALPHASHADOW: i32 = 0x10000;
    pub const NODRAW: i32 = 0x80;
    pub const HINT: i32 = 0x100;
    pub const SKIP: i32 = 0x200;
}
/// Content flags (`contentFlags` of a shader record) that the converter reads.
pub mod contents {
    pub const LAVA: i32 = 0x8;
    pub const SLIME: i32 = 0x10;
    pub const WATER: i32 = 0x20;
    pub const FOG: i32 = 0x40;
    pub const AREAPORTAL: i32 = 0x8000;
    pub const PLAYERCLIP: i32 = 0x10000;
    pub const MONSTERCLIP: i32 = 0x20000;
    pub const CLUSTERPORTAL: i32 = 0x10_0000;
    pub const DONOTENTER: i32 = 0x20_0000;
    pub const BOTCLIP: i32 = 0x40_0000;
    pub const ORIGIN: i32 = 0x100_0000;
    pub const TRANSLUCENT: i32 = 0x2000_0000;
    pub const TRIGGER: i32 = 0x4000_0000;
    pub const NODROP: i32 = 0x8000_0000_u32 as i32;
}

/// Surface types of the surface lump.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SurfaceType {
    /// Planar polygon, triangulated through the index lump.
    Polygon,
    /// Grid of biquadratic Bezier patches (control points in the vertex lump).
    Patch,
    /// Triangle soup (models baked into the map), indexed like polygons.
    Mesh,
    /// Light flare: a point, nothing to draw.
    Flare,
    /// Any other value (kept so counts add up; never drawn).
    Other(i32),
}

impl SurfaceType {
    pub fn from_raw(v: i32) -> Self {
        match v {
            1 => SurfaceType::Polygon,
            2 => SurfaceType::Patch,
            3 => SurfaceType::Mesh,
            4 => SurfaceType::Flare,
            x => SurfaceType::Other(x),
        }
    }
    pub fn to_raw(self) -> i32 {
        match self {
            SurfaceType::Polygon => 1,
            SurfaceType::Patch => 2,
            SurfaceType::Mesh => 3,
            SurfaceType::Flare => 4,
            SurfaceType::Other(x) => x,
        }
    }
}

/// One shader record of lump 1 (the map's "textures").
#[derive(Debug, Clone, PartialEq)]
pub struct ShaderRef {
    /// Shader or texture name without extension, e.g. `textures/base_wall/concrete`.
    pub name: String,
    pub surface_flags: i32,
    pub content_flags: i32,
}

/// One model record of lump 7: model 0 is the world, the others are brush entities.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// Bounds in Quake units.
    pub mins: [f32; 3],
    pub maxs: [f32; 3],
    pub first_surface: u32,
    pub num_surfaces: u32,
    pub first_brush: i32,
    pub num_brushes: i32,
}

/// One vertex of the draw-vertex lump (lightmap style 0 for RBSP).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DrawVert {
    /// Position in Quake units (Z up).
    pub xyz: [f32; 3],
    /// Texture coordinates (s right, t down).
    pub st: [f32; 2],
    /// Lightmap coordinates within the surface's lightmap page, in [0, 1].
    pub lightmap: [f32; 2],
    pub normal: [f32; 3],
    /// RGBA bytes: q3map2's vertex lighting (or lightmap average) and alpha.
    pub color: [u8; 4],
}

/// One record of the surface lump (lightmap style 0 for RBSP).
#[derive(Debug, Clone, PartialEq)]
pub struct Surface {
    /// Index into [`Bsp::shaders`] (checked).
    pub shader: u32,
    pub fog: i32,
    pub kind: SurfaceType,
    /// Range into [`Bsp::verts`] (checked for drawable types).
    pub first_vert: u32,
    pub num_verts: u32,
    /// Range into [`Bsp::indices`] (checked for polygons and meshes).
    pub first_index: u32,
    pub num_indexes: u32,
    /// Lightmap page (>= 0), or -1 none, -3 vertex lit (see CONVENTIONS.md).
    pub lightmap: i32,
    pub lightmap_x: i32,
    pub lightmap_y: i32,
    pub lightmap_w: i32,
    pub lightmap_h: i32,
    pub lightmap_origin: [f32; 3],
    pub lightmap_vecs: [[f32; 3]; 3],
    /// Patch control grid size (odd, >= 3, width * height = num_verts, checked).
    pub patch_w: u32,
    pub patch_h: u32,
}

impl Surface {
    /// A surface of the given shader and type with empty ranges and no lightmap.
    pub fn new(shader: u32, kind: SurfaceType) -> Self {
        Surface {
            shader,
            fog: -1,
            kind,
            first_vert: 0,
            num_verts: 0,
            first_index: 0,
            num_indexes: 0,
            lightmap: -1,
            lightmap_x: 0,
            lightmap_y: 0,
            lightmap_w: 0,
            lightmap_h: 0,
            lightmap_origin: [0.0; 3],
            lightmap_vecs: [[0.0; 3]; 3],
            patch_w: 0,
            patch_h: 0,
        }
    }
}

/// Number of records in the lumps that the converter does not model, for `info`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OtherCounts {
    pub planes: usize,
    pub nodes: usize,
    pub leafs: usize,
    pub brushes: usize,
    pub fogs: usize,
    pub light_grid_bytes: usize,
    pub visibility_bytes: usize,
}

/// One node of lump 3: a splitting plane and its two children.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Node {
    /// Index into [`Collision::planes`] (checked).
    pub plane: u32,
    /// Front and back child: `>= 0` a node (always after this one), `< 0` the leaf `-(c + 1)`
    /// (checked).
    pub children: [i32; 2],
}

/// One leaf of lump 4, as far as the solid structure needs it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Leaf {
    /// PVS cluster; `-1` marks a leaf inside structural solid.
    pub cluster: i32,
    /// Range into [`Collision::leaf_brushes`] (checked).
    pub first_brush: u32,
    pub num_brushes: u32,
}

/// One brush of lump 8.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Brush {
    /// Range into [`Collision::brush_sides`] (checked).
    pub first_side: u32,
    pub num_sides: u32,
    /// Index into [`Bsp::shaders`] (checked): the brush's content shader.
    pub shader: u32,
}

/// One brush side of lump 9.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BrushSide {
    /// Index into [`Collision::planes`] (checked); the plane's normal points out of the brush.
    pub plane: u32,
    /// Index into [`Bsp::shaders`] (checked).
    pub shader: u32,
}

/// The solid structure of the map (lumps 2, 3, 4, 6, 8 and 9): the tree of planes down to
/// leaves, each leaf's cluster and brushes, the brushes' sides. Nothing of it is drawn;
/// q3map2 asked it whether a lightmap's sample point lay in solid, and relight asks it the
/// same (see `solids`). Empty when the file has none; a file whose structure does not
/// check out keeps its geometry and has this empty with [`Collision::error`] saying why.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Collision {
    /// Plane normals (unit) and distances, Quake units: `normal . p = dist` on the plane.
    pub planes: Vec<([f32; 3], f32)>,
    /// Node 0 is the root of the world's tree.
    pub nodes: Vec<Node>,
    pub leafs: Vec<Leaf>,
    /// Indexes into [`Collision::brushes`] (checked).
    pub leaf_brushes: Vec<u32>,
    pub brushes: Vec<Brush>,
    pub brush_sides: Vec<BrushSide>,
    /// Why the structure was dropped, when it was.
    pub error: Option<String>,
}

impl Collision {
    /// Reads and checks the solid structure from its lumps (see [`Collision`]).
    fn parse(lumps: &[&[u8]; 17], num_shaders: usize, rbsp: bool) -> Result<Collision, String> {
        let records = |i: usize, elem: usize| -> Result<std::slice::ChunksExact<'_, u8>, String> {
            let l = lumps[i];
            if l.len() % elem != 0 {
                return Err(format!("lump {i} ({}) has length {}, not a multiple of its {elem}-byte records", lump::NAMES[i], l.len()));
            }
            Ok(l.chunks_exact(elem))
        };
        let planes: Vec<([f32; 3], f32)> = records(lump::PLANES, 16)?
            .map(|r| {
                let mut rec = Rec::new(r);
                (rec.vec3(), rec.f32())
            })
            .collect();
        let nodes_raw: Vec<[i32; 3]> = records(lump::NODES, 36)?
            .map(|r| {
                let mut rec = Rec::new(r);
                [rec.i32(), rec.i32(), rec.i32()]
            })
            .collect();
        let leafs_raw: Vec<[i32; 3]> = records(lump::LEAFS, 48)?
            .map(|r| {
                let mut rec = Rec::new(r);
                let cluster = rec.i32();
                rec.skip(4 * 9); // area, bounds, leaf surfaces
                [cluster, rec.i32(), rec.i32()]
            })
            .collect();
        let leaf_brushes_raw: Vec<i32> = records(lump::LEAF_BRUSHES, 4)?.map(|r| Rec::new(r).i32()).collect();
        let brushes_raw: Vec<[i32; 3]> = records(lump::BRUSHES, 12)?
            .map(|r| {
                let mut rec = Rec::new(r);
                [rec.i32(), rec.i32(), rec.i32()]
            })
            .collect();
        let sides_raw: Vec<[i32; 2]> = records(lump::BRUSH_SIDES, if rbsp { 12 } else { 8 })?
            .map(|r| {
                let mut rec = Rec::new(r);
                [rec.i32(), rec.i32()]
            })
            .collect();
        let index = |x: i32, len: usize, what: &str, of: String| -> Result<u32, String> {
            if x < 0 || x as usize >= len {
                return Err(format!("{of}: {what} {x} outside the {len} present"));
            }
            Ok(x as u32)
        };
        let range = |first: i32, n: i32, len: usize, what: &str, of: String| -> Result<(u32, u32), String> {
            if first < 0 || n < 0 || first as u64 + n as u64 > len as u64 {
                return Err(format!("{of}: {what} {first}+{n} outside the {len} present"));
            }
            Ok((first as u32, n as u32))
        };
        if let Some((i, _)) = planes.iter().enumerate().find(|(_, (n, d))| !n.iter().chain([d]).all(|x| x.is_finite())) {
            return Err(format!("plane {i} is not finite"));
        }
        let num_nodes = nodes_raw.len();
        let mut nodes = Vec::with_capacity(num_nodes);
        for (i, [p, a, b]) in nodes_raw.into_iter().enumerate() {
            let plane = index(p, planes.len(), "plane", format!("node {i}"))?;
            for c in [a, b] {
                // Children come after their parent (q3map2 and q3bsp write the tree in
                // pre-order), which also rules out cycles.
                let ok = if c >= 0 { c as usize > i && (c as usize) < num_nodes } else { ((-(c as i64) - 1) as usize) < leafs_raw.len() };
                if !ok {
                    return Err(format!("node {i}: child {c} is neither a later node nor one of the {} leaves", leafs_raw.len()));
                }
            }
            nodes.push(Node { plane, children: [a, b] });
        }
        let mut leafs = Vec::with_capacity(leafs_raw.len());
        for (i, [cluster, first, n]) in leafs_raw.into_iter().enumerate() {
            let (first_brush, num_brushes) = range(first, n, leaf_brushes_raw.len(), "leaf brushes", format!("leaf {i}"))?;
            leafs.push(Leaf { cluster, first_brush, num_brushes });
        }
        let leaf_brushes = leaf_brushes_raw
            .into_iter()
            .enumerate()
            .map(|(i, b)| index(b, brushes_raw.len(), "brush", format!("leaf brush {i}")))
            .collect::<Result<_, _>>()?;
        let mut brushes = Vec::with_capacity(brushes_raw.len());
        for (i, [first, n, shader]) in brushes_raw.into_iter().enumerate() {
            let (first_side, num_sides) = range(first, n, sides_raw.len(), "sides", format!("brush {i}"))?;
            let shader = index(shader, num_shaders, "shader", format!("brush {i}"))?;
            brushes.push(Brush { first_side, num_sides, shader });
        }
        let brush_sides = sides_raw
            .into_iter()
            .enumerate()
            .map(|(i, [p, s])| Ok(BrushSide { plane: index(p, planes.len(), "plane", format!("brush side {i}"))?, shader: index(s, num_shaders, "shader", format!("brush side {i}"))? }))
            .collect::<Result<_, String>>()?;
        Ok(Collision { planes, nodes, leafs, leaf_brushes, brushes, brush_sides, error: None })
    }

    /// Appends the structure's lumps to `lumps` (see [`Bsp::to_bytes`]); the parts relight
    /// does not read (node and leaf bounds, leaf surfaces, areas) are written as zeros.
    fn write(&self, lumps: &mut [Vec<u8>], rbsp: bool) {
        let put = |v: &mut Vec<u8>, xs: &[i32]| xs.iter().for_each(|x| v.extend_from_slice(&x.to_le_bytes()));
        for (n, d) in &self.planes {
            n.iter().chain([d]).for_each(|x| lumps[lump::PLANES].extend_from_slice(&x.to_le_bytes()));
        }
        for n in &self.nodes {
            put(&mut lumps[lump::NODES], &[n.plane as i32, n.children[0], n.children[1], 0, 0, 0, 0, 0, 0]);
        }
        for l in &self.leafs {
            put(&mut lumps[lump::LEAFS], &[l.cluster, 0, 0, 0, 0, 0, 0, 0, 0, 0, l.first_brush as i32, l.num_brushes as i32]);
        }
        for &b in &self.leaf_brushes {
            put(&mut lumps[lump::LEAF_BRUSHES], &[b as i32]);
        }
        for b in &self.brushes {
            put(&mut lumps[lump::BRUSHES], &[b.first_side as i32, b.num_sides as i32, b.shader as i32]);
        }
        for s in &self.brush_sides {
            put(&mut lumps[lump::BRUSH_SIDES], &[s.plane as i32, s.shader as i32]);
            if rbsp {
                put(&mut lumps[lump::BRUSH_SIDES], &[-1]);
            }
        }
    }
}

/// A parsed, validated BSP file.
#[derive(Debug, Clone, PartialEq)]
pub struct Bsp {
    pub format: Format,
    /// The entity lump as text (Latin-1 bytes mapped to chars, trailing NULs removed).
    pub entities: String,
    pub shaders: Vec<ShaderRef>,
    pub models: Vec<Model>,
    pub verts: Vec<DrawVert>,
    /// Draw indexes, relative to a surface's `first_vert` (checked to be in range).
    pub indices: Vec<u32>,
    pub surfaces: Vec<Surface>,
    /// Lightmap pages of lump 14, each [`LIGHTMAP_BYTES`] of RGB.
    pub lightmaps: Vec<Vec<u8>>,
    /// The solid structure (see [`Collision`]).
    pub collision: Collision,
    pub other: OtherCounts,
}

const HEADER_LUMPS_IBSP: usize = 17;
const HEADER_LUMPS_RBSP: usize = 18;
const SHADER_BYTES: usize = 72;
const MODEL_BYTES: usize = 40;
const VERT_BYTES_IBSP: usize = 44;
const VERT_BYTES_RBSP: usize = 80;
const SURFACE_BYTES_IBSP: usize = 104;
const SURFACE_BYTES_RBSP: usize = 148;
/// Largest patch control grid accepted (the engine's MAX_PATCH_SIZE is 32).
pub const MAX_PATCH_CONTROL: u32 = 65;

/// Little-endian reader over one record; the caller guarantees the record length.
struct Rec<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Rec<'a> {
    fn new(b: &'a [u8]) -> Self {
        Rec { b, at: 0 }
    }
    fn i32(&mut self) -> i32 {
        let v = i32::from_le_bytes(self.b[self.at..self.at + 4].try_into().unwrap());
        self.at += 4;
        v
    }
    fn f32(&mut self) -> f32 {
        let v = f32::from_le_bytes(self.b[self.at..self.at + 4].try_into().unwrap());
        self.at += 4;
        v
    }
    fn vec3(&mut self) -> [f32; 3] {
        [self.f32(), self.f32(), self.f32()]
    }
    fn vec2(&mut self) -> [f32; 2] {
        [self.f32(), self.f32()]
    }
    fn bytes<const N: usize>(&mut self) -> [u8; N] {
        let v: [u8; N] = self.b[self.at..self.at + N].try_into().unwrap();
        self.at += N;
        v
    }
    fn skip(&mut self, n: usize) {
        self.at += n;
    }
}

fn latin1(bytes: &[u8]) -> String {
    bytes.iter().map(|&b| b as char).collect()
}

fn c_string(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    latin1(&bytes[..end])
}

impl Bsp {
    /// Parses and validates a BSP file held in memory.
    pub fn parse(data: &[u8]) -> Result<Bsp, BspError> {
        if data.len() < 8 {
            return Err(BspError::TooShort(data.len()));
        }
        let magic = &data[0..4];
        let version = i32::from_le_bytes(data[4..8].try_into().unwrap());
        let format = match (magic, version) {
            (b"IBSP", 46) | (b"IBSP", 47) => Format::Ibsp(version),
            (b"RBSP", 1) => Format::Rbsp,
            (b"IBSP", _) | (b"RBSP", _) => {
                return Err(BspError::UnsupportedVersion { magic: latin1(magic), version })
            }
            _ => return Err(BspError::BadMagic(latin1(magic).escape_debug().to_string())),
        };
        let nlumps = if format == Format::Rbsp { HEADER_LUMPS_RBSP } else { HEADER_LUMPS_IBSP };
        let header_len = 8 + nlumps * 8;
        if data.len() < header_len {
            return Err(BspError::TooShort(data.len()));
        }
        // Directory of the 17 lumps we read (RBSP's 18th, the light array, is not used).
        let mut lumps: [&[u8]; 17] = [&[]; 17];
        for (i, slot) in lumps.iter_mut().enumerate() {
            let at = 8 + i * 8;
            let offset = i32::from_le_bytes(data[at..at + 4].try_into().unwrap()) as i64;
            let length = i32::from_le_bytes(data[at + 4..at + 8].try_into().unwrap()) as i64;
            let end = offset.checked_add(length);
            if offset < 0 || length < 0 || end.is_none_or(|e| e > data.len() as i64) {
                return Err(BspError::LumpOutOfFile {
                    lump: i,
                    name: lump::NAMES[i],
                    offset,
                    length,
                    file_len: data.len(),
                });
            }
            *slot = &data[offset as usize..(offset + length) as usize];
        }
        let records = |i: usize, elem: usize| -> Result<std::slice::ChunksExact<'_, u8>, BspError> {
            let l = lumps[i];
            if l.len() % elem != 0 {
                return Err(BspError::LumpSize { lump: i, name: lump::NAMES[i], length: l.len(), elem });
            }
            Ok(l.chunks_exact(elem))
        };
        let count = |i: usize, elem: usize| -> Result<usize, BspError> { Ok(records(i, elem)?.len()) };

        let rbsp = format == Format::Rbsp;
        let entities = {
            let mut e = lumps[lump::ENTITIES];
            while let [rest @ .., 0] = e {
                e = rest;
            }
            latin1(e)
        };
        let shaders: Vec<ShaderRef> = records(lump::SHADERS, SHADER_BYTES)?
            .map(|r| {
                let mut rec = Rec::new(&r[64..]);
                ShaderRef { name: c_string(&r[..64]), surface_flags: rec.i32(), content_flags: rec.i32() }
            })
            .collect();
        let models: Vec<Model> = records(lump::MODELS, MODEL_BYTES)?
            .map(|r| {
                let mut rec = Rec::new(r);
                let mins = rec.vec3();
                let maxs = rec.vec3();
                let first_surface = rec.i32();
                let num_surfaces = rec.i32();
                (mins, maxs, first_surface, num_surfaces, rec.i32(), rec.i32())
            })
            .enumerate()
            .map(|(i, (mins, maxs, fs, ns, fb, nb))| {
                if fs < 0 || ns < 0 {
                    return Err(BspError::Invalid(format!(
                        "model {i}: negative surface range (first {fs}, count {ns})"
                    )));
                }
                Ok(Model { mins, maxs, first_surface: fs as u32, num_surfaces: ns as u32, first_brush: fb, num_brushes: nb })
            })
            .collect::<Result<_, _>>()?;
        let vert_bytes = if rbsp { VERT_BYTES_RBSP } else { VERT_BYTES_IBSP };
        let verts: Vec<DrawVert> = records(lump::DRAW_VERTS, vert_bytes)?
            .map(|r| {
                let mut rec = Rec::new(r);
                let xyz = rec.vec3();
                let st = rec.vec2();
                let lightmap = rec.vec2();
                if rbsp {
                    rec.skip(3 * 8); // lightmap styles 1..3
                }
                let normal = rec.vec3();
                let color = rec.bytes::<4>();
                DrawVert { xyz, st, lightmap, normal, color }
            })
            .collect();
        let raw_indices: Vec<i32> =
            records(lump::DRAW_INDEXES, 4)?.map(|r| i32::from_le_bytes(r.try_into().unwrap())).collect();
        let surface_bytes = if rbsp { SURFACE_BYTES_RBSP } else { SURFACE_BYTES_IBSP };
        let surfaces_raw: Vec<[i32; 26]> = records(lump::SURFACES, surface_bytes)?
            .map(|r| {
                let mut rec = Rec::new(r);
                let mut s = [0i32; 26];
                // shader, fog, type, firstVert, numVerts, firstIndex, numIndexes
                for v in s.iter_mut().take(7) {
                    *v = rec.i32();
                }
                if rbsp {
                    rec.skip(8); // lightmap styles and vertex styles
                    s[7] = rec.i32(); // lightmapNum[0]
                    rec.skip(12);
                    s[8] = rec.i32(); // lightmapX[0]
                    rec.skip(12);
                    s[9] = rec.i32(); // lightmapY[0]
                    rec.skip(12);
                } else {
                    for v in s.iter_mut().take(10).skip(7) {
                        *v = rec.i32();
                    }
                }
                s[10] = rec.i32(); // lightmap width
                s[11] = rec.i32(); // lightmap height
                // origin + 3 vecs as raw bits, then patch width/height
                for v in s.iter_mut().take(24).skip(12) {
                    *v = rec.f32().to_bits() as i32;
                }
                s[24] = rec.i32();
                s[25] = rec.i32();
                s
            })
            .collect();
        let lm_lump = lumps[lump::LIGHTMAPS];
        if lm_lump.len() % LIGHTMAP_BYTES != 0 {
            return Err(BspError::LumpSize {
                lump: lump::LIGHTMAPS,
                name: lump::NAMES[lump::LIGHTMAPS],
                length: lm_lump.len(),
                elem: LIGHTMAP_BYTES,
            });
        }
        let lightmaps: Vec<Vec<u8>> = lm_lump.chunks_exact(LIGHTMAP_BYTES).map(|c| c.to_vec()).collect();
        let other = OtherCounts {
            planes: count(lump::PLANES, 16)?,
            nodes: count(lump::NODES, 36)?,
            leafs: count(lump::LEAFS, 48)?,
            brushes: count(lump::BRUSHES, 12)?,
            fogs: count(lump::FOGS, 72)?,
            light_grid_bytes: lumps[lump::LIGHT_GRID].len(),
            visibility_bytes: lumps[lump::VISIBILITY].len(),
        };

        let nverts = verts.len();
        let nidx = raw_indices.len();
        let mut surfaces = Vec::with_capacity(surfaces_raw.len());
        for (i, s) in surfaces_raw.iter().enumerate() {
            let f = |k: usize| f32::from_bits(s[k] as u32);
            let kind = SurfaceType::from_raw(s[2]);
            let bad = |msg: String| BspError::Invalid(format!("surface {i}: {msg}"));
            let (shader, fv, nv, fi, ni) = (s[0], s[3], s[4], s[5], s[6]);
            if shader < 0 || shader as usize >= shaders.len() {
                return Err(bad(format!("shader index {shader} outside the {} shaders", shaders.len())));
            }
            if fv < 0 || nv < 0 || fi < 0 || ni < 0 {
                return Err(bad(format!("negative range (vertices {fv}+{nv}, indexes {fi}+{ni})")));
            }
            let drawn = matches!(kind, SurfaceType::Polygon | SurfaceType::Mesh | SurfaceType::Patch);
            if drawn && fv as usize + nv as usize > nverts {
                return Err(bad(format!("vertices {fv}..{} exceed the {nverts} draw vertices", fv as i64 + nv as i64)));
            }
            let (mut pw, mut ph) = (0u32, 0u32);
            match kind {
                SurfaceType::Polygon | SurfaceType::Mesh => {
                    if fi as usize + ni as usize > nidx {
                        return Err(bad(format!("indexes {fi}..{} exceed the {nidx} draw indexes", fi as i64 + ni as i64)));
                    }
                    if ni % 3 != 0 {
                        return Err(bad(format!("{ni} indexes is not a whole number of triangles")));
                    }
                    if let Some(&x) = raw_indices[fi as usize..(fi + ni) as usize].iter().find(|&&x| x < 0 || x >= nv) {
                        return Err(bad(format!("index {x} outside the surface's {nv} vertices")));
                    }
                }
                SurfaceType::Patch => {
                    let (w, h) = (s[24], s[25]);
                    let ok = |x: i32| x >= 3 && x % 2 == 1 && x as u32 <= MAX_PATCH_CONTROL;
                    if !ok(w) || !ok(h) {
                        return Err(bad(format!("patch control grid {w}x{h} (each side must be odd, 3..={MAX_PATCH_CONTROL})")));
                    }
                    if (w * h) != nv {
                        return Err(bad(format!("patch grid {w}x{h} does not match its {nv} vertices")));
                    }
                    (pw, ph) = (w as u32, h as u32);
                }
                _ => {}
            }
            surfaces.push(Surface {
                shader: shader as u32,
                fog: s[1],
                kind,
                first_vert: fv as u32,
                num_verts: nv as u32,
                first_index: fi as u32,
                num_indexes: ni as u32,
                lightmap: s[7],
                lightmap_x: s[8],
                lightmap_y: s[9],
                lightmap_w: s[10],
                lightmap_h: s[11],
                lightmap_origin: [f(12), f(13), f(14)],
                lightmap_vecs: [[f(15), f(16), f(17)], [f(18), f(19), f(20)], [f(21), f(22), f(23)]],
                patch_w: pw,
                patch_h: ph,
            });
        }
        for (i, m) in models.iter().enumerate() {
            if m.first_surface as usize + m.num_surfaces as usize > surfaces.len() {
                return Err(BspError::Invalid(format!(
                    "model {i}: surfaces {}..{} exceed the {} surfaces",
                    m.first_surface,
                    m.first_surface as u64 + m.num_surfaces as u64,
                    surfaces.len()
                )));
            }
        }
        // Indices were checked against each referencing surface; negative ones elsewhere
        // are never read, so store them as they are (wrapping) for exact round trips.
        let indices = raw_indices.into_iter().map(|x| x as u32).collect();
        let collision = Collision::parse(&lumps, shaders.len(), rbsp).unwrap_or_else(|e| Collision { error: Some(e), ..Default::default() });
        Ok(Bsp { format, entities, shaders, models, verts, indices, surfaces, lightmaps, collision, other })
    }

    /// Vertices of a surface. [`Bsp::parse`] checks the range of drawn surfaces
    /// (polygons, meshes, patches); a flare's or an unknown kind's range is never checked,
    /// so one that falls outside the vertices reads as none rather than panicking.
    pub fn surface_verts(&self, s: &Surface) -> &[DrawVert] {
        let first = s.first_vert as usize;
        first.checked_add(s.num_verts as usize).and_then(|end| self.verts.get(first..end)).unwrap_or(&[])
    }

    /// Indexes of a surface, relative to its first vertex. Checked by [`Bsp::parse`] for
    /// polygons and meshes; any other kind's range outside the indexes reads as none.
    pub fn surface_indices(&self, s: &Surface) -> &[u32] {
        let first = s.first_index as usize;
        first.checked_add(s.num_indexes as usize).and_then(|end| self.indices.get(first..end)).unwrap_or(&[])
    }

    /// Writes the records as a BSP file: IBSP with the version of `self.format`, or RBSP 1
    /// (lightmap style 0 filled in, the other styles unused). Lumps that are not modelled
    /// (planes, nodes, ...) are written empty.
    pub fn to_bytes(&self) -> Vec<u8> {
        let rbsp = self.format == Format::Rbsp;
        let nlumps = if rbsp { HEADER_LUMPS_RBSP } else { HEADER_LUMPS_IBSP };
        let mut lumps: Vec<Vec<u8>> = vec![Vec::new(); nlumps];
        let put_i32 = |v: &mut Vec<u8>, x: i32| v.extend_from_slice(&x.to_le_bytes());
        let put_f32 = |v: &mut Vec<u8>, x: f32| v.extend_from_slice(&x.to_le_bytes());

        let mut ent = self.entities.chars().map(|c| c as u32 as u8).collect::<Vec<u8>>();
        ent.push(0);
        lumps[lump::ENTITIES] = ent;
        for s in &self.shaders {
            let l = &mut lumps[lump::SHADERS];
            let mut name = [0u8; 64];
            for (d, c) in name.iter_mut().zip(s.name.chars().take(63)) {
                *d = c as u32 as u8;
            }
            l.extend_from_slice(&name);
            put_i32(l, s.surface_flags);
            put_i32(l, s.content_flags);
        }
        for m in &self.models {
            let l = &mut lumps[lump::MODELS];
            m.mins.iter().chain(&m.maxs).for_each(|&x| put_f32(l, x));
            for x in [m.first_surface as i32, m.num_surfaces as i32, m.first_brush, m.num_brushes] {
                put_i32(l, x);
            }
        }
        for v in &self.verts {
            let l = &mut lumps[lump::DRAW_VERTS];
            v.xyz.iter().chain(&v.st).chain(&v.lightmap).for_each(|&x| put_f32(l, x));
            if rbsp {
                l.extend_from_slice(&[0u8; 24]);
            }
            v.normal.iter().for_each(|&x| put_f32(l, x));
            l.extend_from_slice(&v.color);
            if rbsp {
                l.extend_from_slice(&[255u8; 12]);
            }
        }
        for &i in &self.indices {
            put_i32(&mut lumps[lump::DRAW_INDEXES], i as i32);
        }
        for s in &self.surfaces {
            let l = &mut lumps[lump::SURFACES];
            for x in [s.shader as i32, s.fog, s.kind.to_raw(), s.first_vert as i32, s.num_verts as i32, s.first_index as i32, s.num_indexes as i32] {
                put_i32(l, x);
            }
            if rbsp {
                l.extend_from_slice(&[0, 255, 255, 255, 0, 255, 255, 255]);
                for x in [s.lightmap, -4, -4, -4, s.lightmap_x, 0, 0, 0, s.lightmap_y, 0, 0, 0] {
                    put_i32(l, x);
                }
            } else {
                for x in [s.lightmap, s.lightmap_x, s.lightmap_y] {
                    put_i32(l, x);
                }
            }
            put_i32(l, s.lightmap_w);
            put_i32(l, s.lightmap_h);
            s.lightmap_origin.iter().chain(s.lightmap_vecs.iter().flatten()).for_each(|&x| put_f32(l, x));
            put_i32(l, s.patch_w as i32);
            put_i32(l, s.patch_h as i32);
        }
        for page in &self.lightmaps {
            lumps[lump::LIGHTMAPS].extend_from_slice(page);
        }
        self.collision.write(&mut lumps, rbsp);

        let mut out = Vec::new();
        out.extend_from_slice(if rbsp { b"RBSP" } else { b"IBSP" });
        let version = match self.format {
            Format::Ibsp(v) => v,
            Format::Rbsp => 1,
        };
        put_i32(&mut out, version);
        let mut offset = 8 + nlumps * 8;
        for l in &lumps {
            put_i32(&mut out, offset as i32);
            put_i32(&mut out, l.len() as i32);
            offset += l.len().next_multiple_of(4);
        }
        for l in &lumps {
            out.extend_from_slice(l);
            out.resize(out.len().next_multiple_of(4), 0);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> Bsp {
        let v = |x: f32, y: f32| DrawVert { xyz: [x, y, 0.0], normal: [0.0, 0.0, 1.0], color: [255; 4], ..Default::default() };
        Bsp {
            format: Format::Ibsp(46),
            entities: "{\n\"classname\" \"worldspawn\"\n}\n".into(),
            shaders: vec![ShaderRef { name: "textures/a/b".into(), surface_flags: 0, content_flags: 1 }],
            models: vec![Model { mins: [0.0; 3], maxs: [1.0; 3], first_surface: 0, num_surfaces: 1, first_brush: 0, num_brushes: 0 }],
            verts: vec![v(0.0, 0.0), v(0.0, 1.0), v(1.0, 1.0)],
            indices: vec![0, 1, 2],
            surfaces: vec![Surface {
                num_verts: 3,
                num_indexes: 3,
                lightmap: 0,
                lightmap_w: 2,
                lightmap_h: 2,
                ..Surface::new(0, SurfaceType::Polygon)
            }],
            lightmaps: vec![vec![7u8; LIGHTMAP_BYTES]],
            collision: Collision {
                planes: vec![([0.0, 0.0, 1.0], 0.0)],
                nodes: vec![Node { plane: 0, children: [-1, -2] }],
                leafs: vec![Leaf { cluster: 0, first_brush: 0, num_brushes: 0 }, Leaf { cluster: -1, first_brush: 0, num_brushes: 1 }],
                leaf_brushes: vec![0],
                brushes: vec![Brush { first_side: 0, num_sides: 1, shader: 0 }],
                brush_sides: vec![BrushSide { plane: 0, shader: 0 }],
                error: None,
            },
            other: OtherCounts::default(),
        }
    }

    #[test]
    fn round_trip_ibsp_and_rbsp() {
        for format in [Format::Ibsp(46), Format::Ibsp(47), Format::Rbsp] {
            let mut b = tiny();
            b.format = format;
            let mut parsed = Bsp::parse(&b.to_bytes()).unwrap();
            assert_eq!((parsed.other.planes, parsed.other.nodes, parsed.other.leafs, parsed.other.brushes), (1, 1, 2, 1));
            parsed.other = b.other;
            assert!(parsed == b, "{format}: the records differ after the round trip");
        }
    }

    /// The whole scene build on `bsp` with an empty file system (as the fuzz target runs it).
    fn build(bsp: Bsp) -> Result<(crate::scene::Scene, crate::pipeline::Summary), crate::error::Error> {
        let map = crate::pipeline::LoadedMap { vfs: crate::vfs::Vfs::new(), bsp, name: "test".into(), shown: "test.bsp".into(), path: None };
        crate::pipeline::build_scene(&map, &crate::pipeline::Options::default(), &|_| {})
    }

    /// Found by the fuzzer (CI, stop 50): a flare in the world model whose vertex range
    /// lies outside the vertices. `parse` checks only drawn surfaces' ranges, so the
    /// accessors must read such a range as empty, and the whole build (shadow casters
    /// included, which walk every surface of the world) must not panic.
    #[test]
    fn unchecked_kinds_with_ranges_outside_read_as_empty() {
        let mut b = tiny();
        b.surfaces.push(Surface { first_vert: 200, num_verts: 5, first_index: 90, num_indexes: 3, ..Surface::new(0, SurfaceType::Flare) });
        b.surfaces.push(Surface { first_vert: 0x7fff_fff0, num_verts: 0x7fff_fff0, ..Surface::new(0, SurfaceType::Other(0)) });
        b.models[0].num_surfaces = 3;
        let parsed = Bsp::parse(&b.to_bytes()).expect("flares' ranges are not checked");
        assert!(parsed.collision.error.is_none() && !parsed.collision.nodes.is_empty(), "the casters must run");
        for s in &parsed.surfaces[1..] {
            assert!(parsed.surface_verts(s).is_empty() && parsed.surface_indices(s).is_empty());
        }
        assert_eq!(parsed.surface_verts(&parsed.surfaces[0]).len(), 3);
        build(parsed).expect("the polygon still converts");
    }

    /// A map without models (no world) is parsed, and the whole build copes with it.
    #[test]
    fn a_map_without_models_builds_without_panicking() {
        let mut b = tiny();
        b.models.clear();
        let parsed = Bsp::parse(&b.to_bytes()).expect("an empty models lump is well formed");
        assert!(parsed.models.is_empty() && parsed.collision.error.is_none());
        let _ = build(parsed);
    }

    #[test]
    fn rejects_bad_headers_and_ranges() {
        let good = tiny().to_bytes();
        assert!(matches!(Bsp::parse(&good[..5]), Err(BspError::TooShort(5))));
        let mut m = good.clone();
        m[0..4].copy_from_slice(b"VBSP");
        assert!(matches!(Bsp::parse(&m), Err(BspError::BadMagic(_))));
        let mut m = good.clone();
        m[4..8].copy_from_slice(&45i32.to_le_bytes());
        assert!(matches!(Bsp::parse(&m), Err(BspError::UnsupportedVersion { version: 45, .. })));
        let mut m = good.clone();
        let at = 8 + lump::DRAW_VERTS * 8 + 4;
        m[at..at + 4].copy_from_slice(&i32::MAX.to_le_bytes());
        assert!(matches!(Bsp::parse(&m), Err(BspError::LumpOutOfFile { lump: 10, .. })));
        let mut b = tiny();
        b.indices[2] = 3;
        assert!(matches!(Bsp::parse(&b.to_bytes()), Err(BspError::Invalid(m)) if m.contains("index 3")));
        let mut b = tiny();
        b.surfaces[0].num_verts = 1 << 30;
        assert!(matches!(Bsp::parse(&b.to_bytes()), Err(BspError::Invalid(m)) if m.contains("exceed")));
    }

    #[test]
    fn a_broken_solid_structure_is_dropped_with_its_reason_and_the_geometry_kept() {
        let cases: [(&str, fn(&mut Collision)); 5] = [
            ("plane 7", |c| c.nodes[0].plane = 7),
            ("child 0", |c| c.nodes[0].children[0] = 0),
            ("leaf brushes", |c| c.leafs[1].num_brushes = 9),
            ("sides", |c| c.brushes[0].first_side = u32::MAX),
            ("shader", |c| c.brush_sides[0].shader = 3),
        ];
        for (said, break_it) in cases {
            let mut b = tiny();
            break_it(&mut b.collision);
            let parsed = Bsp::parse(&b.to_bytes()).unwrap();
            assert_eq!(parsed.surfaces, b.surfaces);
            assert!(parsed.collision.nodes.is_empty() && parsed.collision.brushes.is_empty());
            let why = parsed.collision.error.unwrap_or_default();
            assert!(why.contains(said), "{said}: {why}");
        }
    }
}
