//! The xatlas C++ library, declared from Rust.
//!
//! The `xatlas-rs` crate (0.1.3) compiles the library (`vendor/xatlas.cpp`, a 2019
//! version) into a static archive and links it with libstdc++, but its own bindings name
//! the functions by their MSVC symbols, which exist only on Windows. We depend on it for
//! the build and the link line alone and declare the six functions we call here, under
//! the names the C++ compiler gives them on every platform that uses the Itanium C++ ABI
//! (Linux, the BSDs, macOS): `_ZN6xatlas...`. Nothing of the crate's Rust code is called.
//!
//! Its allocator is set to [`realloc_or_free`].
//!
//! The structs mirror `xatlas.h` field for field (`#[repr(C)]`); the tests below check
//! their sizes against what the header gives on a 64-bit target. `ChartOptions` and
//! `PackOptions` are passed by value: both are trivially copyable, so C++ passes them as a
//! C compiler would, and Rust's `extern "C"` does the same.

#![allow(non_snake_case)]

use std::os::raw::{c_int, c_void};

// Keep the crate (its build script's link directives: the archive, libstdc++) in the link.
use xatlas_rs as _;

/// `xatlas::Chart`.
#[repr(C)]
pub struct Chart {
    pub atlasIndex: u32,
    pub indexArray: *mut u32,
    pub indexCount: u32,
}

/// `xatlas::Vertex`: an output vertex.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct Vertex {
    /// Sub-atlas of the vertex; -1 when its faces were ignored (degenerate).
    pub atlasIndex: i32,
    /// Atlas coordinates in texels (not normalised).
    pub uv: [f32; 2],
    /// The input vertex this one copies.
    pub xref: u32,
}

/// `xatlas::Mesh`: the output for one `AddMesh` call.
#[repr(C)]
pub struct Mesh {
    pub chartArray: *mut Chart,
    pub chartCount: u32,
    pub indexArray: *mut u32,
    pub indexCount: u32,
    pub vertexArray: *mut Vertex,
    pub vertexCount: u32,
}

/// `xatlas::Atlas`.
#[repr(C)]
pub struct Atlas {
    pub width: u32,
    pub height: u32,
    pub atlasCount: u32,
    pub chartCount: u32,
    pub meshCount: u32,
    pub meshes: *mut Mesh,
    pub utilization: *mut f32,
    pub texelsPerUnit: f32,
}

/// `xatlas::IndexFormat::Enum` (an unscoped enum: `int` sized).
pub const INDEX_FORMAT_U32: c_int = 1;

/// `xatlas::MeshDecl`.
#[repr(C)]
pub struct MeshDecl {
    pub vertexCount: u32,
    pub vertexPositionData: *const c_void,
    pub vertexPositionStride: u32,
    pub vertexNormalData: *const c_void,
    pub vertexNormalStride: u32,
    pub vertexUvData: *const c_void,
    pub vertexUvStride: u32,
    pub indexCount: u32,
    pub indexData: *const c_void,
    pub indexOffset: i32,
    pub indexFormat: c_int,
    pub faceIgnoreData: *const bool,
}

/// `xatlas::AddMeshError::Enum`.
pub const ADD_MESH_SUCCESS: c_int = 0;

/// `xatlas::ChartOptions`, with the header's defaults in [`ChartOptions::default`].
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ChartOptions {
    pub maxChartArea: f32,
    pub maxBoundaryLength: f32,
    pub proxyFitMetricWeight: f32,
    pub roundnessMetricWeight: f32,
    pub straightnessMetricWeight: f32,
    pub normalSeamMetricWeight: f32,
    pub textureSeamMetricWeight: f32,
    pub maxThreshold: f32,
    pub growFaceCount: u32,
    pub maxIterations: u32,
}

impl Default for ChartOptions {
    fn default() -> Self {
        ChartOptions {
            maxChartArea: 0.0,
            maxBoundaryLength: 0.0,
            proxyFitMetricWeight: 2.0,
            roundnessMetricWeight: 0.01,
            straightnessMetricWeight: 6.0,
            normalSeamMetricWeight: 4.0,
            textureSeamMetricWeight: 0.5,
            maxThreshold: 2.0,
            growFaceCount: 32,
            maxIterations: 1,
        }
    }
}

