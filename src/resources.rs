//! What a run may use of the machine: memory, threads, time. Every size a user gives is
//! checked here against what the machine (or the image) can use, before anything large is
//! allocated, so a run that cannot fit is refused with a message instead of aborting.
//!
//! Memory available is the smallest of: the system's `MemAvailable`, the cgroup's
//! `memory.max - memory.current` (containers) and the address-space limit (`ulimit -v`) minus
//! what the process already maps. Each source is read from `/proc` or `/sys` on Linux; where
//! none is readable the check passes (the allocator then has the last word).

use crate::error::{Error, Result};

/// Makes freed buffers of any size reusable by later allocations of the process, instead of
/// unmapped at once and mapped afresh (glibc on Linux; elsewhere it does nothing). A run
/// allocates and frees frame-sized buffers stage after stage (a 12.2 MP plane is 49 MB, a
/// layer 244 MB); glibc maps every block above 32 MB straight from the kernel, so each one
/// cost page faults and zeroing again (the kernel's page clearing alone was 16% of the
/// 12.2 MP render command's CPU). Taken from the heap (and the heap not trimmed), they reuse
/// memory the run already touched: `scripts/e2e_timing.sh`'s command 3.64-3.93 s against
/// 3.08-3.39 s, same peak RSS (three alternated runs). In a batch, images in flight on their
/// own threads (issue 43) mapped and unmapped their buffers through the process's one memory
/// map: with this, 16 photos of 12.2 MP at a time on 16 cores made 111 images/minute against
/// 99 (system time 27 s against 45; one window), 2.1 MP photos on 2 cores +5% (two alternated
/// runs each, `scripts/batch_throughput.sh`). The price: a long-running process
/// keeps its largest footprint mapped (reused, not grown), and with several images in flight
/// the reuse fragments (peak RSS +15-20%). For programs (the binary calls it for `render` and
/// `batch`); a library leaves the allocator to its host.
pub fn reuse_large_allocations() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only sets allocator parameters; called before any thread starts.
    unsafe {
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, libc::c_int::MAX);
    }
}

/// Threads of a one-image run per glibc malloc arena ([`share_allocator_arenas`]).
pub const THREADS_PER_ARENA: usize = 4;

/// The malloc arenas a one-image run of `threads` workers gets: one per
/// [`THREADS_PER_ARENA`] threads, at least 2.
pub fn arenas_for(threads: usize) -> usize {
    threads.div_ceil(THREADS_PER_ARENA).max(2)
}

/// Lets a one-image run's `threads` workers share [`arenas_for`] malloc arenas instead of one
/// each (glibc on Linux; elsewhere it does nothing). By default glibc gives each thread its
/// own arena, up to 8 per core, and a block freed in one arena serves only the threads of
/// that arena: the buffers one stage's workers free stay resident beside the next stage's,
/// allocated by other workers in other arenas, and with [`reuse_large_allocations`] nothing
/// is handed back. The 12.2 MP render command at `--threads 16` on 2 cores peaked at
/// 1.40-1.51 GB (four runs) against 1.02 GB at one thread; with 4 arenas, 1.22-1.34 GB
/// (three runs), with 2, 1.14-1.20 GB (four), at the same speed here. Sharing costs lock
/// waits where the threads run at once: on the lent 16-core machine (2026-11-26, 16 threads,
/// two runs each) 4 arenas ran as fast as the default (1.10-1.12 s against 1.10-1.11 s), 2
/// took 1.16-1.24 s and 1 took 1.48-1.54 s; hence four threads per arena. Not for a batch:
/// its images in flight run on threads of their own, each reusing what its thread freed.
/// An arena limit the user set (`MALLOC_ARENA_MAX`, or `glibc.malloc.arena_max` in
/// `GLIBC_TUNABLES`) is left as it is.
pub fn share_allocator_arenas(threads: usize) {
    let env = |name: &str| std::env::var_os(name).map(|v| v.to_string_lossy().into_owned());
    if arena_limit_set(env("MALLOC_ARENA_MAX").as_deref(), env("GLIBC_TUNABLES").as_deref()) {
        return;
    }
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only sets an allocator parameter; called before the workers start.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, arenas_for(threads).min(libc::c_int::MAX as usize) as libc::c_int);
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    let _ = threads;
}

/// Whether the environment sets glibc's arena limit: `MALLOC_ARENA_MAX`, or
/// `glibc.malloc.arena_max` among the `GLIBC_TUNABLES` (`name=value` pairs joined by `:`).
fn arena_limit_set(malloc_arena_max: Option<&str>, tunables: Option<&str>) -> bool {
    malloc_arena_max.is_some() || tunables.is_some_and(|t| t.split(':').any(|kv| kv.split('=').next() == Some("glibc.malloc.arena_max")))
}

/// Peak bytes per pixel of one photo + depth (+ matte) render with the classical stages:
/// measured 97 B/px for the whole 12 MP command (README, Performance), plus margin.
pub const RENDER_BYTES_PER_PIXEL: u64 = 120;

/// Peak bytes per pixel of rendering ready-made layers, per layer (20 B of RGBAD each) plus
/// the compositor, radii and kernel scratch (~40 B).
pub fn layers_bytes_per_pixel(layers: usize) -> u64 {
    20 * layers as u64 + 40
}

/// Bytes this process can still allocate, if the system says (see the module doc).
pub fn available_bytes() -> Option<u64> {
    [mem_available(), cgroup_headroom(), address_space_headroom()].into_iter().flatten().min()
}

fn read(path: &str) -> Option<String> {
    std::fs::read_to_string(path).ok()
}

