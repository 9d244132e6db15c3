//! Lightmap atlases for geometry that has none: xatlas cuts the triangles into charts,
//! flattens each and packs them into one atlas at a chosen texel density, with padding
//! between charts so that bilinear filtering at a chart's edge never reads another chart.
//!
//! Input: triangle meshes in world units (meters), one per glTF primitive instance.
//! Output: per mesh, new vertices (each a copy of an input vertex, `xref`, with atlas
//! coordinates) and new triangles; vertices are split where a chart seam runs. The atlas
//! coordinates are normalised to `[0, 1]` with `v` down the image rows, glTF's TEXCOORD
//! convention, so `uv * (width, height)` is in texels with centres at half-integers (what
//! [`crate::rows::luxel`] samples).
//!
//! Invariants: every output index is below its mesh's vertex count; every `xref` is below
//! the input's vertex count; triangles xatlas ignores (zero area, repeated indices) keep
//! their place in the index list with all three vertices at `(0, 0)` and are counted.

mod xatlas;

use std::sync::Mutex;

/// One mesh to chart.
#[derive(Debug, Clone, Copy)]
pub struct Input<'a> {
    /// World positions, meters. Callers pass them relative to a nearby origin (f32 keeps
    /// about 7 digits; xatlas ignores triangles of area below 1.2e-7 in these units).
    pub positions: &'a [[f32; 3]],
    /// Unit normals, if the mesh has them (xatlas then avoids seams across hard edges less).
    pub normals: Option<&'a [[f32; 3]]>,
    /// Triangle list.
    pub indices: &'a [u32],
}

#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Texels per meter (the inverse of the texel size).
    pub texels_per_m: f32,
    /// Empty texels kept between charts (xatlas's conservative rasterisation plus this).
    pub padding: u32,
    /// The atlas may be at most this many texels on a side.
    pub max_size: u32,
}

/// One mesh's new lightmap coordinates.
#[derive(Debug, Clone, Default)]
pub struct MeshUv {
    /// Input vertex each output vertex copies.
    pub xref: Vec<u32>,
    /// Atlas coordinates, normalised (`u` right, `v` down).
    pub uv: Vec<[f32; 2]>,
    /// Triangle list over the output vertices (same triangle order as the input).
    pub indices: Vec<u32>,
    /// Triangles xatlas ignored (degenerate): no texels.
    pub ignored: usize,
}

#[derive(Debug, Clone, Default)]
pub struct Atlas {
    pub width: u32,
    pub height: u32,
    pub charts: u32,
    /// Fraction of the atlas's texels inside a chart, as xatlas reports it.
    pub utilization: f32,
    pub meshes: Vec<MeshUv>,
}

/// xatlas keeps global state (its print and allocation hooks): one atlas at a time.
static XATLAS: Mutex<()> = Mutex::new(());

/// Most triangles and vertices one call accepts (xatlas counts in 32 bits).
pub const MAX_ELEMENTS: usize = 1 << 28;

