//! Backend selection at run time (burn 0.22: the `Device` picks the backend).

use burn::tensor::Device;

/// The compute backends nia-rs supports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// burn-ndarray on the CPU (the reference backend for tests).
    Ndarray,
    /// burn's flex CPU backend.
    Flex,
    /// wgpu (Vulkan/Metal/DX12; Mesa lavapipe without a GPU). Needs the `wgpu` feature.
    Wgpu,
}

/// Error when a backend was not compiled in.
#[derive(Debug, thiserror::Error)]
#[error("backend `{0}` is not available in this build (rebuild with `--features wgpu`)")]
pub struct BackendUnavailable(pub &'static str);

impl std::str::FromStr for Backend {
    type Err = String;

    /// `ndarray`, `flex` or `wgpu`, in any case.
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "ndarray" => Ok(Backend::Ndarray),
            "flex" => Ok(Backend::Flex),
            "wgpu" => Ok(Backend::Wgpu),
            other => Err(format!(
                "unknown backend `{other}` (expected ndarray, flex or wgpu)"
            )),
        }
    }
}

impl Backend {
    /// The name burn's `BURN_DEVICE` variable (and our configs) use for this backend.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Ndarray => "ndarray",
            Backend::Flex => "flex",
            Backend::Wgpu => "wgpu",
        }
    }

    /// Whether this backend runs on a GPU (a model trained there renders on the CPU unless
    /// told otherwise).
    pub fn is_gpu(self) -> bool {
        matches!(self, Backend::Wgpu)
    }

    /// The inference device of this backend.
    pub fn device(self) -> Result<Device, BackendUnavailable> {
        match self {
            // burn 0.22 deprecates ndarray in favour of flex; the user asked for ndarray, so it
            // stays supported (and is the reference backend of the tests).
            #[allow(deprecated)]
            Backend::Ndarray => Ok(Device::ndarray()),
            Backend::Flex => Ok(Device::flex()),
            #[cfg(feature = "wgpu")]
            Backend::Wgpu => Ok(Device::wgpu(Default::default())),
            #[cfg(not(feature = "wgpu"))]
            Backend::Wgpu => Err(BackendUnavailable("wgpu")),
        }
    }
}
