//! Arithmetic written once for one value or for several independent values side by side.
//!
//! Code generic over [`Lane`] runs on plain `f64`, or on a vector type whose every operation is
//! the scalar operation applied lane by lane (a crate with run-time CPU dispatch provides one; see
//! `incise_fem::forcefield::hex::kernel`). A lane then gets exactly the bits the scalar code gives it: IEEE
//! addition, multiplication, division and square root are correctly rounded either way, and
//! nothing is fused or reordered. Branches become masks and [`Lane::select`].

// Every operation is always inlined: the callers are compiled for wider vector instructions at
// run time, and only an inlined copy gets them.
#![allow(clippy::inline_always)]

use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// A number type for lane-generic code.
pub trait Lane:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// Per-lane truth values.
    type Mask: Copy
        + BitAnd<Output = Self::Mask>
        + BitOr<Output = Self::Mask>
        + Not<Output = Self::Mask>;

    /// `v` in every lane, of the same kind as `self` (a vector type carries the token that
    /// proves its instructions exist).
    #[must_use]
    fn constant(self, v: f64) -> Self;
    /// `|x|`.
    #[must_use]
    fn abs(self) -> Self;
    /// `√x`.
    #[must_use]
    fn sqrt(self) -> Self;
    /// `self < other`.
    fn lt(self, other: Self) -> Self::Mask;
    /// `self <= other`.
    fn le(self, other: Self) -> Self::Mask;
    /// `self > other`.
    fn gt(self, other: Self) -> Self::Mask;
    /// `if_true` where `mask` holds, else `if_false`.
    fn select(mask: Self::Mask, if_true: Self, if_false: Self) -> Self;
}

/// A [`Lane`] type of four lanes.
pub trait Lane4: Lane {
    /// A value of the same kind as `like` with these lanes.
    fn from_lanes(like: Self, lanes: [f64; 4]) -> Self;
    /// The lanes.
    fn lanes(self) -> [f64; 4];
    /// The mask's lanes.
    fn mask_lanes(mask: Self::Mask) -> [bool; 4];
    /// A mask of the same kind as `like` with these lanes.
    fn mask_from_lanes(like: Self, lanes: [bool; 4]) -> Self::Mask;
}

impl Lane for f64 {
    type Mask = bool;

    #[inline(always)]
    fn constant(self, v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f64::abs(self)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn lt(self, other: Self) -> bool {
        self < other
    }
    #[inline(always)]
    fn le(self, other: Self) -> bool {
        self <= other
    }
    #[inline(always)]
    fn gt(self, other: Self) -> bool {
        self > other
    }
    #[inline(always)]
    fn select(mask: bool, if_true: Self, if_false: Self) -> Self {
        if mask { if_true } else { if_false }
    }
}

/// Four `f64` lanes as a plain array: the portable [`Lane4`] (where no vector type is at hand).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct F64x4(pub [f64; 4]);

macro_rules! lanewise {
    ($trait:ident, $method:ident, $ty:ty, $op:tt) => {
        impl std::ops::$trait for $ty {
            type Output = Self;
            #[inline(always)]
            fn $method(self, other: Self) -> Self {
                Self([
                    self.0[0] $op other.0[0],
                    self.0[1] $op other.0[1],
                    self.0[2] $op other.0[2],
                    self.0[3] $op other.0[3],
                ])
            }
        }
    };
}

lanewise!(Add, add, F64x4, +);
lanewise!(Sub, sub, F64x4, -);
lanewise!(Mul, mul, F64x4, *);
lanewise!(Div, div, F64x4, /);
lanewise!(BitAnd, bitand, Mask4, &);
lanewise!(BitOr, bitor, Mask4, |);

impl Neg for F64x4 {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        Self(self.0.map(|x| -x))
    }
}

/// The lanes' truth values of an [`F64x4`] comparison.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mask4(pub [bool; 4]);

impl Not for Mask4 {
    type Output = Self;
    #[inline(always)]
    fn not(self) -> Self {
        Self(self.0.map(|b| !b))
    }
}

impl Lane for F64x4 {
    type Mask = Mask4;

    #[inline(always)]
    fn constant(self, v: f64) -> Self {
        Self([v; 4])
    }
    #[inline(always)]
    fn abs(self) -> Self {
        Self(self.0.map(f64::abs))
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Self(self.0.map(f64::sqrt))
    }
    #[inline(always)]
    fn lt(self, other: Self) -> Mask4 {
        Mask4(std::array::from_fn(|l| self.0[l] < other.0[l]))
    }
    #[inline(always)]
    fn le(self, other: Self) -> Mask4 {
        Mask4(std::array::from_fn(|l| self.0[l] <= other.0[l]))
    }
    #[inline(always)]
    fn gt(self, other: Self) -> Mask4 {
        Mask4(std::array::from_fn(|l| self.0[l] > other.0[l]))
    }
    #[inline(always)]
    fn select(mask: Mask4, if_true: Self, if_false: Self) -> Self {
        Self(std::array::from_fn(|l| if mask.0[l] { if_true.0[l] } else { if_false.0[l] }))
    }
}

impl Lane4 for F64x4 {
    #[inline(always)]
    fn from_lanes(_like: Self, lanes: [f64; 4]) -> Self {
        Self(lanes)
    }
    #[inline(always)]
    fn lanes(self) -> [f64; 4] {
        self.0
    }
    #[inline(always)]
    fn mask_lanes(mask: Mask4) -> [bool; 4] {
        mask.0
    }
    #[inline(always)]
    fn mask_from_lanes(_like: Self, lanes: [bool; 4]) -> Mask4 {
        Mask4(lanes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn poly<T: Lane>(x: T) -> T {
        let y = (x * x - x.constant(0.3)) / (x.abs() + x.constant(1.0));
        T::select(y.lt(x.constant(0.0)), -(-y).sqrt(), y.sqrt())
    }

    #[test]
    fn a_lane_gets_the_scalar_bits() {
        let xs = [0.1, -2.7, 1e-9, 123.456];
        let wide = poly(F64x4(xs));
        for l in 0..4 {
            assert_eq!(wide.0[l].to_bits(), poly(xs[l]).to_bits(), "lane {l}");
        }
    }
}