/// Charts and packs `meshes` into one atlas.
///
/// Errors (as text for the caller to attach a file name to): an index out of range, a
/// non-finite position, an index count not divisible by three, a non-positive density, or
/// an atlas larger than `max_size` (the message says which texel size would fit).
pub fn chart(meshes: &[Input], opts: &Options) -> Result<Atlas, String> {
    if !(opts.texels_per_m.is_finite() && opts.texels_per_m > 0.0) {
        return Err(format!("texel density {} per meter is not positive", opts.texels_per_m));
    }
    let mut area_m2 = 0.0f64;
    for (k, m) in meshes.iter().enumerate() {
        if m.indices.len() % 3 != 0 {
            return Err(format!("mesh {k}: {} indices is not a triangle list", m.indices.len()));
        }
        if m.positions.len() > MAX_ELEMENTS || m.indices.len() > MAX_ELEMENTS {
            return Err(format!("mesh {k}: more than {MAX_ELEMENTS} vertices or indices"));
        }
        if let Some(i) = m.indices.iter().find(|&&i| i as usize >= m.positions.len()) {
            return Err(format!("mesh {k}: index {i} out of range (vertex count {})", m.positions.len()));
        }
        if m.positions.iter().flatten().any(|v| !v.is_finite()) {
            return Err(format!("mesh {k}: a position is not finite"));
        }
        if m.normals.is_some_and(|n| n.len() != m.positions.len()) {
            return Err(format!("mesh {k}: normal count differs from position count"));
        }
        for t in m.indices.chunks_exact(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| glam::Vec3::from(m.positions[i as usize]).as_dvec3());
            area_m2 += 0.5 * (b - a).cross(c - a).length();
        }
    }
    // Refuse before xatlas allocates: the charts alone cover area * density^2 texels, and
    // packing rarely does better than half.
    let side = opts.max_size as f64;
    let texels = area_m2 * (opts.texels_per_m as f64).powi(2);
    if texels > 0.5 * side * side {
        let fits = (2.0 * area_m2).sqrt() / side;
        return Err(format!(
            "{area_m2:.0} m^2 of surface at {:.4} m per texel needs at least {:.0} texels, more than a {}x{} atlas holds; use a texel size of {fits:.3} m or more",
            1.0 / opts.texels_per_m,
            texels,
            opts.max_size,
            opts.max_size
        ));
    }

    let _guard = XATLAS.lock().unwrap_or_else(|e| e.into_inner());
    // SAFETY: every pointer handed to xatlas points into a slice that outlives the call
    // (AddMesh copies its input); indices were checked above; the atlas is destroyed on
    // every path by `Owned`.
    unsafe {
        xatlas::SetPrint(None, false);
        xatlas::SetRealloc(xatlas::realloc_or_free);
        let owned = Owned(xatlas::Create());
        if owned.0.is_null() {
            return Err("xatlas could not create an atlas".into());
        }
        let mut added = Vec::new();
        for (k, m) in meshes.iter().enumerate() {
            if m.indices.is_empty() {
                continue;
            }
            let decl = xatlas::MeshDecl {
                vertexCount: m.positions.len() as u32,
                vertexPositionData: m.positions.as_ptr().cast(),
                vertexPositionStride: 12,
                vertexNormalData: m.normals.map_or(std::ptr::null(), |n| n.as_ptr().cast()),
                vertexNormalStride: if m.normals.is_some() { 12 } else { 0 },
                vertexUvData: std::ptr::null(),
                vertexUvStride: 0,
                indexCount: m.indices.len() as u32,
                indexData: m.indices.as_ptr().cast(),
                indexOffset: 0,
                indexFormat: xatlas::INDEX_FORMAT_U32,
                faceIgnoreData: std::ptr::null(),
            };
            let err = xatlas::AddMesh(owned.0, &decl);
            if err != xatlas::ADD_MESH_SUCCESS {
                return Err(format!("mesh {k}: xatlas refused it (error {err})"));
            }
            added.push(k);
        }
        let mut out = Atlas { meshes: vec![MeshUv::default(); meshes.len()], ..Atlas::default() };
        if added.is_empty() {
            return Ok(out);
        }
        let pack = xatlas::PackOptions {
            texelsPerUnit: opts.texels_per_m,
            maxChartSize: opts.max_size,
            conservative: true,
            padding: opts.padding,
            ..xatlas::PackOptions::default()
        };
        xatlas::Generate(owned.0, xatlas::ChartOptions::default(), None, pack, None, std::ptr::null_mut());
        let a = &*owned.0;
        if a.meshCount as usize != added.len() || a.meshes.is_null() {
            return Err(format!("xatlas returned {} meshes for {}", a.meshCount, added.len()));
        }
        if a.width > opts.max_size || a.height > opts.max_size {
            return Err(format!("the atlas came out {}x{} texels, more than {}: use a larger texel size", a.width, a.height, opts.max_size));
        }
        out.width = a.width;
        out.height = a.height;
        out.charts = a.chartCount;
        out.utilization = if a.utilization.is_null() { 0.0 } else { *a.utilization };
        let (w, h) = (a.width.max(1) as f32, a.height.max(1) as f32);
        for (slot, &k) in added.iter().enumerate() {
            let src = &meshes[k];
            let m = &*a.meshes.add(slot);
            let verts = raw_slice(m.vertexArray, m.vertexCount);
            let idx = raw_slice(m.indexArray, m.indexCount);
            if idx.len() != src.indices.len() {
                return Err(format!("mesh {k}: xatlas returned {} indices for {}", idx.len(), src.indices.len()));
            }
            if let Some(bad) = idx.iter().find(|&&i| i >= m.vertexCount) {
                return Err(format!("mesh {k}: xatlas returned index {bad} of {} vertices", m.vertexCount));
            }
            if let Some(bad) = verts.iter().find(|v| v.xref as usize >= src.positions.len()) {
                return Err(format!("mesh {k}: xatlas returned vertex copying {} of {}", bad.xref, src.positions.len()));
            }
            let ignored = idx.chunks_exact(3).filter(|t| t.iter().any(|&i| verts[i as usize].atlasIndex < 0)).count();
            out.meshes[k] = MeshUv {
                xref: verts.iter().map(|v| v.xref).collect(),
                uv: verts
                    .iter()
                    .map(|v| if v.atlasIndex < 0 || !v.uv.iter().all(|c| c.is_finite()) { [0.0, 0.0] } else { [v.uv[0] / w, v.uv[1] / h] })
                    .collect(),
                indices: idx.to_vec(),
                ignored,
            };
        }
        Ok(out)
    }
}

/// Destroys the atlas when dropped.
struct Owned(*mut xatlas::Atlas);
impl Drop for Owned {
    fn drop(&mut self) {
        if !self.0.is_null() {
            // SAFETY: created by xatlas::Create, destroyed once.
            unsafe { xatlas::Destroy(self.0) }
        }
    }
}

