//! Import of torchvision `resnet18` weights (a PyTorch `state_dict` saved with `torch.save`)
//! into the [`ImageEncoder`] trunk, through burn-store's [`PytorchStore`].
//!
//! Key mapping, torchvision -> ours:
//! - `layerK.i.downsample.0.*` -> `layerK.i.downsample.conv.*` (1x1 strided conv),
//!   `layerK.i.downsample.1.*` -> `layerK.i.downsample.bn.*` (its BatchNorm);
//! - BatchNorm `weight` / `bias` -> `gamma` / `beta` (burn-store's `PyTorchToBurnAdapter`),
//!   `running_mean` / `running_var` keep their names;
//! - everything else (`conv1.weight`, `layer1.0.conv2.weight`, ...) is identical.
//!
//! Keys the trunk does not use (`layer4.*`, `fc.*`, `*.num_batches_tracked`) are ignored. Every
//! parameter of the encoder must be in the file with the encoder's shape and as float32;
//! otherwise the import fails with an [`EncoderLoadError`] naming the file and the tensor
//! (in torchvision's naming).

use std::path::{Path, PathBuf};

use burn::tensor::DType;

use super::ImageEncoder;
use crate::store::pytorch_import::{import, others_note, preview, ImportFailure, KeyRules};

/// torchvision's `downsample` Sequential indices -> our [`super::encoder::Downsample`] fields.
const DOWNSAMPLE_REMAPPING: [(&str, &str); 2] = [
    (r"\.downsample\.0\.", ".downsample.conv."),
    (r"\.downsample\.1\.", ".downsample.bn."),
];

/// Top-level torchvision modules the trunk consists of (`layer4` and `fc` are not part of it).
const TRUNK_PREFIXES: [&str; 5] = ["conv1.", "bn1.", "layer1.", "layer2.", "layer3."];

/// BatchNorm's batch counter: torch bookkeeping with no counterpart in burn's `BatchNorm`.
const NUM_BATCHES_TRACKED: &str = ".num_batches_tracked";

/// Why a torchvision state dict could not be imported into the encoder.
#[derive(Debug, thiserror::Error)]
pub enum EncoderLoadError {
    /// The file could not be opened or is not a readable PyTorch checkpoint (missing,
    /// truncated, not a pickled state dict). burn-store's zip reader (zip 9.4.1) also refuses
    /// valid `torch.save` files whose archive root (the stem of the name they were saved
    /// under) is exactly 21 characters long ("Invalid Central Directory header"); saving
    /// under another name avoids it (scripts/fixtures/make_resnet_fixture.py explains why).
    #[error("{}: cannot read as a PyTorch state dict: {message}", file.display())]
    Read { file: PathBuf, message: String },
    /// A tensor's shape differs from the encoder's (e.g. a base-width-64 file into a
    /// base-width-8 encoder).
    #[error(
        "{}: tensor `{tensor}` has shape {found:?} in the file but the encoder (base width \
         {base_width}) expects {expected:?}{}",
        file.display(),
        others_note(*others)
    )]
    ShapeMismatch {
        file: PathBuf,
        /// torchvision key, e.g. `conv1.weight`.
        tensor: String,
        expected: Vec<usize>,
        found: Vec<usize>,
        base_width: usize,
        /// How many further tensors mismatch.
        others: usize,
    },
    /// A trunk tensor is stored with an element type other than float32.
    #[error("{}: tensor `{tensor}` is {found:?}, expected F32", file.display())]
    UnsupportedDType {
        file: PathBuf,
        tensor: String,
        found: DType,
    },
    /// Parameters of the encoder that the file does not contain.
    #[error(
        "{}: {} encoder tensors are missing from the file: {}",
        file.display(),
        missing.len(),
        preview(missing)
    )]
    MissingTensors {
        file: PathBuf,
        /// torchvision keys of the missing tensors, sorted by our parameter path.
        missing: Vec<String>,
    },
    /// Trunk tensors in the file with no place in the encoder (e.g. a third `layer1` block:
    /// a ResNet-34 file), which a ResNet-18 import must not silently drop.
    #[error(
        "{}: the file has {} tensors under conv1/bn1/layer1-3 that a ResNet-18 trunk does not \
         have: {}",
        file.display(),
        unexpected.len(),
        preview(unexpected)
    )]
    UnexpectedTensors {
        file: PathBuf,
        /// torchvision keys, sorted.
        unexpected: Vec<String>,
    },
    /// Any other per-tensor failure reported by burn-store (tensor data unreadable, wrong
    /// kind of element).
    #[error("{}: tensor `{tensor}`: {message}", file.display())]
    Tensor {
        file: PathBuf,
        tensor: String,
        message: String,
    },
}

