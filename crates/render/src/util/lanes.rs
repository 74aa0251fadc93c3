//! f32 lanes of any multiple of four, computed four at a time with glam's `Vec4` (one SSE
//! register on x86-64): eight lanes are two registers per number, whose independent chains the
//! core runs side by side. The packet queries and the many-path tracer ([`crate::wide`]) are
//! written once over these lanes and compiled for each width.
//!
//! Plain loops over `[f32; N]` were tried first and left to the compiler's vectoriser: it
//! grouped a vector's x, y and z into one register instead of four lanes' x, and the tracer ran
//! slower than with explicit `Vec4`s (docs/renderer.md). The eight-lane tracer is also compiled for AVX2 and
//! AVX-512 encodings of the same 128-bit operations (`wide::trace8`), which keep the bits.
//!
//! Every operation is the scalar IEEE operation on each lane, with no fused multiply-add and
//! nothing across lanes except [`M::bits`], so a lane's numbers never depend on the width or on
//! their lane mates: that is what keeps the paths' bits the scalar trace's. `min` and `max`
//! are glam's (`minps`/`maxps` on x86-64, which give the second operand where either is NaN).

use glam::{BVec4A, Vec4};
use std::ops::{Add, BitAnd, BitAndAssign, BitOr, BitOrAssign, Div, Mul, Neg, Not, Sub};

/// `N` f32 lanes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct F<const N: usize>(pub [f32; N]);

/// `N` lanes of true or false, as glam's SSE masks four lanes at a time (all ones or all zeros,
/// what a compare gives, so that a select is one blend); the groups past `N` are unused.
#[derive(Clone, Copy, Debug)]
pub struct M<const N: usize>([BVec4A; MAX_CHUNKS]);

/// Groups of four lanes a mask holds at most: 32 lanes, the bits of a `u32`.
const MAX_CHUNKS: usize = 8;

/// Three lanes of vectors: x, y and z components, each in `N` lanes.
pub type V3<const N: usize> = [F<N>; 3];

impl<const N: usize> F<N> {
    /// Every lane 0.
    pub const ZERO: Self = Self([0.0; N]);
    /// Every lane 1.
    pub const ONE: Self = Self([1.0; N]);
    /// Every lane +∞.
    pub const INFINITY: Self = Self([f32::INFINITY; N]);
    /// Every lane −∞.
    pub const NEG_INFINITY: Self = Self([f32::NEG_INFINITY; N]);

    /// `v` in every lane.
    #[inline(always)]
    pub fn splat(v: f32) -> Self {
        Self([v; N])
    }

    /// Applies `f` to each group of four lanes as a glam `Vec4`: explicit SSE operations,
    /// which the compiler keeps lane for lane. (Plain loops over the lanes leave the grouping
    /// to its vectoriser, which grouped a vector's x, y and z instead and ran slower.)
    #[inline(always)]
    fn chunks(self, f: impl Fn(Vec4) -> Vec4) -> Self {
        const { assert!(N.is_multiple_of(4) && N <= 32) };
        let mut r = self.0;
        for c in 0..groups::<N>() {
            st(f(ld(&self.0, c)), &mut r, c);
        }
        Self(r)
    }

    #[inline(always)]
    fn chunks2(self, o: Self, f: impl Fn(Vec4, Vec4) -> Vec4) -> Self {
        let mut r = self.0;
        for c in 0..groups::<N>() {
            st(f(ld(&self.0, c), ld(&o.0, c)), &mut r, c);
        }
        Self(r)
    }

    #[inline(always)]
    fn cmp(self, o: Self, f: impl Fn(Vec4, Vec4) -> BVec4A) -> M<N> {
        let mut r = M::NONE;
        for c in 0..groups::<N>() {
            r.0[c] = f(ld(&self.0, c), ld(&o.0, c));
        }
        r
    }

    /// |x|.
    #[inline(always)]
    pub fn abs(self) -> Self {
        self.chunks(Vec4::abs)
    }

    /// |x| with the sign of `sign`'s lane.
    #[inline(always)]
    pub fn copysign(self, sign: Self) -> Self {
        self.chunks2(sign, Vec4::copysign)
    }

    /// Correctly rounded square roots.
    #[inline(always)]
    pub fn sqrt(self) -> Self {
        self.chunks(|v| {
            let [x, y, z, w] = v.to_array();
            Vec4::new(x.sqrt(), y.sqrt(), z.sqrt(), w.sqrt())
        })
    }

    /// 1/x.
    #[inline(always)]
    pub fn recip(self) -> Self {
        self.chunks(Vec4::recip)
    }

