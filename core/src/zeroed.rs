//! Building large values in place: the payloads and the controller are hundreds of KiB, so they
//! are never built on the stack and moved, but zeroed where they will live (a `static`, a `Box`,
//! a shared-memory sample) and then filled.
//!
//! [`Zeroable`] marks the types whose all-zero bytes are a valid value; [`zeroed_in_place`] turns
//! storage you own into such a value, and, with the `alloc` feature, [`boxed_zeroed`] does the
//! same on the heap. These two functions hold the crate's only `unsafe` for in-place
//! construction; `init_in_place`, `reset` and `new_boxed` of the payloads and of the controller
//! are written on them.
//!
//! Structs of the crate implement [`Zeroable`] through `impl_zeroable!`, which checks at compile
//! time that the field list is complete (an exhaustive pattern) and that every field's type is
//! itself [`Zeroable`].

use core::mem::MaybeUninit;

/// Types for which the all-zero byte pattern is a valid value.
///
/// # Safety
/// Implementors promise that a value whose every byte is 0 is a valid `Self`: no references,
/// no `NonZero`, no enum without a variant of discriminant 0, no field that is not itself
/// `Zeroable`.
pub unsafe trait Zeroable: Sized {}

/// Where the zeros are written: storage that may be uninitialised, or a live value.
enum Place<'a, T> {
    Uninit(&'a mut MaybeUninit<T>),
    Init(&'a mut T),
}

/// The one place that writes zero bytes over a `T` and hands it out as initialised.
fn zero_at<T: Zeroable>(place: Place<'_, T>) -> &mut T {
    let p: *mut T = match place {
        Place::Uninit(slot) => slot.as_mut_ptr(),
        Place::Init(value) => value,
    };
    // SAFETY: `p` comes from a live exclusive reference to storage for one `T`, so it is valid
    // and aligned for writing one `T`, and nothing else can observe it during the write. The
    // old value (if any) is overwritten without being dropped, which only leaks what it owned;
    // `Zeroable` types are plain data. After the write every byte is 0, which `T: Zeroable`
    // promises is a valid `T`, so handing out `&mut T` for the same lifetime is sound.
    unsafe {
        p.write_bytes(0, 1);
        &mut *p
    }
}

/// Zeroes `slot` in place (no stack temporary) and returns it as an initialised value.
///
/// # Example
/// ```
/// use core::mem::MaybeUninit;
/// use needle_core::{ComplianceFrame, zeroed_in_place};
///
/// let mut slot = MaybeUninit::<[[f64; 4]; 4]>::uninit();
/// let w = zeroed_in_place(&mut slot);
/// w[1][2] = 3.0;
/// assert_eq!(w[1][2] + w[0][0], 3.0);
///
/// // A frame (all zero, so its version is 0 until stamped: prefer `init_in_place`).
/// let mut f = Box::new(MaybeUninit::<ComplianceFrame<8>>::uninit());
/// assert_eq!(zeroed_in_place(&mut *f).version, 0);
/// ```
pub fn zeroed_in_place<T: Zeroable>(slot: &mut MaybeUninit<T>) -> &mut T {
    zero_at(Place::Uninit(slot))
}

/// Overwrites a live value with zeros in place (for `reset`).
pub(crate) fn zero_out<T: Zeroable>(value: &mut T) -> &mut T {
    zero_at(Place::Init(value))
}

/// A heap-allocated all-zero `T`, zeroed where it lives (never on the stack).
///
/// # Example
/// ```
/// use needle_core::boxed_zeroed;
///
/// let w = boxed_zeroed::<[[f64; 192]; 192]>(); // 288 KiB, never on the stack
/// assert!(w.iter().flatten().all(|x| *x == 0.0));
/// ```
#[cfg(feature = "alloc")]
pub fn boxed_zeroed<T: Zeroable>() -> alloc::boxed::Box<T> {
    let mut b = alloc::boxed::Box::<T>::new_uninit();
    zeroed_in_place(&mut b);
    // SAFETY: `zeroed_in_place` initialised every byte of the box's contents with a valid `T`.
    unsafe { b.assume_init() }
}

/// Compile-time check used by `impl_zeroable!`.
#[doc(hidden)]
pub(crate) fn require_zeroable<T: Zeroable>(_: &T) {}

/// Implements [`Zeroable`] for a struct of the crate, checking that the listed fields are all
/// of them (exhaustive pattern) and that each field's type is [`Zeroable`].
macro_rules! impl_zeroable {
    ($ty:ident $(<$(const $g:ident),+>)? { $($field:ident),+ $(,)? }) => {
        // SAFETY: every field's type is `Zeroable` (checked below) and the list is complete (the
        // pattern below is exhaustive), so all-zero bytes, padding included, are a valid value.
        unsafe impl$(<$(const $g: usize),+>)? $crate::zeroed::Zeroable for $ty$(<$($g),+>)? {}
        const _: () = {
            #[allow(dead_code)]
            fn fields_are_zeroable$(<$(const $g: usize),+>)?(value: &$ty$(<$($g),+>)?) {
                let $ty { $($field),+ } = value;
                $($crate::zeroed::require_zeroable($field);)+
            }
        };
    };
}
pub(crate) use impl_zeroable;

// SAFETY: integers, floats and `false` are all-zero bytes.
unsafe impl Zeroable for f64 {}
// SAFETY: as above.
unsafe impl Zeroable for u8 {}
// SAFETY: as above.
unsafe impl Zeroable for u32 {}
// SAFETY: as above.
unsafe impl Zeroable for u64 {}
// SAFETY: as above.
unsafe impl Zeroable for usize {}
// SAFETY: `false` is the byte 0.
unsafe impl Zeroable for bool {}
// SAFETY: an array is its elements, each valid when all-zero.
unsafe impl<T: Zeroable, const N: usize> Zeroable for [T; N] {}
// SAFETY: a statically sized nalgebra matrix is an `ArrayStorage` (`[[T; R]; C]`) and a
// zero-sized marker.
unsafe impl<T: Zeroable, const R: usize, const C: usize> Zeroable for nalgebra::SMatrix<T, R, C> {}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn zeroed_in_place_and_zero_out_give_zeros() {
        let mut slot = MaybeUninit::<[[f64; 3]; 5]>::uninit();
        let v = zeroed_in_place(&mut slot);
        assert!(v.iter().flatten().all(|x| x.to_bits() == 0));
        v[4][2] = -1.5;
        zero_out(v);
        assert!(v.iter().flatten().all(|x| x.to_bits() == 0));
    }
}