/// `MemAvailable` of /proc/meminfo.
fn mem_available() -> Option<u64> {
    let text = read("/proc/meminfo")?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    kib_field(line)
}

/// `1234 kB` after the colon, in bytes.
fn kib_field(line: &str) -> Option<u64> {
    let v: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(v.saturating_mul(1024))
}

/// cgroup v2 limit minus usage of this process's cgroup.
fn cgroup_headroom() -> Option<u64> {
    let cg = read("/proc/self/cgroup")?;
    let rel = cg.lines().find_map(|l| l.strip_prefix("0::"))?.trim();
    let dir = format!("/sys/fs/cgroup{}", if rel == "/" { "" } else { rel });
    let max: u64 = read(&format!("{dir}/memory.max"))?.trim().parse().ok()?; // "max" → None
    let cur: u64 = read(&format!("{dir}/memory.current"))?.trim().parse().ok()?;
    Some(max.saturating_sub(cur))
}

/// `ulimit -v` minus the address space already mapped.
fn address_space_headroom() -> Option<u64> {
    let limits = read("/proc/self/limits")?;
    let line = limits.lines().find(|l| l.starts_with("Max address space"))?;
    let soft: u64 = line.split_whitespace().nth(3)?.parse().ok()?; // "unlimited" → None
    let status = read("/proc/self/status")?;
    let vm = status.lines().find(|l| l.starts_with("VmSize:")).and_then(kib_field).unwrap_or(0);
    // Thread stacks and allocator arenas are mapped before they are touched: keep 256 MiB.
    Some(soft.saturating_sub(vm).saturating_sub(256 << 20))
}

/// Human-readable size.
pub fn format_bytes(b: u64) -> String {
    const GIB: f64 = (1u64 << 30) as f64;
    const MIB: f64 = (1u64 << 20) as f64;
    let b = b as f64;
    if b >= GIB { format!("{:.1} GB", b / GIB) } else { format!("{:.0} MB", (b / MIB).ceil()) }
}

/// Refuses (usage error) a job that needs `needed` bytes when less is available. `what`
/// says what needs it, e.g. "photo.jpg (10000x10000) through the pipeline".
pub fn check_memory(what: &str, needed: u64) -> Result<()> {
    check_memory_against(what, needed, available_bytes())
}

fn check_memory_against(what: &str, needed: u64, available: Option<u64>) -> Result<()> {
    match available {
        Some(avail) if needed > avail => Err(Error::usage(format!(
            "{what} needs about {} of memory but only {} is available; use a smaller image (or free memory, raise the limit)",
            format_bytes(needed),
            format_bytes(avail)
        ))),
        _ => Ok(()),
    }
}

/// Most worker threads accepted: more than this many per core only adds overhead (and a
/// huge count spent minutes creating threads before any work).
pub const MAX_THREADS_PER_CORE: usize = 16;

/// The machine's cores as the system reports them to this process (1 when it does not say).
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |c| c.get())
}

/// The most worker threads a run accepts: max(64, 16 × cores); and the core count.
pub fn max_threads() -> (usize, usize) {
    let cores = cores();
    ((MAX_THREADS_PER_CORE * cores).max(64), cores)
}

/// Checks a user-given worker-thread count: 1 ..= [`max_threads`].
pub fn check_threads(n: usize, flag: &str) -> Result<usize> {
    let (max, cores) = max_threads();
    if n == 0 || n > max {
        return Err(Error::usage(format!("{flag} must be between 1 and {max} ({cores} cores here), got {n}")));
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `MALLOC_ARENA_MAX`, or the arena limit among other glibc tunables, is the user's
    /// choice; other tunables are not.
    #[test]
    fn a_users_arena_limit_is_kept() {
        assert!(!arena_limit_set(None, None));
        assert!(arena_limit_set(Some("1"), None));
        assert!(arena_limit_set(None, Some("glibc.malloc.arena_max=2")));
        assert!(arena_limit_set(None, Some("glibc.malloc.tcache_count=0:glibc.malloc.arena_max=8")));
        assert!(!arena_limit_set(None, Some("glibc.malloc.arena_test=2:glibc.malloc.hugetlb=1")));
    }

    /// Four threads per arena (what the lent 16-core machine ran at full speed), never fewer
    /// than two arenas.
    #[test]
    fn arenas_are_one_per_four_threads_and_at_least_two() {
        for (threads, arenas) in [(1, 2), (2, 2), (8, 2), (9, 3), (16, 4), (17, 5), (64, 16)] {
            assert_eq!(arenas_for(threads), arenas, "{threads} threads");
        }
    }

    #[test]
    fn memory_check_names_both_sizes() {
        assert!(check_memory_against("x", 10, Some(20)).is_ok());
        assert!(check_memory_against("x", 10, None).is_ok());
        let e = check_memory_against("big.png (10000x10000)", 12 << 30, Some(3 << 30)).unwrap_err().to_string();
        assert!(e.contains("big.png") && e.contains("12.0 GB") && e.contains("3.0 GB"), "{e}");
        // This machine reports something, and a sane amount.
        if let Some(a) = available_bytes() {
            assert!(a > 0);
        }
    }

    #[test]
    fn thread_counts() {
        assert!(check_threads(1, "--threads").is_ok());
        assert!(check_threads(64, "--threads").is_ok());
        let e = check_threads(100_000, "--threads").unwrap_err().to_string();
        assert!(e.contains("--threads") && e.contains("100000"), "{e}");
        assert!(check_threads(0, "--threads").is_err());
    }
}