    /// `minps`: the lane of `self` where it is below `o`'s, else `o`'s (NaN included).
    #[inline(always)]
    pub fn min(self, o: Self) -> Self {
        self.chunks2(o, Vec4::min)
    }

    /// `maxps`: the lane of `self` where it is above `o`'s, else `o`'s (NaN included).
    #[inline(always)]
    pub fn max(self, o: Self) -> Self {
        self.chunks2(o, Vec4::max)
    }

    /// Lanes equal to `o`'s.
    #[inline(always)]
    pub fn cmpeq(self, o: Self) -> M<N> {
        self.cmp(o, Vec4::cmpeq)
    }

    /// Lanes not equal to `o`'s (NaN included).
    #[inline(always)]
    pub fn cmpne(self, o: Self) -> M<N> {
        self.cmp(o, Vec4::cmpne)
    }

    /// Lanes above `o`'s.
    #[inline(always)]
    pub fn cmpgt(self, o: Self) -> M<N> {
        self.cmp(o, Vec4::cmpgt)
    }

    /// Lanes at or above `o`'s.
    #[inline(always)]
    pub fn cmpge(self, o: Self) -> M<N> {
        self.cmp(o, Vec4::cmpge)
    }

    /// Lanes below `o`'s.
    #[inline(always)]
    pub fn cmplt(self, o: Self) -> M<N> {
        self.cmp(o, Vec4::cmplt)
    }

    /// Lanes at or below `o`'s.
    #[inline(always)]
    pub fn cmple(self, o: Self) -> M<N> {
        self.cmp(o, Vec4::cmple)
    }

    /// NaN lanes.
    #[inline(always)]
    pub fn is_nan_mask(self) -> M<N> {
        self.cmpne(self)
    }

    /// `a`'s lane where `m` is set, else `b`'s.
    #[inline(always)]
    pub fn select(m: M<N>, a: Self, b: Self) -> Self {
        let mut r = b.0;
        for c in 0..groups::<N>() {
            st(Vec4::select(m.0[c], ld(&a.0, c), ld(&b.0, c)), &mut r, c);
        }
        Self(r)
    }
}

impl<const N: usize> M<N> {
    /// No lane set.
    const NONE: Self = Self([BVec4A::FALSE; MAX_CHUNKS]);

    /// `v` in every lane.
    #[inline(always)]
    pub fn splat(v: bool) -> Self {
        let mut r = Self::NONE;
        for c in 0..groups::<N>() {
            r.0[c] = BVec4A::splat(v);
        }
        r
    }

    /// The lanes whose bits are set in `bits` (lane i is bit i).
    #[inline(always)]
    pub fn from_bits(bits: u32) -> Self {
        let mut r = Self::NONE;
        for c in 0..groups::<N>() {
            let b = bits >> (4 * c);
            r.0[c] = BVec4A::new(b & 1 != 0, b & 2 != 0, b & 4 != 0, b & 8 != 0);
        }
        r
    }

    /// Lane i as bit i.
    #[inline(always)]
    pub fn bits(self) -> u32 {
        let mut b = 0;
        for c in 0..groups::<N>() {
            b |= self.0[c].bitmask() << (4 * c);
        }
        b
    }

    /// Whether any lane is set.
    #[inline(always)]
    pub fn any(self) -> bool {
        self.bits() != 0
    }
}

/// Groups of four lanes in `N` lanes.
const fn groups<const N: usize>() -> usize {
    N / 4
}

/// Lanes 4c..4c + 4 as a glam vector.
#[inline(always)]
fn ld<const N: usize>(a: &[f32; N], c: usize) -> Vec4 {
    Vec4::new(a[4 * c], a[4 * c + 1], a[4 * c + 2], a[4 * c + 3])
}

/// Stores a glam vector as lanes 4c..4c + 4.
#[inline(always)]
fn st<const N: usize>(v: Vec4, r: &mut [f32; N], c: usize) {
    let [x, y, z, w] = v.to_array();
    r[4 * c] = x;
    r[4 * c + 1] = y;
    r[4 * c + 2] = z;
    r[4 * c + 3] = w;
}

macro_rules! arith {
    ($($tr:ident $f:ident $op:tt),*) => {$(
        impl<const N: usize> $tr for F<N> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                self.chunks2(o, |a, b| a $op b)
            }
        }
        impl<const N: usize> $tr<f32> for F<N> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: f32) -> Self {
                self.chunks(|a| a $op o)
            }
        }
        impl<const N: usize> $tr<F<N>> for f32 {
            type Output = F<N>;
            #[inline(always)]
            fn $f(self, o: F<N>) -> F<N> {
                o.chunks(|b| self $op b)
            }
        }
    )*};
}
arith!(Add add +, Sub sub -, Mul mul *, Div div /);

