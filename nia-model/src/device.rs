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

    /// What a user should know before this backend's first calls in a process, for the
    /// binaries to print (`None` on the CPU backends). On wgpu each new kernel shape is
    /// compiled and its matrix products tuned on first use: on an NVIDIA H200 with empty
    /// caches a paper-size first forward took 61-77 s, a later process 17 s (docs/speed.md).
    pub fn start_up_note(self) -> Option<&'static str> {
        match self {
            Backend::Ndarray | Backend::Flex => None,
            Backend::Wgpu => Some(
                "wgpu: the first calls of a process compile and tune GPU kernels, a minute or \
                 more on a machine new to nia-rs; later processes reuse cubecl's choices in \
                 ~/.cache/cubecl and the driver's shader cache",
            ),
        }
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

/// One compute device: a backend and, for GPU backends, which GPU (`wgpu:1`: the second
/// discrete GPU). Written `flex`, `ndarray`, `wgpu` or `wgpu:N` in configs and flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceSpec {
    pub backend: Backend,
    /// GPU index for GPU backends (`None`: the system's default adapter); CPU backends have
    /// one device and take no index.
    pub index: Option<usize>,
}

/// A device that cannot exist.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    #[error(transparent)]
    Unavailable(#[from] BackendUnavailable),
    #[error(
        "`{backend}:{index}`: {backend} is a CPU backend with a single device (write `{backend}`)"
    )]
    IndexedCpu { backend: &'static str, index: usize },
    #[error(
        "`{0}`: wgpu found no GPU adapter. Install the GPU's driver and the Vulkan loader \
         (Debian/Ubuntu: `apt-get install libvulkan1`), or `mesa-vulkan-drivers` for a slow \
         software one; `VK_DRIVER_FILES` names the driver's ICD file where it is not found"
    )]
    NoAdapter(String),
}

impl DeviceSpec {
    /// The default device of `backend`.
    pub fn of(backend: Backend) -> Self {
        DeviceSpec {
            backend,
            index: None,
        }
    }

    /// The device (inference mode; `.autodiff()` for training).
    pub fn device(self) -> Result<Device, DeviceError> {
        match (self.backend, self.index) {
            (Backend::Ndarray | Backend::Flex, Some(index)) => Err(DeviceError::IndexedCpu {
                backend: self.backend.name(),
                index,
            }),
            #[cfg(feature = "wgpu")]
            (Backend::Wgpu, Some(index)) => probe_gpu(
                Device::wgpu(burn::tensor::DeviceKind::DiscreteGpu(index)),
                self,
            ),
            #[cfg(feature = "wgpu")]
            (Backend::Wgpu, None) => probe_gpu(Backend::Wgpu.device()?, self),
            (backend, _) => Ok(backend.device()?),
        }
    }
}

/// Whether a Vulkan driver is installed (Linux): an ICD manifest in the loader's standard
/// folders, or one named by `VK_ICD_FILENAMES` / `VK_DRIVER_FILES`. Without one wgpu falls
/// back to Mesa's OpenGL (llvmpipe) on a machine without a GPU, where a test's kernels crawl
/// (a 14-minute `wgpu_matches_ndarray` was seen); the wgpu tests are not run there.
#[cfg(target_os = "linux")]
pub fn vulkan_driver_installed() -> bool {
    if ["VK_ICD_FILENAMES", "VK_DRIVER_FILES"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
    {
        return true;
    }
    [
        "/usr/share/vulkan/icd.d",
        "/usr/local/share/vulkan/icd.d",
        "/etc/vulkan/icd.d",
    ]
    .iter()
    .filter_map(|dir| std::fs::read_dir(dir).ok())
    .flatten()
    .flatten()
    .any(|entry| entry.path().extension().is_some_and(|e| e == "json"))
}

/// Elsewhere wgpu's own backends (Metal, DX12) are fast enough.
#[cfg(not(target_os = "linux"))]
pub fn vulkan_driver_installed() -> bool {
    true
}

/// wgpu picks its adapter at the first operation, and without one burn 0.22 panics in a worker
/// thread (`AdapterUnavailable`, then `RecvError` here). One tiny operation, caught, turns that
/// into [`DeviceError::NoAdapter`]; the worker's own panic message still reaches stderr.
#[cfg(feature = "wgpu")]
fn probe_gpu(device: Device, spec: DeviceSpec) -> Result<Device, DeviceError> {
    use burn::tensor::Tensor;
    let probe = device.clone();
    let sum = std::panic::catch_unwind(std::panic::AssertUnwindSafe(move || {
        Tensor::<1>::from_floats([1.0, 2.0], &probe)
            .sum()
            .into_scalar::<f32>()
    }));
    match sum {
        Ok(3.0) => Ok(device),
        _ => Err(DeviceError::NoAdapter(spec.to_string())),
    }
}

impl std::fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.index {
            Some(i) => write!(f, "{}:{i}", self.backend.name()),
            None => f.write_str(self.backend.name()),
        }
    }
}