/// Our parameter path (`layer2.0.downsample.bn.gamma`) in torchvision's naming
/// (`layer2.0.downsample.1.weight`), for messages.
fn torchvision_key(path: &str) -> String {
    let key = path
        .replace(".downsample.conv.", ".downsample.0.")
        .replace(".downsample.bn.", ".downsample.1.");
    if let Some(stem) = key.strip_suffix(".gamma") {
        format!("{stem}.weight")
    } else if let Some(stem) = key.strip_suffix(".beta") {
        format!("{stem}.bias")
    } else {
        key
    }
}

/// Whether a (remapped) file key belongs to the trunk's parameters.
fn is_trunk_parameter(key: &str) -> bool {
    TRUNK_PREFIXES.iter().any(|p| key.starts_with(p)) && !key.ends_with(NUM_BATCHES_TRACKED)
}

impl ImageEncoder {
    /// Replaces every parameter and BatchNorm running statistic of the trunk by the one stored
    /// in a torchvision ResNet `state_dict` file (`torch.save(model.state_dict(), path)`, e.g.
    /// torchvision's `resnet18-f37072fd.pth`). `layer4.*`, `fc.*` and `num_batches_tracked`
    /// are ignored.
    ///
    /// The encoder's configuration must match the file: `base_width` 64 for ResNet-18.
    ///
    /// # Errors
    /// [`EncoderLoadError`], naming `path`: unreadable file, a trunk tensor missing from the
    /// file, a shape differing from the encoder's, an element type other than float32, or a
    /// trunk tensor the encoder has no place for. The encoder is consumed either way.
    pub fn load_torchvision(self, path: &Path) -> Result<ImageEncoder, EncoderLoadError> {
        let file = path.to_path_buf();
        let base_width = self.conv1.weight.dims()[0];
        let remapping: Vec<(String, String)> = DOWNSAMPLE_REMAPPING
            .iter()
            .map(|(from, to)| (from.to_string(), to.to_string()))
            .collect();
        let rules = KeyRules {
            remapping: &remapping,
            owned: &is_trunk_parameter,
            file_key: &torchvision_key,
        };
        import(self, path, &rules).map_err(|failure| match failure {
            ImportFailure::Read(message) => EncoderLoadError::Read { file, message },
            ImportFailure::UnsupportedDType { tensor, found } => {
                EncoderLoadError::UnsupportedDType {
                    file,
                    tensor,
                    found,
                }
            }
            ImportFailure::ShapeMismatch {
                tensor,
                expected,
                found,
                others,
            } => EncoderLoadError::ShapeMismatch {
                file,
                tensor,
                expected,
                found,
                base_width,
                others,
            },
            ImportFailure::Tensor { tensor, message } => EncoderLoadError::Tensor {
                file,
                tensor,
                message,
            },
            ImportFailure::Unexpected(unexpected) => {
                EncoderLoadError::UnexpectedTensors { file, unexpected }
            }
            ImportFailure::Missing(missing) => EncoderLoadError::MissingTensors { file, missing },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn burn_paths_map_back_to_torchvision_keys() {
        assert_eq!(
            torchvision_key("layer2.0.downsample.bn.gamma"),
            "layer2.0.downsample.1.weight"
        );
        assert_eq!(
            torchvision_key("layer3.0.downsample.conv.weight"),
            "layer3.0.downsample.0.weight"
        );
        assert_eq!(torchvision_key("bn1.beta"), "bn1.bias");
        assert_eq!(
            torchvision_key("layer1.1.bn2.running_var"),
            "layer1.1.bn2.running_var"
        );
    }

    #[test]
    fn trunk_keys_exclude_layer4_fc_and_batch_counters() {
        assert!(is_trunk_parameter("layer3.1.conv2.weight"));
        assert!(is_trunk_parameter("bn1.running_mean"));
        assert!(!is_trunk_parameter("layer4.0.conv1.weight"));
        assert!(!is_trunk_parameter("fc.weight"));
        assert!(!is_trunk_parameter("layer1.0.bn1.num_batches_tracked"));
    }
}
