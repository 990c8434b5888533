//! What the CPU offers beyond the build's baseline (x86-64: SSE2), for the few hot loops that
//! carry a second build of the same code for wider vectors (same arithmetic, same results).

/// Whether the CPU has AVX2 (false off x86-64; std caches the detection).
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    return std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    false
}
