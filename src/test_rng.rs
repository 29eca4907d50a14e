//! Repeatable randomness for the unit tests: a xorshift64 sequence (no
//! dependency, the same draws on every machine and run).

/// The xorshift64 sequence from `seed` (not 0).
pub(crate) fn xorshift(mut seed: u64) -> impl FnMut() -> u64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    }
}

/// Draws in [0, 1) in steps of 10⁻⁶, from [`xorshift`].
pub(crate) fn unit_draws(seed: u64) -> impl FnMut() -> f64 {
    let mut next = xorshift(seed);
    move || (next() % 1_000_000) as f64 / 1_000_000.0
}