impl<const N: usize> Neg for F<N> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.chunks(|a| -a)
    }
}

macro_rules! logic {
    ($($tr:ident $f:ident $tra:ident $fa:ident $op:tt),*) => {$(
        impl<const N: usize> $tr for M<N> {
            type Output = Self;
            #[inline(always)]
            fn $f(mut self, o: Self) -> Self {
                for c in 0..groups::<N>() {
                    self.0[c] = $tr::$f(self.0[c], o.0[c]);
                }
                self
            }
        }
        impl<const N: usize> $tra for M<N> {
            #[inline(always)]
            fn $fa(&mut self, o: Self) {
                *self = *self $op o;
            }
        }
    )*};
}
logic!(BitAnd bitand BitAndAssign bitand_assign &, BitOr bitor BitOrAssign bitor_assign |);

impl<const N: usize> Not for M<N> {
    type Output = Self;
    #[inline(always)]
    fn not(mut self) -> Self {
        for c in 0..groups::<N>() {
            self.0[c] = !self.0[c];
        }
        self
    }
}

/// Dot products lane by lane, summed as (x + y) + z like glam's `Vec3A::dot`.
#[inline(always)]
pub fn dot<const N: usize>(a: &V3<N>, b: &V3<N>) -> F<N> {
    (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
}

/// One vector per lane, as lanes: four at a time through glam's 4×4 transpose (whole-register
/// shuffles), not a float at a time.
#[inline(always)]
pub fn transpose3<const N: usize>(v: &[glam::Vec3A; N]) -> V3<N> {
    let mut r = [F::ZERO; 3];
    for c in 0..groups::<N>() {
        let m = glam::Mat4::from_cols(
            v[4 * c].extend(0.0),
            v[4 * c + 1].extend(0.0),
            v[4 * c + 2].extend(0.0),
            v[4 * c + 3].extend(0.0),
        )
        .transpose();
        st(m.x_axis, &mut r[0].0, c);
        st(m.y_axis, &mut r[1].0, c);
        st(m.z_axis, &mut r[2].0, c);
    }
    r
}

/// `[f(0), f(1), f(2)]`: for a vector's components, instead of std's `array::from_fn` and
/// `map`, which can stay out of line (calls with their arrays in memory) in a function
/// compiled for other target features, as the AVX2 tracer is.
#[inline(always)]
pub fn v3<T>(mut f: impl FnMut(usize) -> T) -> [T; 3] {
    [f(0), f(1), f(2)]
}

/// A vector in every lane.
#[inline(always)]
pub fn splat3<const N: usize>(v: glam::Vec3A) -> V3<N> {
    [F::splat(v.x), F::splat(v.y), F::splat(v.z)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lanes agree with glam's SSE operations bit for bit, NaN and signed zeros included,
    /// and the masks' bits are the lanes.
    #[test]
    fn lanes_are_glams_operations() {
        use glam::Vec4;
        let vals = [
            0.0,
            -0.0,
            1.5,
            -2.25,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            1e-40,
        ];
        for &a in &vals {
            for &b in &vals {
                let (fa, fb) = (F::<4>([a, b, a, b]), F::<4>([b, a, b, a]));
                let (va, vb) = (Vec4::from_array(fa.0), Vec4::from_array(fb.0));
                let same = |f: F<4>, v: Vec4| {
                    assert_eq!(
                        f.0.map(f32::to_bits),
                        v.to_array().map(f32::to_bits),
                        "{a} {b}"
                    )
                };
                same(fa.min(fb), va.min(vb));
                same(fa.max(fb), va.max(vb));
                same(fa / fb, va / vb);
                same(fa.copysign(fb), va.copysign(vb));
                same(fa.sqrt(), va.to_array().map(f32::sqrt).into());
                assert_eq!(fa.cmplt(fb).bits(), va.cmplt(vb).bitmask());
                assert_eq!(fa.cmpne(fb).bits(), va.cmpne(vb).bitmask());
                assert_eq!(fa.is_nan_mask().bits(), va.is_nan_mask().bitmask());
            }
        }
        let m = M::<8>::from_bits(0b1010_0110);
        assert_eq!(m.bits(), 0b1010_0110);
        assert_eq!((!m).bits(), 0b0101_1001);
        let s = F::<8>::select(m, F::ONE, F::ZERO);
        assert_eq!(s.0, [0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0]);
    }
}