impl std::str::FromStr for DeviceSpec {
    type Err = String;

    /// `flex`, `ndarray`, `wgpu` or `wgpu:N`.
    fn from_str(s: &str) -> Result<Self, String> {
        let (backend, index) = match s.split_once(':') {
            Some((b, i)) => (
                b,
                Some(i.trim().parse::<usize>().map_err(|_| {
                    format!("`{s}`: expected backend:index with a GPU index, e.g. wgpu:1")
                })?),
            ),
            None => (s, None),
        };
        Ok(DeviceSpec {
            backend: backend.trim().parse()?,
            index,
        })
    }
}

impl serde::Serialize for DeviceSpec {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for DeviceSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// Whether `device` computes in host memory (the flex and ndarray backends, not under
/// autodiff): where the renderers read the body volume on the host ([`crate::body_volume::HostVolume`]).
pub fn is_host(device: &Device) -> bool {
    !device.is_autodiff() && computes_on_cpu(device)
}

/// Whether `device` is a GPU backend whose kernels add `f32` atomically in global memory. burn's
/// scatter-add is then one kernel with a thread per value, of any length; without, it is one
/// serial loop per column, which Mesa's software Vulkan got wrong from 65,536 rows (so
/// [`crate::kernels::blocked_rows`] and [`crate::kernels::row_scatter`] cut it into blocks there). False on the
/// CPU backends and on cubecl's CPU runtime.
pub fn adds_floats_atomically(device: &Device) -> bool {
    #[cfg(feature = "wgpu")]
    {
        use burn_dispatch::DispatchDevice;
        let cube = |d: &DispatchDevice| match d {
            DispatchDevice::Cube(d) => cube_adds_floats_atomically(d),
            _ => false,
        };
        match device.as_dispatch() {
            DispatchDevice::Autodiff(d) => cube(&d.clone().inner()),
            d => cube(d),
        }
    }
    #[cfg(not(feature = "wgpu"))]
    {
        let _ = device;
        false
    }
}

/// [`adds_floats_atomically`] for a cubecl device: its client's atomic `f32` usage includes
/// `Add`, and it is not cubecl's CPU runtime (where burn keeps the serial kernel).
#[cfg(feature = "wgpu")]
pub fn cube_adds_floats_atomically(device: &burn_cubecl::CubeDevice) -> bool {
    use burn_cubecl::cubecl::features::AtomicUsage;
    use burn_cubecl::cubecl::ir::{ElemType, FloatKind, Type};
    let client = device.client();
    let properties = client.properties();
    properties.hardware.num_cpu_cores.is_none()
        && properties
            .atomic_type_usage(Type::atomic(ElemType::Float(FloatKind::F32)))
            .contains(AtomicUsage::Add)
}

/// Whether `device` computes on the CPU (flex or ndarray), with or without autodiff; the others
/// are GPU backends, where the renderers pad their network calls to shape buckets
/// (`renderer::shape_buckets`) and gather and scatter-add through `blocked_rows`.
pub fn computes_on_cpu(device: &Device) -> bool {
    use burn_dispatch::DispatchDevice;
    let cpu =
        |d: &DispatchDevice| matches!(d, DispatchDevice::Flex(_) | DispatchDevice::NdArray(_));
    match device.as_dispatch() {
        DispatchDevice::Autodiff(d) => cpu(&d.clone().inner()),
        d => cpu(d),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_specs_parse_print_and_refuse_nonsense() {
        for (text, backend, index) in [
            ("flex", Backend::Flex, None),
            ("ndarray", Backend::Ndarray, None),
            ("wgpu", Backend::Wgpu, None),
            ("wgpu:1", Backend::Wgpu, Some(1)),
        ] {
            let spec: DeviceSpec = text.parse().unwrap();
            assert_eq!((spec.backend, spec.index), (backend, index));
            assert_eq!(spec.to_string(), text);
        }
        for bad in ["cuda", "wgpu:x", "wgpu:-1", ""] {
            assert!(bad.parse::<DeviceSpec>().is_err(), "{bad}");
        }
        let err = "flex:1"
            .parse::<DeviceSpec>()
            .unwrap()
            .device()
            .unwrap_err();
        assert!(err.to_string().contains("single device"), "{err}");
    }

    #[test]
    fn only_the_gpu_backend_warns_of_its_start_up() {
        assert_eq!(Backend::Flex.start_up_note(), None);
        assert_eq!(Backend::Ndarray.start_up_note(), None);
        let note = Backend::Wgpu.start_up_note().unwrap();
        assert!(
            note.starts_with("wgpu:") && note.contains("~/.cache/cubecl"),
            "{note}"
        );
    }
}
