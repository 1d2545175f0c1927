//! The process heap's policy for tensor buffers.
//!
//! Every tensor operation of the CPU backends allocates its output, and at the paper's sizes
//! most of those buffers are tens to hundreds of MB (`[3, 65536, 128]` f32 is 100 MB). glibc's
//! malloc serves every block above its mmap threshold (at most 32 MB) with a fresh `mmap` and
//! gives it back with `munmap` when freed, so each such buffer costs page faults and the
//! kernel zeroing every page before the operation writes it. Profiled on the paper-size
//! training step (`perf record` on `nia-infer bench`), page faults, page clearing and the
//! copies into fresh pages took about a third of the time.
//!
//! [`keep_freed_memory`] makes the heap keep and reuse what tensors free: no `mmap` for large
//! blocks (they come from the heap, which then grows once and is reused) and no trimming of the
//! heap's top. What it costs: the heap stays at its high-water mark and fragments, so the peak
//! resident memory is higher (measured in docs/speed.md, "What made it fast"). Only binaries call it,
//! first thing in `main`; `NIA_HEAP=system` leaves malloc as it is, and any other value of
//! `NIA_HEAP` is refused ([`HeapError`]) rather than silently ignored.

/// What [`keep_freed_memory`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeapPolicy {
    /// glibc's malloc now keeps freed blocks (no mmap for large blocks, no trimming).
    KeepFreed,
    /// `NIA_HEAP=system` asked to leave malloc as it is.
    SystemByRequest,
    /// Not glibc (or glibc refused the settings): malloc left as it is.
    Unsupported,
}

/// The environment variable that turns the policy off (`NIA_HEAP=system`).
pub const HEAP_ENV: &str = "NIA_HEAP";

impl HeapPolicy {
    /// Short name for reports (`bench`'s JSON).
    pub fn name(self) -> &'static str {
        match self {
            HeapPolicy::KeepFreed => "keep_freed",
            HeapPolicy::SystemByRequest => "system (NIA_HEAP=system)",
            HeapPolicy::Unsupported => "system (not glibc)",
        }
    }
}

/// A value of [`HEAP_ENV`] that names no policy.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("environment variable {HEAP_ENV}={value:?}: expected `system` (leave malloc as it is) or `keep_freed` (the default; also when unset)")]
pub struct HeapError {
    /// The value found (lossy UTF-8).
    pub value: String,
}

/// Whether `value` of [`HEAP_ENV`] asks for the system's malloc settings (`Ok(true)`), for the
/// default policy (`Ok(false)`: unset, empty or `keep_freed`), or names nothing (`Err`).
/// Case-insensitive.
pub fn system_requested(value: Option<&str>) -> Result<bool, HeapError> {
    match value.map(str::trim) {
        None | Some("") => Ok(false),
        Some(v) if v.eq_ignore_ascii_case("system") => Ok(true),
        Some(v) if v.eq_ignore_ascii_case("keep_freed") => Ok(false),
        Some(v) => Err(HeapError {
            value: v.to_string(),
        }),
    }
}

static POLICY: std::sync::OnceLock<HeapPolicy> = std::sync::OnceLock::new();

/// Sets the heap policy of this process (see the module docs) on the first call and returns
/// it (later calls return the same). Call before any tensor is allocated, from a binary's
/// `main`. A value of `NIA_HEAP` that names no policy is an error, and nothing is changed.
pub fn keep_freed_memory() -> Result<HeapPolicy, HeapError> {
    if let Some(policy) = POLICY.get() {
        return Ok(*policy);
    }
    let value = std::env::var_os(HEAP_ENV).map(|v| v.to_string_lossy().into_owned());
    let system = system_requested(value.as_deref())?;
    Ok(*POLICY.get_or_init(|| {
        if system {
            HeapPolicy::SystemByRequest
        } else {
            set_glibc_keep_freed()
        }
    }))
}

/// The policy [`keep_freed_memory`] set, if it was called.
pub fn current() -> Option<HeapPolicy> {
    POLICY.get().copied()
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn set_glibc_keep_freed() -> HeapPolicy {
    // From glibc's <malloc.h>.
    const M_TRIM_THRESHOLD: libc::c_int = -1;
    const M_MMAP_MAX: libc::c_int = -4;
    // SAFETY: `mallopt` only changes malloc's tunables; it is called before other threads
    // allocate, with documented values: mmap max 0 serves every block from the heap, trim
    // threshold -1 "disables trimming completely" (mallopt(3)). A finite threshold is not
    // enough: `int` caps it at 2 GB, and the paper-size training step frees more than that at
    // the heap's top between its forward and backward (measured: 43 s per step with 2^31 - 1
    // against 17.5 s without trimming).
    let no_mmap = unsafe { libc::mallopt(M_MMAP_MAX, 0) };
    // SAFETY: as above.
    let no_trim = unsafe { libc::mallopt(M_TRIM_THRESHOLD, -1) };
    if no_mmap == 1 && no_trim == 1 {
        HeapPolicy::KeepFreed
    } else {
        HeapPolicy::Unsupported
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn set_glibc_keep_freed() -> HeapPolicy {
    HeapPolicy::Unsupported
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nia_heap_values_name_a_policy_or_are_refused() {
        assert_eq!(system_requested(None), Ok(false));
        assert_eq!(system_requested(Some("")), Ok(false));
        assert_eq!(system_requested(Some("keep_freed")), Ok(false));
        assert_eq!(system_requested(Some("system")), Ok(true));
        assert_eq!(system_requested(Some(" SYSTEM ")), Ok(true));
        let err = system_requested(Some("sytem")).unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("NIA_HEAP") && text.contains("sytem") && text.contains("`system`"),
            "{text}"
        );
    }

    /// On glibc the settings are accepted, and memory freed and allocated again after them
    /// stays usable (a large block, then a smaller and a larger one in its place).
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_accepts_the_policy_and_large_blocks_still_work() {
        if std::env::var(HEAP_ENV).is_ok() {
            return; // the caller chose the policy; nothing to check here
        }
        assert_eq!(keep_freed_memory(), Ok(HeapPolicy::KeepFreed));
        for len in [64usize << 20, 16 << 20, 96 << 20] {
            let v = vec![1.5f32; len / 4];
            assert_eq!(v.len(), len / 4);
            assert!(v.iter().step_by(4096).all(|&x| x == 1.5));
        }
    }
}
