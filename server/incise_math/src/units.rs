//! SI aliases. incise works in metres, kilograms, seconds, newtons and pascals throughout; a
//! value that is not SI carries a suffix in its name (`period_nanos`).

/// The physics scalar: `f64` on the CPU everywhere.
pub type Real = f64;
/// A length in metres.
pub type Metres = f64;
/// A stress or Young's modulus in pascals.
pub type Pascals = f64;
/// A 3-vector (position, displacement, spacing) in SI units.
pub type Vec3 = [f64; 3];
