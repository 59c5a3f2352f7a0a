//! When two 16-byte records a shader wrote for one ray agree: every 32-bit word equal, or
//! both words normal floats (not zero, denormal, infinite or NaN) of the same sign within
//! [`ULPS`] units in the last place. Drivers transform rays and intersect them in their own
//! order of operations, so a `t` or a barycentric may differ in its last bits; integers below
//! 2^23 (ids, indices, types, flags) are denormal bit patterns, so they are compared exactly.

/// Units in the last place two normal floats may differ by.
pub const ULPS: u32 = 4;

/// Whether words `a` and `b` agree (see the module's notes).
pub fn words_agree(a: u32, b: u32) -> bool {
    if a == b {
        return true;
    }
    let normal = |w: u32| f32::from_bits(w).is_normal();
    if !(normal(a) && normal(b)) || (a ^ b) >> 31 != 0 {
        return false;
    }
    // Same sign: the magnitudes' bit patterns are ordered as the values.
    (a & 0x7fff_ffff).abs_diff(b & 0x7fff_ffff) <= ULPS
}

/// Whether records `a` and `b` agree word by word.
pub fn records_agree(a: &[u32; 4], b: &[u32; 4]) -> bool {
    a.iter().zip(b).all(|(&x, &y)| words_agree(x, y))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rule() {
        let one = 1.0f32.to_bits();
        assert!(words_agree(one, one + ULPS));
        assert!(!words_agree(one, one + ULPS + 1));
        assert!(words_agree(one + 3, one - 1));
        // Integers below 2^23 are denormal patterns: exact.
        assert!(!words_agree(7, 8));
        assert!(words_agree(7, 7));
        // Zero, infinity and NaN only equal themselves; signs must match.
        assert!(!words_agree(0, 1));
        assert!(!words_agree(f32::INFINITY.to_bits(), f32::MAX.to_bits()));
        assert!(!words_agree(f32::NAN.to_bits(), f32::NAN.to_bits() + 1));
        assert!(!words_agree((-1.0f32).to_bits(), one));
        assert!(words_agree((-2.0f32).to_bits(), (-2.0f32).to_bits() + 2));
        assert!(records_agree(&[one, 1, 2, 3], &[one + 1, 1, 2, 3]));
        assert!(!records_agree(&[one, 1, 2, 3], &[one, 1, 2, 4]));
    }
}
