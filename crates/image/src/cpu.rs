//! What the CPU can run, asked in one place: every crate's vector kernels
//! (WTA, SGM, census, medians, k-means, mean shift, RGB rectification) pick their AVX2 copy
//! through [`avx2`], so one answer holds for a whole run and a test can
//! reason about which path it exercised.

/// True when the AVX2 kernels can run here. POPCNT, which the SGM kernels
/// also use and every AVX2 CPU has, is checked with it. Always false off
/// x86-64 (the ARM926 board has no SIMD). The standard library caches the
/// answer, so asking per call costs an atomic load.
pub fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