/// `xatlas::PackOptions`, with the header's defaults in [`PackOptions::default`].
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct PackOptions {
    pub attempts: c_int,
    pub texelsPerUnit: f32,
    pub resolution: u32,
    pub maxChartSize: u32,
    pub blockAlign: bool,
    pub conservative: bool,
    pub padding: u32,
}

impl Default for PackOptions {
    fn default() -> Self {
        PackOptions { attempts: 4096, texelsPerUnit: 0.0, resolution: 0, maxChartSize: 1024, blockAlign: false, conservative: false, padding: 0 }
    }
}

pub type ParameterizeFunc = Option<unsafe extern "C" fn(*const f32, *mut f32, u32, *const u32, u32, bool)>;
pub type ProgressFunc = Option<unsafe extern "C" fn(c_int, c_int, *mut c_void)>;

extern "C" {
    /// `xatlas::Create()`
    #[link_name = "_ZN6xatlas6CreateEv"]
    pub fn Create() -> *mut Atlas;
    /// `xatlas::Destroy(Atlas*)`
    #[link_name = "_ZN6xatlas7DestroyEPNS_5AtlasE"]
    pub fn Destroy(atlas: *mut Atlas);
    /// `xatlas::AddMesh(Atlas*, MeshDecl const&)`
    #[link_name = "_ZN6xatlas7AddMeshEPNS_5AtlasERKNS_8MeshDeclE"]
    pub fn AddMesh(atlas: *mut Atlas, decl: *const MeshDecl) -> c_int;
    /// `xatlas::Generate(Atlas*, ChartOptions, ParameterizeFunc, PackOptions, ProgressFunc, void*)`
    #[link_name = "_ZN6xatlas8GenerateEPNS_5AtlasENS_12ChartOptionsEPFvPKfPfjPKjjbENS_11PackOptionsEPFvNS_16ProgressCategory4EnumEiPvESD_"]
    pub fn Generate(atlas: *mut Atlas, chart: ChartOptions, param: ParameterizeFunc, pack: PackOptions, progress: ProgressFunc, user: *mut c_void);
    /// `xatlas::SetPrint(int (*)(char const*, ...), bool)`: `None` silences the library.
    #[link_name = "_ZN6xatlas8SetPrintEPFiPKczEb"]
    pub fn SetPrint(print: Option<unsafe extern "C" fn(*const std::os::raw::c_char, ...) -> c_int>, verbose: bool);
    /// `xatlas::SetRealloc(void* (*)(void*, size_t))`.
    #[link_name = "_ZN6xatlas10SetReallocEPFPvS0_mE"]
    pub fn SetRealloc(realloc: unsafe extern "C" fn(*mut c_void, usize) -> *mut c_void);
}

extern "C" {
    #[link_name = "realloc"]
    fn c_realloc(p: *mut c_void, size: usize) -> *mut c_void;
    #[link_name = "free"]
    fn c_free(p: *mut c_void);
}

/// The allocator handed to xatlas: the C library's, except that xatlas frees by
/// `realloc(p, 0)`, which C leaves to the implementation (glibc frees; AddressSanitizer's
/// allocator returns a new minimal block, which then leaks). Size 0 frees here.
///
/// # Safety
/// As `realloc`: `p` is null or a live block of this allocator.
pub unsafe extern "C" fn realloc_or_free(p: *mut c_void, size: usize) -> *mut c_void {
    if size == 0 {
        c_free(p);
        std::ptr::null_mut()
    } else {
        c_realloc(p, size)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::{offset_of, size_of};

    #[test]
    #[cfg(target_pointer_width = "64")]
    fn layouts_match_the_header_on_64_bit_targets() {
        assert_eq!(size_of::<Vertex>(), 16);
        assert_eq!(size_of::<Chart>(), 24);
        assert_eq!(size_of::<Mesh>(), 48);
        assert_eq!(offset_of!(Atlas, meshes), 24);
        assert_eq!(size_of::<Atlas>(), 48);
        assert_eq!(offset_of!(MeshDecl, indexData), 56);
        assert_eq!(offset_of!(MeshDecl, faceIgnoreData), 72);
        assert_eq!(size_of::<MeshDecl>(), 80);
        assert_eq!(size_of::<ChartOptions>(), 40);
        assert_eq!(offset_of!(PackOptions, blockAlign), 16);
        assert_eq!(offset_of!(PackOptions, padding), 20);
        assert_eq!(size_of::<PackOptions>(), 24);
    }
}
