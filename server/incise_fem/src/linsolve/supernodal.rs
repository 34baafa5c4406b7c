//! Forward and back substitution through a supernodal Cholesky factor laid out by faer.
//!
//! faer's solve visits the supernodes one after another. In a nested-dissection order the two
//! halves below the top separator are independent, so these substitutions run them on two threads
//! (nearly twice as fast on B3's `f32` factor); on one thread they are as fast as faer's. They
//! are the plain column-oriented loops: the off-diagonal
//! block of a supernode is dense with one shared row pattern, so the forward step is an axpy per
//! column into a contiguous buffer and the back step a dot product per column, both vectorisable.
//! The dot products sum in eight fixed lanes, so results do not depend on the build's vector width.

use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;
use std::ops::{Add, Div, Mul, Sub};

/// Factors with fewer entries are solved on one thread: waking the second costs more than it saves
/// below this (B1's factor solves slower on two threads, B3's faster). The arithmetic is the same
/// either way.
const PARALLEL_ENTRIES: usize = 1_000_000;

/// The arithmetic the substitutions need (`f32` and `f64`).
pub trait Scalar:
    Copy + Default + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self>
{
}
impl Scalar for f32 {}
impl Scalar for f64 {}

/// The supernode layout of one symbolic factor, copied out of faer's structure once.
pub struct Supernodes {
    /// First column of each supernode, and one past the last at the end.
    begin: Vec<usize>,
    /// Start of each supernode's column-major values in the factor (and the total at the end).
    values: Vec<usize>,
    /// Start of each supernode's off-diagonal row pattern in `rows`.
    pattern: Vec<usize>,
    rows: Vec<u32>,
    /// Longest off-diagonal pattern: the size of the scratch buffer.
    longest: usize,
    /// The top dissection level, when the supernodes split along it.
    halves: Option<Halves>,
}

/// The two independent halves of a nested-dissection order and the separator after them: the
/// substitutions run the halves on two threads. Supernodes `..left` hold the first half's columns
/// (`..left_end`), `left..right` the second's (`..right_end`), the rest the separator.
struct Halves {
    left: usize,
    right: usize,
    left_end: usize,
    right_end: usize,
}

/// Where a substitution reads and writes: columns from `own_start` live in `own`, rows from
/// `sep_start` in `sep` (the separator, or a buffer for one thread's updates of it).
struct Part<'a, T> {
    own: &'a mut [T],
    own_start: usize,
    sep_start: usize,
}

impl Supernodes {
    /// The layout of `symbolic`, whose columns `..split[0]` and `split[0]..split[1]` are the two
    /// halves of a dissection (pass `None`, or a split the supernodes straddle, to run serially).
    #[must_use]
    pub fn new(symbolic: &SymbolicSupernodalCholesky<u32>, split: Option<[usize; 2]>) -> Self {
        let count = symbolic.n_supernodes();
        let mut begin: Vec<usize> =
            symbolic.supernode_begin().iter().map(|&b| b as usize).collect();
        begin.push(symbolic.supernode_end().last().map_or(0, |&e| e as usize));
        let values = symbolic.col_ptr_for_val().iter().map(|&v| v as usize).collect();
        let pattern: Vec<usize> =
            symbolic.col_ptr_for_row_idx().iter().map(|&v| v as usize).collect();
        let longest = (0..count).map(|s| pattern[s + 1] - pattern[s]).max().unwrap_or(0);
        let mut supernodes = Self {
            begin,
            values,
            pattern,
            rows: symbolic.row_idx().to_vec(),
            longest,
            halves: None,
        };
        supernodes.halves = split.and_then(|split| supernodes.halves_at(split));
        supernodes
    }

    /// Whether the substitutions split at the top dissection.
    #[must_use]
    pub fn has_halves(&self) -> bool {
        self.halves.is_some()
    }

    /// Multiply-adds of one numeric factorisation: `Σ c²/2` over the columns, `c` the column's
    /// length below and on the diagonal.
    #[must_use]
    pub fn factor_work(&self) -> f64 {
        let mut work = 0.0;
        for s in 0..self.begin.len() - 1 {
            let width = self.begin[s + 1] - self.begin[s];
            let height = width + self.pattern[s + 1] - self.pattern[s];
            for j in 0..width {
                let c = (height - j) as f64;
                work += 0.5 * c * c;
            }
        }
        work
    }

