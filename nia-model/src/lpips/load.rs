//! Loading LPIPS weights from the user's PyTorch files through burn-store's [`PytorchStore`]:
//!
//! - the trunk from a torchvision state dict (`torch.save(model.state_dict())`, e.g.
//!   `alexnet-owt-7be5be79.pth`, `vgg16-397923af.pth`): `features.{i}.weight` / `.bias` ->
//!   `convs.{k}.weight` / `.bias` of [`Trunk`] for the k-th conv of torchvision index i
//!   ([`super::net::ConvLayer::index`]); `classifier.*` is ignored;
//! - the heads from the package's weight file (`lpips/weights/v0.1/alex.pth`, `vgg.pth`):
//!   `lin{l}.model.1.weight` [1, C_l, 1, 1] -> `lins.{l}.weight` of [`LinearHeads`]; other keys
//!   (a whole LPIPS state dict's `net.*`, `scaling_layer.*`, `lins.*`) are ignored.
//!
//! Every parameter must be in its file with the configured shape and as float32, and a file
//! must not hold trunk convs / heads the configuration has no place for (a VGG19 or VGG16-BN
//! trunk, SqueezeNet's seven heads). Errors name the file and the tensor by its key in the
//! file.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::prelude::*;
use burn::tensor::DType;

use super::heads::LinearHeads;
use super::net::LpipsNet;
use super::trunk::Trunk;
use super::{Lpips, LpipsConfig, LpipsConfigError};
use crate::store::pytorch_import::{import, others_note, preview, ImportFailure, KeyRules};

/// Why LPIPS weights could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LpipsLoadError {
    #[error("invalid LPIPS configuration: {0}")]
    Config(#[from] LpipsConfigError),
    /// The file could not be opened or is not a readable PyTorch checkpoint (missing,
    /// truncated, not a pickled state dict; burn-store's zip reader also refuses valid
    /// `torch.save` files whose archive root, the stem of the name they were saved under, is
    /// exactly 21 characters long: see scripts/fixtures/make_resnet_fixture.py).
    #[error("{}: cannot read as a PyTorch state dict: {message}", file.display())]
    Read { file: PathBuf, message: String },
    /// A tensor's shape differs from the configured network's (e.g. published full-width
    /// weights into a narrow configuration, or AlexNet weights for VGG16).
    #[error(
        "{}: tensor `{tensor}` has shape {found:?} in the file but the LPIPS {net} \
         configuration expects {expected:?}{}",
        file.display(),
        others_note(*others)
    )]
    ShapeMismatch {
        file: PathBuf,
        /// Key in the file, e.g. `features.0.weight` or `lin0.model.1.weight`.
        tensor: String,
        expected: Vec<usize>,
        found: Vec<usize>,
        net: LpipsNet,
        /// How many further tensors mismatch.
        others: usize,
    },
    /// A tensor is stored with an element type other than float32.
    #[error("{}: tensor `{tensor}` is {found:?}, expected F32", file.display())]
    UnsupportedDType {
        file: PathBuf,
        tensor: String,
        found: DType,
    },
    /// Parameters the file does not contain.
    #[error(
        "{}: {} LPIPS {net} tensors are missing from the file: {}",
        file.display(),
        missing.len(),
        preview(missing)
    )]
    MissingTensors {
        file: PathBuf,
        net: LpipsNet,
        /// Keys in the file's naming, in parameter order.
        missing: Vec<String>,
    },
    /// Trunk or head tensors the configuration has no place for.
    #[error(
        "{}: the file has {} tensors that the LPIPS {net} network does not have: {}",
        file.display(),
        unexpected.len(),
        preview(unexpected)
    )]
    UnexpectedTensors {
        file: PathBuf,
        net: LpipsNet,
        /// Keys in the file, sorted.
        unexpected: Vec<String>,
    },
    /// Any other per-tensor failure reported by burn-store.
    #[error("{}: tensor `{tensor}`: {message}", file.display())]
    Tensor {
        file: PathBuf,
        tensor: String,
        message: String,
    },
}

/// How one file's keys relate to one module's parameter paths.
struct KeyMap {
    net: LpipsNet,
    /// (regex, replacement) from file keys to module paths.
    remapping: Vec<(String, String)>,
    /// Whether a (remapped) key is a parameter this kind of file must provide, or one the
    /// module has no place for: such keys must load, anything else is ignored.
    owned: fn(&str) -> bool,
    /// Module path -> key in the file, for messages.
    file_key: Box<dyn Fn(&str) -> String>,
}

/// torchvision `features.{i}.` -> `convs.{k}.`; keys of non-conv indices stay `features.*`
/// and count as unexpected.
fn trunk_keys(net: LpipsNet) -> KeyMap {
    let indices: Vec<usize> = net.layers().iter().map(|l| l.index).collect();
    let remapping = indices
        .iter()
        .enumerate()
        .map(|(k, i)| (format!(r"^features\.{i}\."), format!("convs.{k}.")))
        .collect();
    KeyMap {
        net,
        remapping,
        owned: |key| key.starts_with("convs.") || key.starts_with("features."),
        file_key: Box::new(move |path| match path.strip_prefix("convs.") {
            Some(rest) => {
                let (k, tail) = rest.split_once('.').unwrap_or((rest, ""));
                match k.parse::<usize>().ok().and_then(|k| indices.get(k)) {
                    Some(i) => format!("features.{i}.{tail}"),
                    None => path.to_string(),
                }
            }
            None => path.to_string(),
        }),
    }
}

