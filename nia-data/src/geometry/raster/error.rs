//! The error of a mesh or per-vertex attribute that does not fit together, and the check of
//! face indices that the rasteriser and every other mesh consumer share.

use super::EMPTY_FACE;

/// A mesh or per-vertex attribute that does not fit together.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    #[error(
        "{what}: faces[{face}][{corner}] = {index}, but `{field}` has only {len} entries \
         (expected an index below {len})"
    )]
    FaceIndex {
        what: &'static str,
        field: &'static str,
        face: usize,
        corner: usize,
        index: u32,
        len: usize,
    },
    #[error("{what}: `{field}` has {got} entries, expected {expected}")]
    Length {
        what: &'static str,
        field: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("{what}: `{field}`: expected {expected}")]
    Invalid {
        what: &'static str,
        field: &'static str,
        expected: &'static str,
    },
}

/// Checks every face index against `len` entries of `field` (e.g. the vertex array).
pub fn validate_faces(
    what: &'static str,
    field: &'static str,
    len: usize,
    faces: &[[u32; 3]],
) -> Result<(), MeshError> {
    if faces.len() >= EMPTY_FACE as usize {
        return Err(MeshError::Length {
            what,
            field: "faces",
            got: faces.len(),
            expected: EMPTY_FACE as usize - 1,
        });
    }
    for (f, tri) in faces.iter().enumerate() {
        for (c, &index) in tri.iter().enumerate() {
            if index as usize >= len {
                return Err(MeshError::FaceIndex {
                    what,
                    field,
                    face: f,
                    corner: c,
                    index,
                    len,
                });
            }
        }
    }
    Ok(())
}
