//! [`ShapeError`]: a tensor argument of a module has the wrong shape or value. Shared by every
//! module of the field and by the renderer and the loss.

/// A tensor argument of a field module has the wrong shape or value.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ShapeError {
    /// The shape differs from what the module expects (`_` = any size).
    #[error("{input}: expected shape {expected}, got {got:?}")]
    Mismatch {
        /// The argument, with its symbolic shape.
        input: String,
        /// The expected shape, `_` for a free dimension.
        expected: String,
        /// The shape received.
        got: Vec<usize>,
    },
    /// A dimension that must be at least 1 is 0.
    #[error("{input}: must not be empty")]
    Empty {
        /// The argument or dimension.
        input: String,
    },
    /// A scalar argument is out of its range.
    #[error("{input}: expected {expected}")]
    InvalidArgument {
        /// The argument.
        input: String,
        /// What was expected and what came.
        expected: String,
    },
}

impl ShapeError {
    /// Checks `got` against `expected` (`None` = any size).
    pub fn check(input: &str, got: &[usize], expected: &[Option<usize>]) -> Result<(), ShapeError> {
        let matches = got.len() == expected.len()
            && got
                .iter()
                .zip(expected)
                .all(|(g, e)| e.is_none_or(|e| e == *g));
        if matches {
            return Ok(());
        }
        let dims: Vec<String> = expected
            .iter()
            .map(|e| e.map_or_else(|| "_".to_string(), |e| e.to_string()))
            .collect();
        Err(ShapeError::Mismatch {
            input: input.to_string(),
            expected: format!("[{}]", dims.join(", ")),
            got: got.to_vec(),
        })
    }

    /// An empty-dimension error for `input`.
    pub fn empty(input: &str) -> ShapeError {
        ShapeError::Empty {
            input: input.to_string(),
        }
    }

    /// An out-of-range scalar error for `input`.
    pub fn value(input: &str, expected: String) -> ShapeError {
        ShapeError::InvalidArgument {
            input: input.to_string(),
            expected,
        }
    }
}
