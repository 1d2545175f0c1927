//! Per-view vertex visibility, computed once per frame and view and cached on disk.
//!
//! Each entry is one file `<dir>/<subject>/f<frame>_v<view>.vis` holding a key of everything
//! the visibility depends on ([`VisibilityKey`]: a hash of the vertex positions and of the
//! faces, the camera's `K`, `R`, `T` and image size, the depth tolerance, and
//! [`VIS_CACHE_VERSION`]) followed by the [V] 0/1 values and a checksum. A lookup whose key
//! differs from the stored one (new vertices, another resolution, another tolerance, another
//! algorithm version) recomputes and overwrites the entry; a truncated or corrupt file is
//! treated the same way. Files are written atomically (temporary file + rename), so loader
//! threads may share one cache.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec3;

use super::error::DatasetError;
use crate::geometry::camera::Camera;
use crate::geometry::visibility::visibility;

/// Bump when the visibility algorithm (or this file format) changes: every cached entry then
/// misses and is recomputed.
pub const VIS_CACHE_VERSION: u32 = 1;

const MAGIC: &[u8; 8] = b"NIAVIS\x00\x01";

/// 64-bit FNV-1a: a stable hash (the same on every platform and Rust version, unlike
/// `std::hash`), used to fingerprint vertex and face arrays.
pub fn fnv1a64(bytes: impl IntoIterator<Item = u8>) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Everything a vertex visibility depends on.
#[derive(Debug, Clone, PartialEq)]
pub struct VisibilityKey {
    pub version: u32,
    pub num_vertices: u64,
    /// FNV-1a of the vertex coordinates' f32 bits.
    pub vertices_hash: u64,
    pub num_faces: u64,
    /// FNV-1a of the face indices.
    pub faces_hash: u64,
    /// `K` (9, column-major), `R` (9, column-major), `T` (3): the camera the visibility is
    /// computed in (the loaded, undistorted and resized image's).
    pub camera: [f32; 21],
    pub width: u32,
    pub height: u32,
    pub depth_tol_m: f32,
}

impl VisibilityKey {
    pub fn new(camera: &Camera, vertices: &[Vec3], faces: &[[u32; 3]], depth_tol_m: f32) -> Self {
        let vertices_hash = fnv1a64(
            vertices
                .iter()
                .flat_map(|v| v.to_array())
                .flat_map(|x| x.to_bits().to_le_bytes()),
        );
        let faces_hash = fnv1a64(faces.iter().flatten().flat_map(|i| i.to_le_bytes()));
        let mut cam = [0.0f32; 21];
        cam[..9].copy_from_slice(&camera.k.to_cols_array());
        cam[9..18].copy_from_slice(&camera.r.to_cols_array());
        cam[18..].copy_from_slice(&camera.t.to_array());
        VisibilityKey {
            version: VIS_CACHE_VERSION,
            num_vertices: vertices.len() as u64,
            vertices_hash,
            num_faces: faces.len() as u64,
            faces_hash,
            camera: cam,
            width: camera.width,
            height: camera.height,
            depth_tol_m,
        }
    }

    /// Little-endian serialisation (compared byte for byte).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(128);
        b.extend(self.version.to_le_bytes());
        b.extend(self.num_vertices.to_le_bytes());
        b.extend(self.vertices_hash.to_le_bytes());
        b.extend(self.num_faces.to_le_bytes());
        b.extend(self.faces_hash.to_le_bytes());
        for c in self.camera {
            b.extend(c.to_bits().to_le_bytes());
        }
        b.extend(self.width.to_le_bytes());
        b.extend(self.height.to_le_bytes());
        b.extend(self.depth_tol_m.to_bits().to_le_bytes());
        b
    }
}

/// A visibility cache rooted at a folder, with hit/miss counters.
#[derive(Debug)]
pub struct VisibilityCache {
    dir: PathBuf,
    hits: AtomicU64,
    misses: AtomicU64,
}

