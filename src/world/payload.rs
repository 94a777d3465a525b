//! The content of a V2V message: any value, shared between its receivers and never copied per
//! receiver; a small `Copy` value is held inline, with no allocation and no reference count.
//!
//! Every message used to hold its value behind an `Arc<dyn Any>`. A beacon of a few bytes then
//! cost an allocation when it was sent, a locked decrement and a free when its round's batch
//! went, and a cache line of its own: about a tenth of the benchmark's processor time (perf,
//! 10,000 vehicles on two threads: the `Arc` drops 5.6 %, the sends with their `malloc` 4.7 %).
//! A value sent with [`Payload::copied`] (or [`Mailbox::send_copy`](super::Mailbox::send_copy))
//! that fits in two words lives in the message itself; the batch of a round is still one
//! allocation shared by all receivers, so a broadcast copies nothing per receiver either way.

use std::any::{Any, TypeId};
use std::mem::{MaybeUninit, align_of, size_of};
use std::sync::Arc;

/// Any value a vehicle sends; shared by its receivers, never copied per receiver.
///
/// Made from an `Arc` (`Payload::from(Arc::new(value))`, or [`Payload::new`]), it is that
/// `Arc`: clones share the value. Made with [`Payload::copied`] from a `Copy` value of at most
/// 16 bytes (a speed, an id, a pair of floats), it holds the value inline. Either way read it
/// with [`Payload::downcast_ref`] (or `Message::payload`).
#[derive(Clone)]
pub struct Payload(Repr);

/// How a [`Payload`] holds its value.
#[derive(Clone)]
enum Repr {
    /// A `Copy` value of at most [`Payload::INLINE_BYTES`] bytes, aligned to at most 8, in
    /// `bits`; `type_id` gives its type (a function pointer: 8 bytes, where a `TypeId` takes 16).
    Inline { type_id: fn() -> TypeId, bits: MaybeUninit<[u64; 2]> },
    /// Any other value, shared.
    Shared(Arc<dyn Any + Send + Sync>),
}

impl Payload {
    /// The largest value [`Payload::copied`] holds inline \[bytes\].
    pub const INLINE_BYTES: usize = 16;

    /// `value`, shared behind an `Arc` (clones of the payload share it).
    pub fn new<T: Any + Send + Sync>(value: T) -> Payload {
        Payload(Repr::Shared(Arc::new(value)))
    }

    /// `value` held inline when it fits ([`Payload::INLINE_BYTES`] bytes, aligned to at most
    /// 8), else shared as by [`Payload::new`]. `Copy` is what makes the inline form sound: a
    /// `Copy` type has no destructor and no interior mutability (`UnsafeCell` is not `Copy`),
    /// so copying its bytes with the message copies the value and receivers only see `&T`.
    pub fn copied<T: Copy + Any + Send + Sync>(value: T) -> Payload {
        if size_of::<T>() <= Self::INLINE_BYTES && align_of::<T>() <= align_of::<u64>() {
            let mut bits = MaybeUninit::<[u64; 2]>::uninit();
            // SAFETY: `bits` is 16 bytes aligned to 8, and `T` fits in that (checked above).
            unsafe { bits.as_mut_ptr().cast::<T>().write(value) };
            Payload(Repr::Inline { type_id: TypeId::of::<T>, bits })
        } else {
            Payload::new(value)
        }
    }

    /// The value as a `T`, or `None` if it holds something else.
    #[inline]
    pub fn downcast_ref<T: Any>(&self) -> Option<&T> {
        match &self.0 {
            Repr::Inline { type_id, bits } => {
                // SAFETY: `Payload::copied` wrote a `T` at the start of `bits` (and only it
                // makes this variant); the type ids match, so this is that `T`.
                (type_id() == TypeId::of::<T>()).then(|| unsafe { &*bits.as_ptr().cast::<T>() })
            }
            Repr::Shared(value) => value.downcast_ref::<T>(),
        }
    }

