//! What the CPU offers beyond the build's baseline (x86-64: SSE2), for the few hot loops that
//! carry a second build of the same code for wider vectors (same arithmetic, same results).

/// Whether the CPU has AVX2 (false off x86-64; std caches the detection).
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    return std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// Runs `f` compiled for AVX2 when `avx2` (from [`has_avx2`]) is true, else as the baseline
/// build: the closure is inlined into a function built with that feature, so its loops
/// vectorize wider. The same code either way: integer results are identical, and float
/// results too (no feature here fuses a multiply and an add).
#[inline(always)]
pub fn with_avx2<R>(avx2: bool, f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        #[target_feature(enable = "avx2")]
        fn wide<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        // SAFETY: `avx2` says the CPU supports AVX2.
        return unsafe { wide(f) };
    }
    let _ = avx2;
    f()
}
