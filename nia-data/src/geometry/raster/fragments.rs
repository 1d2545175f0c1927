//! The rasteriser's output buffer: per pixel, the depth, the covering face and its
//! barycentrics; cleared and reused between views, read as a mask or an interpolated attribute.

use glam::Vec3;
use rayon::prelude::*;

use super::{validate_faces, MeshError};

/// Pixels per rayon task when clearing buffers.
const CLEAR_MIN_LEN: usize = 1 << 14;

/// Face value of a pixel no triangle covers.
pub const EMPTY_FACE: u32 = u32::MAX;

/// The rasteriser's output, all [H * W] row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Fragments {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// [H * W] camera depth `z_c` of the nearest surface, metres; `+inf` where empty.
    pub depth: Vec<f32>,
    /// [H * W] index of the covering face; [`EMPTY_FACE`] where empty.
    pub face: Vec<u32>,
    /// [H * W] perspective-correct barycentrics in that face (sum 1); zeros where empty.
    pub bary: Vec<[f32; 3]>,
}

impl Fragments {
    /// Every face index the fragments hold addresses `faces` (checked before reading it).
    pub(crate) fn check_face_indices(
        &self,
        what: &'static str,
        faces: &[[u32; 3]],
    ) -> Result<(), MeshError> {
        match self
            .face
            .iter()
            .find(|f| **f != EMPTY_FACE && **f as usize >= faces.len())
        {
            Some(bad) => Err(MeshError::Length {
                what,
                field: "faces",
                got: faces.len(),
                expected: *bad as usize + 1,
            }),
            None => Ok(()),
        }
    }

    /// An empty buffer (nothing drawn).
    pub fn empty(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Fragments {
            width,
            height,
            depth: vec![f32::INFINITY; n],
            face: vec![EMPTY_FACE; n],
            bary: vec![[0.0; 3]; n],
        }
    }

    /// Resizes to `width x height` and clears every pixel (in parallel, reusing the memory).
    pub fn reset(&mut self, width: u32, height: u32) {
        let n = width as usize * height as usize;
        if self.depth.len() != n || self.face.len() != n || self.bary.len() != n {
            // Fresh buffers: `vec!` of zeros maps lazily-zeroed pages.
            *self = Fragments::empty(width, height);
            return;
        }
        self.width = width;
        self.height = height;
        self.depth
            .par_iter_mut()
            .with_min_len(CLEAR_MIN_LEN)
            .for_each(|d| *d = f32::INFINITY);
        self.face
            .par_iter_mut()
            .with_min_len(CLEAR_MIN_LEN)
            .for_each(|f| *f = EMPTY_FACE);
        self.bary
            .par_iter_mut()
            .with_min_len(CLEAR_MIN_LEN)
            .for_each(|b| *b = [0.0; 3]);
    }

    /// [H * W] true where a face covers the pixel.
    pub fn mask(&self) -> Vec<bool> {
        self.face.iter().map(|f| *f != EMPTY_FACE).collect()
    }

    /// Perspective-correct interpolation of a per-vertex attribute ([V] values, e.g. world
    /// positions) at every pixel: `None` where empty. `faces` must be the faces that were
    /// rasterised.
    pub fn interpolate(
        &self,
        faces: &[[u32; 3]],
        attribute: &[Vec3],
    ) -> Result<Vec<Option<Vec3>>, MeshError> {
        const WHAT: &str = "Fragments::interpolate";
        validate_faces(WHAT, "attribute", attribute.len(), faces)?;
        self.check_face_indices(WHAT, faces)?;
        Ok(self
            .face
            .par_iter()
            .zip(self.bary.par_iter())
            .map(|(&f, b)| {
                (f != EMPTY_FACE).then(|| {
                    let [i, j, k] = faces[f as usize];
                    attribute[i as usize] * b[0]
                        + attribute[j as usize] * b[1]
                        + attribute[k as usize] * b[2]
                })
            })
            .collect())
    }
}
