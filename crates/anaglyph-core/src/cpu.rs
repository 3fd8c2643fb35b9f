//! What the CPU can run, for the hot loops that carry an AVX2 + FMA build beside the
//! baseline x86-64 one (the learned features' transforms, the multi-view cost, the scene
//! prior's estimates) and, for the multi-view cost's bfloat16 dot products, an AVX-512
//! BF16 one. The binary stays portable: the choice is made at run time.

/// Whether AVX2 and FMA are available (the result is cached by the standard library).
#[cfg(target_arch = "x86_64")]
pub(crate) fn has_avx2_fma() -> bool {
    is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
}

/// Whether AVX-512F and AVX-512 BF16 (`vdpbf16ps`: bfloat16 pair products summed into
/// f32) are available.
#[cfg(target_arch = "x86_64")]
pub(crate) fn has_avx512_bf16() -> bool {
    is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("avx512bf16")
}
