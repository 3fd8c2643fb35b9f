//! What the CPU can run, for the hot loops that carry an AVX2 + FMA build beside the
//! baseline x86-64 one (the learned features' transforms, the multi-view cost, the scene
//! prior's estimates) and, for the multi-view cost's bfloat16 dot products, an AVX-512
//! BF16 one, and for the matching network's convolutions AMX tiles. The binary stays
//! portable: the choice is made at run time.

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

/// Whether AMX tiles with bfloat16 products (`tdpbf16ps`) can run in this process: the CPU
/// has AMX-TILE, AMX-BF16 and the AVX-512 the conversions around them use, and Linux
/// grants the process the tile state (`arch_prctl(ARCH_REQ_XCOMP_PERM)`, asked once).
/// `ANAGLYPH_NO_AMX` set in the environment turns the tiles off (the network then runs in
/// f32, as on CPUs without them).
#[cfg(target_arch = "x86_64")]
pub(crate) fn has_amx_bf16() -> bool {
    static PERMITTED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *PERMITTED.get_or_init(|| {
        if std::env::var_os("ANAGLYPH_NO_AMX").is_some() {
            return false;
        }
        // CPUID leaf 7, subleaf 0: EDX bit 22 AMX-BF16, bit 24 AMX-TILE (zeros where
        // the leaf is beyond the CPU's maximum).
        let leaf = std::arch::x86_64::__cpuid_count(7, 0);
        let tiles = leaf.edx & (1 << 22) != 0 && leaf.edx & (1 << 24) != 0;
        tiles
            && is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512bw")
            && request_tile_state()
    })
}

/// Asks Linux for the AMX tile data state (without it the first tile instruction faults).
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
fn request_tile_state() -> bool {
    const ARCH_REQ_XCOMP_PERM: libc::c_long = 0x1023;
    const XFEATURE_XTILEDATA: libc::c_long = 18;
    // SAFETY: arch_prctl with ARCH_REQ_XCOMP_PERM only changes which extended states the
    // process may use; it returns nonzero where the kernel or CPU refuses.
    unsafe {
        libc::syscall(
            libc::SYS_arch_prctl,
            ARCH_REQ_XCOMP_PERM,
            XFEATURE_XTILEDATA,
        ) == 0
    }
}

/// Elsewhere the tile state is not asked for.
#[cfg(all(target_arch = "x86_64", not(target_os = "linux")))]
fn request_tile_state() -> bool {
    false
}
