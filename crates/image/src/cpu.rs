//! What the CPU can run, asked once per process: the one place the crates
//! of stereolink detect instruction sets, so that every kernel with an
//! AVX2 copy (matchers, refinement, rectification) decides alike.

/// True when the AVX2 kernels can run here. POPCNT is checked too (the
/// SGM kernels use it; every AVX2 CPU has it). Always false off x86-64.
pub fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
