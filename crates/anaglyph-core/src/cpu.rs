//! What the CPU can run, for the hot loops that carry an AVX2 + FMA build beside the
//! baseline x86-64 one (the learned features' transforms, the multi-view cost, the scene
//! prior's estimates). The binary stays portable: the choice is made at run time.

/// Whether AVX2 and FMA are available (the result is cached by the standard library).
#[cfg(target_arch = "x86_64")]
pub(crate) fn has_avx2_fma() -> bool {
    is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
}