impl VisibilityCache {
    /// A cache in `dir` (created on first write).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        VisibilityCache {
            dir: dir.into(),
            hits: AtomicU64::new(0),
            misses: AtomicU64::new(0),
        }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// `(hits, misses)` since creation.
    pub fn stats(&self) -> (u64, u64) {
        (
            self.hits.load(Ordering::Relaxed),
            self.misses.load(Ordering::Relaxed),
        )
    }

    /// The file of one entry.
    pub fn entry_path(&self, subject: &str, frame: usize, view: usize) -> PathBuf {
        self.dir
            .join(sanitize(subject))
            .join(format!("f{frame:06}_v{view:03}.vis"))
    }

    /// The cached values when the file exists and its key equals `key`.
    pub fn read(&self, path: &Path, key: &VisibilityKey) -> Option<Vec<u8>> {
        let bytes = std::fs::read(path).ok()?;
        let kb = key.to_bytes();
        let rest = bytes.strip_prefix(MAGIC.as_slice())?;
        let klen = u32::from_le_bytes(rest.get(..4)?.try_into().ok()?) as usize;
        let rest = &rest[4..];
        if rest.get(..klen)? != kb.as_slice() {
            return None;
        }
        let rest = &rest[klen..];
        let n = u64::from_le_bytes(rest.get(..8)?.try_into().ok()?) as usize;
        let rest = &rest[8..];
        let values = rest.get(..n)?;
        let sum = u64::from_le_bytes(rest.get(n..n + 8)?.try_into().ok()?);
        (rest.len() == n + 8
            && n as u64 == key.num_vertices
            && sum == fnv1a64(values.iter().copied()))
        .then(|| values.to_vec())
    }

    fn write(&self, path: &Path, key: &VisibilityKey, values: &[u8]) -> Result<(), DatasetError> {
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|source| DatasetError::Io {
                path: parent.to_path_buf(),
                source,
            })?;
        }
        let kb = key.to_bytes();
        let mut bytes = Vec::with_capacity(MAGIC.len() + 4 + kb.len() + 16 + values.len());
        bytes.extend_from_slice(MAGIC);
        bytes.extend((kb.len() as u32).to_le_bytes());
        bytes.extend(&kb);
        bytes.extend((values.len() as u64).to_le_bytes());
        bytes.extend_from_slice(values);
        bytes.extend(fnv1a64(values.iter().copied()).to_le_bytes());
        crate::formats::write_atomic(path, &bytes)?;
        Ok(())
    }

    /// The [V] 0/1 visibility the query asks for: from the cache when its key matches, else
    /// computed with [`crate::geometry::visibility::visibility`] and stored.
    pub fn get_or_compute(&self, query: &VisibilityQuery<'_>) -> Result<Vec<u8>, DatasetError> {
        let key = query.key();
        let path = self.entry_path(query.subject, query.frame, query.view);
        if let Some(v) = self.read(&path, &key) {
            self.hits.fetch_add(1, Ordering::Relaxed);
            return Ok(v);
        }
        self.misses.fetch_add(1, Ordering::Relaxed);
        let values = compute(query)?;
        self.write(&path, &key, &values)?;
        Ok(values)
    }
}

/// One vertex visibility to look up or compute: `vertices` (with their `faces`) seen by
/// `camera`, for `subject`'s `frame` and `view` (which name the cache entry and errors).
#[derive(Debug, Clone, Copy)]
pub struct VisibilityQuery<'a> {
    pub subject: &'a str,
    pub frame: usize,
    pub view: usize,
    pub camera: &'a Camera,
    pub vertices: &'a [Vec3],
    pub faces: &'a [[u32; 3]],
    pub depth_tol_m: f32,
}

impl VisibilityQuery<'_> {
    /// The cache key of the query's inputs.
    pub fn key(&self) -> VisibilityKey {
        VisibilityKey::new(self.camera, self.vertices, self.faces, self.depth_tol_m)
    }
}

/// Visibility without a cache, errors attributed to the subject/frame/view.
pub fn compute(query: &VisibilityQuery<'_>) -> Result<Vec<u8>, DatasetError> {
    let VisibilityQuery {
        subject,
        frame,
        view,
        camera,
        vertices,
        faces,
        depth_tol_m,
    } = *query;
    visibility(camera, vertices, faces, depth_tol_m).map_err(|source| DatasetError::Visibility {
        subject: subject.to_string(),
        frame,
        view,
        source,
    })
}

/// A subject name usable as one path component.
fn sanitize(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "-_.()".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}