/// # Safety
/// `p` must point to `n` initialised elements living as long as the returned slice, or be
/// null (then `n` is ignored).
unsafe fn raw_slice<'a, T>(p: *const T, n: u32) -> &'a [T] {
    if p.is_null() || n == 0 {
        &[]
    } else {
        std::slice::from_raw_parts(p, n as usize)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Axis-aligned unit cube, 24 vertices (flat faces), as Blender exports one.
    pub(crate) fn cube(size: f32, at: [f32; 3]) -> (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<u32>) {
        let mut p = Vec::new();
        let mut n = Vec::new();
        let mut idx = Vec::new();
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let mut normal = [0.0; 3];
                normal[axis] = sign;
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let base = p.len() as u32;
                for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                    let mut q = [0.0f32; 3];
                    q[axis] = sign * 0.5 * size;
                    q[u] = a * 0.5 * size;
                    q[v] = b * 0.5 * size;
                    p.push([q[0] + at[0], q[1] + at[1], q[2] + at[2]]);
                    n.push(normal);
                }
                if sign > 0.0 {
                    idx.extend([base, base + 1, base + 2, base, base + 2, base + 3]);
                } else {
                    idx.extend([base, base + 2, base + 1, base, base + 3, base + 2]);
                }
            }
        }
        (p, n, idx)
    }

    #[test]
    fn a_cube_is_charted_at_the_requested_density() {
        let (p, n, idx) = cube(2.0, [0.0, 0.0, 0.0]);
        let a = chart(&[Input { positions: &p, normals: Some(&n), indices: &idx }], &Options { texels_per_m: 16.0, padding: 2, max_size: 4096 }).unwrap();
        let m = &a.meshes[0];
        assert_eq!(m.indices.len(), idx.len());
        assert_eq!(m.ignored, 0);
        assert!(a.charts >= 1);
        // Each 2 m face spans about 32 texels: 6 faces need at least 6 * 32^2 texels.
        let (w, h) = (a.width as f32, a.height as f32);
        assert!(w * h >= 6.0 * 32.0 * 32.0, "{w}x{h}");
        // Texel area per world area is the density squared, for every triangle.
        for t in m.indices.chunks_exact(3) {
            let [a3, b3, c3] = [0, 1, 2].map(|k| glam::Vec3::from(p[m.xref[t[k] as usize] as usize]));
            let [a2, b2, c2] = [0, 1, 2].map(|k| glam::Vec2::from(m.uv[t[k] as usize]) * glam::Vec2::new(w, h));
            let world = 0.5 * (b3 - a3).cross(c3 - a3).length();
            let texels = 0.5 * (b2 - a2).perp_dot(c2 - a2).abs();
            let ratio = texels / world / 256.0;
            assert!((0.8..1.25).contains(&ratio), "texels per m^2 off by {ratio}");
        }
        assert!(m.uv.iter().flatten().all(|c| (0.0..=1.0).contains(c)));
    }

    #[test]
    fn degenerate_triangles_are_kept_in_place_and_counted() {
        let (mut p, n, mut idx) = cube(1.0, [0.0; 3]);
        let mut n = n;
        p.push([0.0, 0.0, 0.0]);
        n.push([0.0, 0.0, 1.0]);
        let last = p.len() as u32 - 1;
        idx.extend([last, last, 0]); // repeated index
        idx.extend([0, 1, 0]); // repeated index
        let a = chart(&[Input { positions: &p, normals: Some(&n), indices: &idx }], &Options { texels_per_m: 8.0, padding: 1, max_size: 1024 }).unwrap();
        assert_eq!(a.meshes[0].indices.len(), idx.len());
        assert_eq!(a.meshes[0].ignored, 2);
    }

    #[test]
    fn bad_input_and_oversized_atlases_are_errors_not_crashes() {
        let (p, _, idx) = cube(1.0, [0.0; 3]);
        let o = Options { texels_per_m: 8.0, padding: 1, max_size: 1024 };
        let mut bad = idx.clone();
        bad[4] = 99;
        assert!(chart(&[Input { positions: &p, normals: None, indices: &bad }], &o).unwrap_err().contains("out of range"));
        assert!(chart(&[Input { positions: &p, normals: None, indices: &idx[..4] }], &o).is_err());
        let mut nan = p.clone();
        nan[0][1] = f32::NAN;
        assert!(chart(&[Input { positions: &nan, normals: None, indices: &idx }], &o).unwrap_err().contains("finite"));
        let big = Options { texels_per_m: 4096.0, ..o };
        let e = chart(&[Input { positions: &p, normals: None, indices: &idx }], &big).unwrap_err();
        assert!(e.contains("texel size of"), "{e}");
        assert!(chart(&[Input { positions: &p, normals: None, indices: &idx }], &Options { texels_per_m: 0.0, ..o }).is_err());
        // An empty mesh beside a real one.
        let a = chart(&[Input { positions: &[], normals: None, indices: &[] }, Input { positions: &p, normals: None, indices: &idx }], &o).unwrap();
        assert!(a.meshes[0].indices.is_empty() && a.meshes[1].indices.len() == idx.len());
    }
}
