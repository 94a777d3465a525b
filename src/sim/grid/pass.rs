//! Passes compiled for the processor: a loop body the caller runs with AVX2 where it has it.

/// A branch-free pass over candidate arrays, which [`vectorised`] compiles for AVX2.
///
/// `run` must be `#[inline(always)]` and call only `#[inline(always)]` code: only what is inlined
/// into [`with_avx2`] is compiled with AVX2 on. (The passes were closures until an unrelated
/// change in the wifi round tipped the compiler's inlining: the sensors' closure was then called,
/// not inlined, compiled without AVX2, and the sensors took 1.5 times as long.)
pub trait Pass {
    /// What the pass gives back.
    type Output;
    /// Do the pass.
    fn run(self) -> Self::Output;
}

/// `pass.run()`, compiled for AVX2 where the processor has it (checked at run time; the
/// standard library remembers the answer), else as it is: the compiler turns the branch-free
/// loops over candidate arrays into vector code four candidates wide. The same operations in
/// the same order either way, so the same bits.
#[inline(always)]
pub fn vectorised<P: Pass>(pass: P) -> P::Output {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2, checked just above.
        return unsafe { with_avx2(pass) };
    }
    pass.run()
}

/// `pass.run()` compiled with AVX2 on ([`vectorised`] calls it; tests call it to compare both).
///
/// # Safety
/// Only on a processor with AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub unsafe fn with_avx2<P: Pass>(pass: P) -> P::Output {
    pass.run()
}

/// Copy the items of `from` other than `none` to the front of `to` (at least as long), in order;
/// returns how many. Without a branch on the items (which are kept is unpredictable), and into
/// another buffer (in place, each store could alias the next load).
pub fn pack<T: Copy + PartialEq>(from: &[T], to: &mut [T], none: T) -> usize {
    let mut n = 0;
    for &item in from {
        to[n] = item;
        n += usize::from(item != none);
    }
    n
}
