//! Handing freed heap memory back to the kernel once the gateway has started, and after each
//! SIGHUP re-read and REST change of the configuration.
//!
//! Reading the configuration builds TOML tables in memory (one line's at a time, `plant::parse`;
//! a REST change whole documents) and drops them once the config is read. glibc's
//! malloc keeps what was freed for later allocations and returns memory to the kernel only from
//! the top of its heap; the document's pages lie under the config, the lines and the image that
//! were allocated after it, so they would stay resident for the life of the process (7 MiB of the
//! 17 MiB anonymous memory in the memory benchmark). `malloc_trim(0)` gives back every whole
//! free page, wherever it lies in the heap (glibc 2.8 and later).
//!
//! Other C libraries (musl in the static image) have no `malloc_trim`; there this does nothing.
#![allow(unsafe_code)]

/// Returns the free pages of the heap to the kernel. Cheap enough for once after start-up (a walk
/// of malloc's free lists); not meant for a hot path.
pub(crate) fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: `malloc_trim` has no preconditions: it walks malloc's own free lists under
        // malloc's locks and touches no memory of ours.
        let released = unsafe { libc::malloc_trim(0) };
        tracing::debug!(
            released = released != 0,
            "free heap pages returned to the kernel"
        );
    }
}
