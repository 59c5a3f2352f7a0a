//! When two 16-byte records a shader wrote for one ray agree: every 32-bit word equal, or
//! both words floats of the same sign no smaller than [`SMALLEST`] whose difference is at
//! most [`TOLERANCE`] times the larger of 1 and their magnitudes. Drivers transform rays,
//! invert instance transforms and intersect triangles in their own order of operations, so
//! a `t` may differ in its last bits, and a barycentric — a difference of nearly equal
//! products — by as much relative to 1 as to itself. Integers below 2^29 (ids, indices,
//! custom indices, types, flags, counts) read as floats below [`SMALLEST`], so they are
//! compared exactly, as are infinities and NaN; +0 and -0 are equal.

/// How far apart two floats may be, relative to the larger of 1 and their magnitudes: 2^-16
/// (128 units in the last place at 1; measured differences between vkrt and Mesa's lavapipe
/// reach 9 on the `t` of a rotated instance and 66 on a barycentric, whose edge functions
/// lavapipe takes in double precision).
pub const TOLERANCE: f32 = 1.0 / 65_536.0;

/// The smallest magnitude compared with [`TOLERANCE`]: 2^-60, so that every bit pattern
/// below 2^29 (the integers a shader writes) is compared exactly.
pub const SMALLEST: f32 = f32::from_bits(67 << 23);

/// Whether words `a` and `b` agree (see the module's notes).
pub fn words_agree(a: u32, b: u32) -> bool {
    // (+0 and -0 are equal floats: a translation's zero may come out either way)
    if a == b || (a | b) == 0x8000_0000 {
        return true;
    }
    let (x, y) = (f32::from_bits(a), f32::from_bits(b));
    let float = |v: f32| v.is_finite() && v.abs() >= SMALLEST;
    if !(float(x) && float(y)) || (a ^ b) >> 31 != 0 {
        return false;
    }
    (x - y).abs() <= TOLERANCE * x.abs().max(y.abs()).max(1.0)
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
        assert!(words_agree(one, one + 128));
        assert!(!words_agree(one, one + 129));
        assert!(words_agree(one + 3, one - 1));
        // Below 1 the tolerance is absolute: 2^-16 is 1024 ulp of a barycentric of 0.24.
        let b = 0.24f32.to_bits();
        assert!(words_agree(b, b + 1024));
        assert!(!words_agree(b, b + 1030));
        // Above 1 it is relative: 2^-16 of 1000 is 250 of its ulp (2^-14).
        let big = 1000.0f32.to_bits();
        assert!(words_agree(big, big + 250));
        assert!(!words_agree(big, big + 251));
        // Integers below 2^29 compare exactly, 2^24 - 1 (a custom index) too.
        assert!(!words_agree(7, 8));
        assert!(words_agree(7, 7));
        assert!(!words_agree(0xff_ffff, 0xff_fffe));
        assert!(!words_agree((1 << 29) - 1, (1 << 29) - 2));
        assert!(SMALLEST.to_bits() == 67 << 23);
        // Zero, infinity and NaN only equal themselves; signs must match.
        assert!(!words_agree(0, 1));
        assert!(!words_agree(0, 1e-9f32.to_bits()));
        assert!(words_agree(0, 0x8000_0000));
        assert!(!words_agree(f32::INFINITY.to_bits(), f32::MAX.to_bits()));
        assert!(!words_agree(f32::NAN.to_bits(), f32::NAN.to_bits() + 1));
        assert!(!words_agree((-1.0f32).to_bits(), one));
        assert!(words_agree((-2.0f32).to_bits(), (-2.0f32).to_bits() + 2));
        assert!(records_agree(&[one, 1, 2, 3], &[one + 1, 1, 2, 3]));
        assert!(!records_agree(&[one, 1, 2, 3], &[one, 1, 2, 4]));
    }
}
