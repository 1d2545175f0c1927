//! Weights from the user's PyTorch files (`torch.save(state_dict)`) into a module through
//! burn-store's [`PytorchStore`], with every check an import needs: each parameter present,
//! of the module's shape, float32, and no tensor the module has no place for. The encoder's
//! torchvision import and the LPIPS loaders name the keys; this module does the rest, and each
//! caller turns an [`ImportFailure`] into its own typed error naming the file.

use std::path::Path;

use burn::module::Module;
use burn::store::{ApplyError, ModuleSnapshot, ModuleStore, PytorchStore};
use burn::tensor::DType;

/// Keys listed in a message before "...".
const PREVIEW_KEYS: usize = 4;

/// The first [`PREVIEW_KEYS`] keys, quoted and comma-separated.
pub fn preview(keys: &[String]) -> String {
    let mut text = keys
        .iter()
        .take(PREVIEW_KEYS)
        .map(|k| format!("`{k}`"))
        .collect::<Vec<_>>()
        .join(", ");
    if keys.len() > PREVIEW_KEYS {
        text.push_str(", ...");
    }
    text
}

/// ` (N more tensors have mismatched shapes)`, or nothing for N = 0.
pub fn others_note(others: usize) -> String {
    if others == 0 {
        String::new()
    } else {
        format!(" ({others} more tensors have mismatched shapes)")
    }
}

/// How a file's keys relate to a module's parameter paths.
pub struct KeyRules<'a> {
    /// (regex, replacement) from file keys to module paths.
    pub remapping: &'a [(String, String)],
    /// Whether a (remapped) key is one the file must provide or one the module must take:
    /// such keys must load; anything else in the file is ignored.
    pub owned: &'a dyn Fn(&str) -> bool,
    /// Module path -> key in the file, for messages.
    pub file_key: &'a dyn Fn(&str) -> String,
}

/// Why an import failed; tensors are named by their key in the file.
#[derive(Debug, Clone, PartialEq)]
pub enum ImportFailure {
    /// The file is not a readable PyTorch state dict.
    Read(String),
    /// A tensor is stored with another element type than float32.
    UnsupportedDType { tensor: String, found: DType },
    /// The shapes of `others + 1` tensors differ from the module's; the first is named.
    ShapeMismatch {
        tensor: String,
        expected: Vec<usize>,
        found: Vec<usize>,
        others: usize,
    },
    /// Any other per-tensor failure reported by burn-store.
    Tensor { tensor: String, message: String },
    /// Owned tensors in the file with no place in the module, sorted.
    Unexpected(Vec<String>),
    /// Parameters of the module the file does not hold, in parameter order.
    Missing(Vec<String>),
}

/// Loads `file` into `module` under `rules`. Indices are not renumbered: the remapping gives
/// the module's indices, and burn-store's renumbering would let a file lacking one layer load
/// the next one in its place.
pub fn import<M: Module>(module: M, file: &Path, rules: &KeyRules<'_>) -> Result<M, ImportFailure> {
    let mut module = module;
    let mut store = PytorchStore::from_file(file);
    for (from, to) in rules.remapping {
        store = store.with_key_remapping(from, to);
    }
    let mut store = store
        .map_indices_contiguous(false)
        .allow_partial(true)
        .validate(false);
    let read = |e: &dyn std::fmt::Display| ImportFailure::Read(e.to_string());
    // A float64/float16 tensor would load as itself and mix element types in the forward.
    let tensors = store.get_all_tensors().map_err(|e| read(&e))?;
    if let Some(t) = tensors
        .values()
        .find(|t| (rules.owned)(&t.name) && t.dtype != DType::F32)
    {
        return Err(ImportFailure::UnsupportedDType {
            tensor: (rules.file_key)(&t.name),
            found: t.dtype,
        });
    }
    let result = module.load_from(&mut store).map_err(|e| read(&e))?;
    let mut shape_errors = Vec::new();
    for error in &result.errors {
        match error {
            ApplyError::ShapeMismatch {
                path,
                expected,
                found,
            } => shape_errors.push((path, expected.to_vec(), found.to_vec())),
            ApplyError::DTypeMismatch { path, .. }
            | ApplyError::AdapterError { path, .. }
            | ApplyError::LoadError { path, .. } => {
                return Err(ImportFailure::Tensor {
                    tensor: (rules.file_key)(path),
                    message: error.to_string(),
                })
            }
        }
    }
    if let Some((path, expected, found)) = shape_errors.first() {
        return Err(ImportFailure::ShapeMismatch {
            tensor: (rules.file_key)(path),
            expected: expected.clone(),
            found: found.clone(),
            others: shape_errors.len() - 1,
        });
    }
    let mut unexpected: Vec<String> = result
        .unused
        .iter()
        .filter(|k| (rules.owned)(k))
        .map(|k| (rules.file_key)(k))
        .collect();
    if !unexpected.is_empty() {
        unexpected.sort();
        return Err(ImportFailure::Unexpected(unexpected));
    }
    if !result.missing.is_empty() {
        let missing = result
            .missing
            .iter()
            .map(|(p, _)| (rules.file_key)(p))
            .collect();
        return Err(ImportFailure::Missing(missing));
    }
    Ok(module)
}
