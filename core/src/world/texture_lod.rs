//! The texture level of detail of a ray cone (ray cones: Akenine-Möller et
//! al., Ray Tracing Gems, 2019, ch. 20), with a log₂ of plain arithmetic so
//! that every worker computes the same level.

/// The texture's level of detail for a ray cone of width `width` meeting a
/// triangle at cosine `cos` (Akenine-Möller et al., "Texture Level of
/// Detail Strategies for Real-Time Ray Tracing", Ray Tracing Gems, 2019,
/// ch. 20): λ = ½·log₂(texel area / world area) + log₂(width / cos), the
/// areas being the triangle's in texels and in world units. A degenerate
/// triangle or a grazing ray gets level 0 or the coarsest (the lookup
/// clamps). The logarithm is [`log2`], plain arithmetic, so that every
/// worker computes the same level.
pub fn texture_lod(texel_area: f32, world_area: f32, width: f32, cos: f32) -> f32 {
    if !(texel_area > 0.0 && world_area > 0.0 && width > 0.0) {
        return 0.0;
    }
    let cos = cos.max(1e-6);
    0.5 * log2(texel_area / world_area) + log2(width / cos)
}

/// log₂ of a positive finite `x` to within 0.008 from its exponent and a
/// cubic in the mantissa (no libm: its `log2f` may differ between the
/// machines of a farm in the last bit). Non-positive or non-finite `x` give
/// ∓ a large number.
pub fn log2(x: f32) -> f32 {
    if !(x > 0.0) {
        return -1e30;
    }
    if !x.is_finite() {
        return 1e30;
    }
    // Subnormals: scale into the normal range first.
    let (x, bias) = if x < f32::MIN_POSITIVE {
        (x * 16_777_216.0, 24.0)
    } else {
        (x, 0.0)
    };
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000) - 1.0;
    // log₂(1 + m) on [0, 1): a cubic through 0 and 1 fitted to it.
    let p = m * (std::f32::consts::LOG2_E + m * (-0.680_347 + m * 0.237_652));
    e as f32 + p - bias
}