    /// The halves at `split`, if no supernode straddles the first boundary and no supernode of
    /// one half updates a row of the other. A supernode straddling the second boundary (faer
    /// merges the second half's root into the separator above it) goes with the separator.
    fn halves_at(&self, [left_end, right_end]: [usize; 2]) -> Option<Halves> {
        let count = self.begin.len() - 1;
        let left = self.begin.iter().position(|&b| b == left_end)?;
        let right = self.begin.iter().rposition(|&b| b <= right_end)?;
        let right_end = self.begin[right];
        if !(0 < left && left < right && right < count) {
            return None;
        }
        let within = |range: std::ops::Range<usize>, own: std::ops::Range<usize>| {
            range.into_iter().all(|s| {
                self.rows[self.pattern[s]..self.pattern[s + 1]]
                    .iter()
                    .all(|&r| own.contains(&(r as usize)) || r as usize >= right_end)
            })
        };
        (within(0..left, 0..left_end) && within(left..right, left_end..right_end))
            .then_some(Halves { left, right, left_end, right_end })
    }

    /// Solves `L Lᵀ x = b` in place (`x` holds `b` on entry), with `l` the factor's values.
    pub fn solve<T: Scalar + Send + Sync>(
        &self,
        exec: &crate::exec::Executor,
        l: &[T],
        x: &mut [T],
    ) {
        let count = self.begin.len() - 1;
        let n = x.len();
        let Some(h) = &self.halves else {
            let mut all = Part { own: x, own_start: 0, sep_start: n };
            self.sweep(Sweep::Forward(&mut []), 0..count, l, &mut all);
            self.sweep(Sweep::Backward(&[]), 0..count, l, &mut all);
            return;
        };
        let parallel = self.values[count] >= PARALLEL_ENTRIES;
        let (first, rest) = x.split_at_mut(h.left_end);
        let (second, separator) = rest.split_at_mut(h.right_end - h.left_end);
        let mut a = Part { own: first, own_start: 0, sep_start: h.right_end };
        let mut b = Part { own: second, own_start: h.left_end, sep_start: h.right_end };
        // The second half's updates of the separator go to a buffer that is added after both
        // halves: the same order of sums whichever thread runs what.
        let mut buffer = vec![T::default(); separator.len()];
        exec.join_if(
            parallel,
            || self.sweep(Sweep::Forward(separator), 0..h.left, l, &mut a),
            || self.sweep(Sweep::Forward(&mut buffer), h.left..h.right, l, &mut b),
        );
        for (x, b) in separator.iter_mut().zip(&buffer) {
            *x = *x + *b;
        }
        let mut top = Part { own: separator, own_start: h.right_end, sep_start: n };
        self.sweep(Sweep::Forward(&mut []), h.right..count, l, &mut top);
        self.sweep(Sweep::Backward(&[]), h.right..count, l, &mut top);
        // The halves only read the separator on the way back.
        let separator = &*top.own;
        exec.join_if(
            parallel,
            || self.sweep(Sweep::Backward(separator), 0..h.left, l, &mut a),
            || self.sweep(Sweep::Backward(separator), h.left..h.right, l, &mut b),
        );
    }

    /// Runs one direction over a range of supernodes (backward runs it in reverse), compiled for
    /// AVX2 where the CPU has it: no contraction, so every path gives the same bits.
    fn sweep<T: Scalar>(
        &self,
        sweep: Sweep<'_, T>,
        range: std::ops::Range<usize>,
        l: &[T],
        part: &mut Part<'_, T>,
    ) {
        pulp::Arch::new().dispatch(SweepOp { supernodes: self, sweep, range, l, part });
    }

