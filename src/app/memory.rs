//! The process's memory as a user's `top` sees it: the peak resident set (Linux's VmHWM; the
//! bench runs each decimation in a process of its own to measure it), and the allocator setting
//! that keeps it near what the heap holds.

/// Blocks at least this large come straight from the OS and go back to it when freed.
/// Why: glibc raises this threshold each time it frees such a block (up to 32 MB), after which
/// the candidate test's per-candidate buffers (up to a few MB late in a run) came from the heap
/// and fragmented it: the bunny's live heap stays under 22 MB, its resident set reached 44 MB on
/// two threads (10^6 bytes). Fixed at 1 MiB: 38 MB, 1.3 s of system time (64 KiB: 37 MB, 2.7 s;
/// glibc's default 0.5 s), the same wall time within noise (76–79 s).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MMAP_THRESHOLD: libc::c_int = 1024 * 1024;

/// Sets the allocator up for a long decimation (glibc: a fixed mmap threshold, see
/// `MMAP_THRESHOLD`); elsewhere nothing. Call once, before the work starts.
pub fn keep_heap_compact() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes glibc's allocation policy; it is safe to call at any time.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD);
    }
}

/// Peak resident set size since the process started, in MB
/// (10^6 bytes); `None` where the OS does not say.
pub fn peak_rss_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let l = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = l.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0 / 1e6)
}

/// Rounds of the decimation between two [`trim_heap`] calls.
/// Why: a round frees its candidates' buffers, and what the arenas keep of them stays resident;
/// trimmed every 16 rounds (~250 calls on the bunny, no time that a run shows) the bunny's
/// peak on two threads was 34.2 and 34.0 MB, untrimmed 34.4 and 36.9 MB.
pub const TRIM_EVERY_ROUNDS: u64 = 16;

/// Hands the free pages of every heap arena back to the OS (glibc's `malloc_trim`).
pub fn trim_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free memory to the OS; it is safe to call at any time.
    unsafe {
        libc::malloc_trim(0);
    }
}