    /// Whether the value is a `T`.
    pub fn is<T: Any>(&self) -> bool {
        self.downcast_ref::<T>().is_some()
    }

    /// Whether `a` and `b` share one value behind one `Arc` (inline payloads share nothing).
    pub fn ptr_eq(a: &Payload, b: &Payload) -> bool {
        match (&a.0, &b.0) {
            (Repr::Shared(a), Repr::Shared(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }

    /// Whether the value is held inline (made by [`Payload::copied`] from a small value).
    pub fn is_inline(&self) -> bool {
        matches!(self.0, Repr::Inline { .. })
    }
}

impl<T: Any + Send + Sync> From<Arc<T>> for Payload {
    fn from(value: Arc<T>) -> Payload {
        Payload(Repr::Shared(value))
    }
}

impl From<Arc<dyn Any + Send + Sync>> for Payload {
    fn from(value: Arc<dyn Any + Send + Sync>) -> Payload {
        Payload(Repr::Shared(value))
    }
}

impl std::fmt::Debug for Payload {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.is_inline() { "Payload(inline)" } else { "Payload(shared)" })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicU64, Ordering};

    #[test]
    fn a_small_copy_value_is_held_inline_and_read_back_as_its_type_only() {
        let speed = Payload::copied(17.25_f64);
        assert!(speed.is_inline());
        assert_eq!(speed.downcast_ref::<f64>(), Some(&17.25));
        assert_eq!(speed.downcast_ref::<u64>(), None, "same size, other type");
        assert_eq!(speed.downcast_ref::<f32>(), None);
        let pair = Payload::copied((3_u32, -1.5_f64));
        assert_eq!(pair.clone().downcast_ref::<(u32, f64)>(), Some(&(3, -1.5)));
        assert!(pair.is::<(u32, f64)>() && !pair.is::<(f64, u32)>());
        // A unit value and a one-byte value: no bytes past their own are read.
        assert_eq!(Payload::copied(()).downcast_ref::<()>(), Some(&()));
        assert_eq!(Payload::copied(7_u8).downcast_ref::<u8>(), Some(&7));
    }

    #[test]
    fn a_copy_value_too_large_or_too_aligned_is_shared_instead() {
        let big = Payload::copied([1.0_f64; 3]);
        assert!(!big.is_inline());
        assert_eq!(big.downcast_ref::<[f64; 3]>(), Some(&[1.0; 3]));
        assert!(Payload::ptr_eq(&big, &big.clone()), "clones share the one value");
        #[derive(Clone, Copy, PartialEq, Debug)]
        #[repr(align(16))]
        struct Wide(u8);
        let wide = Payload::copied(Wide(9));
        assert!(!wide.is_inline());
        assert_eq!(wide.downcast_ref::<Wide>(), Some(&Wide(9)));
    }

    #[test]
    fn a_shared_value_is_the_arc_it_was_made_from() {
        let counter = Arc::new(AtomicU64::new(0));
        let payload = Payload::from(Arc::clone(&counter));
        payload.downcast_ref::<AtomicU64>().expect("an AtomicU64").fetch_add(2, Ordering::Relaxed);
        assert_eq!(counter.load(Ordering::Relaxed), 2, "the receivers see the sender's value");
        assert_eq!(Arc::strong_count(&counter), 2);
        drop(payload);
        assert_eq!(Arc::strong_count(&counter), 1);
        let any: Arc<dyn Any + Send + Sync> = Arc::new(String::from("x"));
        assert_eq!(Payload::from(any).downcast_ref::<String>().map(String::as_str), Some("x"));
    }

    #[test]
    fn a_payload_is_three_words() {
        // Messages are copied into each round's batch: the inline form must not make them grow
        // past an `Arc<dyn Any>` and a tag.
        assert!(size_of::<Payload>() <= 24, "{} bytes", size_of::<Payload>());
    }
}