    // Inlined into pulp's feature-enabled entry point with everything below, or the loops would
    // not get the wide instructions.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn sweep_here<T: Scalar>(
        &self,
        sweep: Sweep<'_, T>,
        range: std::ops::Range<usize>,
        l: &[T],
        part: &mut Part<'_, T>,
    ) {
        let mut scratch = vec![T::default(); self.longest];
        match sweep {
            Sweep::Forward(sep) => {
                for s in range {
                    self.forward(s, l, part, sep, &mut scratch);
                }
            }
            Sweep::Backward(sep) => {
                for s in range.rev() {
                    self.backward(s, l, part, sep, &mut scratch);
                }
            }
        }
    }

    /// Supernode `s`: its first column counted from `own_start`, its width, its off-diagonal row
    /// pattern, and its column-major block of `height` rows.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn supernode<'a, T>(&'a self, s: usize, l: &'a [T], own_start: usize) -> Supernode<'a, T> {
        let (start, size) = (self.begin[s] - own_start, self.begin[s + 1] - self.begin[s]);
        let rows = &self.rows[self.pattern[s]..self.pattern[s + 1]];
        let height = size + rows.len();
        let block = &l[self.values[s]..self.values[s] + height * size];
        Supernode { start, size, rows, height, block }
    }

    /// One supernode of `L y = b`: its diagonal block, then its update of later rows (rows from
    /// `part.sep_start` are subtracted from `sep`).
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn forward<T: Scalar>(
        &self,
        s: usize,
        l: &[T],
        part: &mut Part<'_, T>,
        sep: &mut [T],
        scratch: &mut [T],
    ) {
        let Supernode { start, size, rows, height, block } = self.supernode(s, l, part.own_start);
        let x = &mut *part.own;
        let tmp = &mut scratch[..rows.len()];
        tmp.fill(T::default());
        for j in 0..size {
            let column = &block[j * height..(j + 1) * height];
            let xj = x[start + j] / column[j];
            x[start + j] = xj;
            for (xi, &lij) in x[start + j + 1..start + size].iter_mut().zip(&column[j + 1..size]) {
                *xi = *xi - lij * xj;
            }
            for (t, &lij) in tmp.iter_mut().zip(&column[size..]) {
                *t = *t + lij * xj;
            }
        }
        for (&r, &t) in rows.iter().zip(tmp.iter()) {
            let r = r as usize;
            let target = if r < part.sep_start {
                &mut x[r - part.own_start]
            } else {
                &mut sep[r - part.sep_start]
            };
            *target = *target - t;
        }
    }

    /// One supernode of `Lᵀ x = y`: gather the later rows (from `sep` past `part.sep_start`),
    /// then the transposed diagonal block.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn backward<T: Scalar>(
        &self,
        s: usize,
        l: &[T],
        part: &mut Part<'_, T>,
        sep: &[T],
        scratch: &mut [T],
    ) {
        let Supernode { start, size, rows, height, block } = self.supernode(s, l, part.own_start);
        let x = &mut *part.own;
        let tmp = &mut scratch[..rows.len()];
        for (t, &r) in tmp.iter_mut().zip(rows) {
            let r = r as usize;
            *t = if r < part.sep_start { x[r - part.own_start] } else { sep[r - part.sep_start] };
        }
        for j in (0..size).rev() {
            let column = &block[j * height..(j + 1) * height];
            let inner = dot(&column[j + 1..size], &x[start + j + 1..start + size]);
            let outer = dot(&column[size..], tmp);
            x[start + j] = (x[start + j] - inner - outer) / column[j];
        }
    }
}

/// One supernode's place and values (see [`Supernodes::supernode`]).
struct Supernode<'a, T> {
    start: usize,
    size: usize,
    rows: &'a [u32],
    height: usize,
    block: &'a [T],
}

/// The two substitutions, each with the rows past `Part::sep_start`: the forward one subtracts
/// its updates from them, the backward one reads them.
enum Sweep<'s, T> {
    Forward(&'s mut [T]),
    Backward(&'s [T]),
}

/// [`Supernodes::sweep`] as a `pulp` operation.
struct SweepOp<'a, 'b, T> {
    supernodes: &'a Supernodes,
    sweep: Sweep<'a, T>,
    range: std::ops::Range<usize>,
    l: &'a [T],
    part: &'a mut Part<'b, T>,
}

impl<T: Scalar> pulp::WithSimd for SweepOp<'_, '_, T> {
    type Output = ();

    // Inlined into pulp's feature-enabled entry point, or it would not get the wide instructions.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        self.supernodes.sweep_here(self.sweep, self.range, self.l, self.part);
    }
}

/// `Σ aᵢ bᵢ` in eight fixed lanes, then the lanes in order.
#[allow(clippy::inline_always)]
#[inline(always)]
fn dot<T: Scalar>(a: &[T], b: &[T]) -> T {
    let mut lanes = [T::default(); 8];
    let (a8, a_rest) = a.split_at(a.len() / 8 * 8);
    let (b8, b_rest) = b.split_at(a8.len());
    for (ca, cb) in a8.chunks_exact(8).zip(b8.chunks_exact(8)) {
        for k in 0..8 {
            lanes[k] = lanes[k] + ca[k] * cb[k];
        }
    }
    let mut sum = T::default();
    for lane in lanes {
        sum = sum + lane;
    }
    for (&p, &q) in a_rest.iter().zip(b_rest) {
        sum = sum + p * q;
    }
    sum
}