/// Whether a (remapped) heads-file key is `lins.{l}.{name}`: a head parameter, or one the
/// heads have no place for (a bias, a sixth head). A whole LPIPS state dict's own `lins.{l}.
/// model.1.weight` aliases are not.
fn is_head_parameter(key: &str) -> bool {
    let parts: Vec<&str> = key.split('.').collect();
    parts.len() == 3 && parts[0] == "lins" && parts[1].parse::<usize>().is_ok()
}

/// The package's `lin{l}.model.1.` -> `lins.{l}.`.
fn heads_keys(net: LpipsNet) -> KeyMap {
    KeyMap {
        net,
        remapping: vec![(r"^lin(\d+)\.model\.1\.".into(), "lins.${1}.".into())],
        owned: is_head_parameter,
        file_key: Box::new(|path| match path.strip_prefix("lins.") {
            Some(rest) => {
                let (l, tail) = rest.split_once('.').unwrap_or((rest, ""));
                format!("lin{l}.model.1.{tail}")
            }
            None => path.to_string(),
        }),
    }
}

/// Loads `file` into `module` through `keys`, with the checks described in the module doc.
fn load_file<M: Module>(module: M, file: &Path, keys: &KeyMap) -> Result<M, LpipsLoadError> {
    let rules = KeyRules {
        remapping: &keys.remapping,
        owned: &keys.owned,
        file_key: &*keys.file_key,
    };
    let file = file.to_path_buf();
    let net = keys.net;
    import(module, &file, &rules).map_err(|failure| match failure {
        ImportFailure::Read(message) => LpipsLoadError::Read { file, message },
        ImportFailure::UnsupportedDType { tensor, found } => LpipsLoadError::UnsupportedDType {
            file,
            tensor,
            found,
        },
        ImportFailure::ShapeMismatch {
            tensor,
            expected,
            found,
            others,
        } => LpipsLoadError::ShapeMismatch {
            file,
            tensor,
            expected,
            found,
            net,
            others,
        },
        ImportFailure::Tensor { tensor, message } => LpipsLoadError::Tensor {
            file,
            tensor,
            message,
        },
        ImportFailure::Unexpected(unexpected) => LpipsLoadError::UnexpectedTensors {
            file,
            net,
            unexpected,
        },
        ImportFailure::Missing(missing) => LpipsLoadError::MissingTensors { file, net, missing },
    })
}

impl Trunk {
    /// Replaces every conv weight and bias by the one in a torchvision AlexNet / VGG16 state
    /// dict (`features.{i}.weight` / `.bias`; `classifier.*` ignored).
    ///
    /// # Errors
    /// [`LpipsLoadError`] naming `file`: unreadable, a conv tensor missing, of another shape
    /// than the trunk's, not float32, or a `features.*` tensor the trunk has no place for.
    pub fn load_torchvision(self, file: &Path) -> Result<Trunk, LpipsLoadError> {
        let keys = trunk_keys(self.net);
        load_file(self, file, &keys)
    }
}

impl LinearHeads {
    /// Replaces the five head weights by those of an `lpips` package weight file
    /// (`lin{l}.model.1.weight`, [1, C_l, 1, 1]).
    ///
    /// # Errors
    /// [`LpipsLoadError`] naming `file`: unreadable, a head missing, of another width than
    /// the configured layer's, not float32, or a head beyond the fifth.
    pub fn load_lpips(self, net: LpipsNet, file: &Path) -> Result<LinearHeads, LpipsLoadError> {
        load_file(self, file, &heads_keys(net))
    }
}

impl Lpips {
    /// The metric with the user's weights: the trunk from a torchvision state dict
    /// (`backbone`, e.g. `alexnet-owt-7be5be79.pth`) and the heads from the package's
    /// `weights/v0.1/{alex,vgg}.pth` (`heads`). Nothing is downloaded.
    ///
    /// # Errors
    /// [`LpipsLoadError`]: an invalid `config`, or a file that does not fit it (see
    /// [`Trunk::load_torchvision`], [`LinearHeads::load_lpips`]).
    pub fn load(
        config: &LpipsConfig,
        backbone: &Path,
        heads: &Path,
        device: &Device,
    ) -> Result<Lpips, LpipsLoadError> {
        let lpips = config.init(device)?;
        let net = config.net;
        Ok(Lpips {
            trunk: lpips.trunk.load_torchvision(backbone)?,
            heads: lpips.heads.load_lpips(net, heads)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn module_paths_map_back_to_file_keys() {
        let trunk = trunk_keys(LpipsNet::Alex);
        assert_eq!((trunk.file_key)("convs.0.weight"), "features.0.weight");
        assert_eq!((trunk.file_key)("convs.3.bias"), "features.8.bias");
        assert_eq!((trunk.file_key)("features.13.weight"), "features.13.weight");
        let trunk = trunk_keys(LpipsNet::Vgg);
        assert_eq!((trunk.file_key)("convs.12.weight"), "features.28.weight");
        let heads = heads_keys(LpipsNet::Vgg);
        assert_eq!((heads.file_key)("lins.4.weight"), "lin4.model.1.weight");
    }

    #[test]
    fn owned_keys_exclude_classifier_and_other_lpips_modules() {
        let trunk = trunk_keys(LpipsNet::Alex);
        assert!((trunk.owned)("convs.1.weight"));
        assert!((trunk.owned)("features.1.weight"));
        assert!(!(trunk.owned)("classifier.1.weight"));
        let heads = heads_keys(LpipsNet::Alex);
        assert!((heads.owned)("lins.0.weight"));
        assert!((heads.owned)("lins.5.weight"));
        assert!(!(heads.owned)("lins.0.model.1.weight"));
        assert!(!(heads.owned)("net.slice1.0.weight"));
    }
}
