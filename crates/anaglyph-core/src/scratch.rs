//! Per-thread working buffers that outlive rayon's split jobs. `for_each_init` makes its
//! state anew for every job it splits a loop into; buffers of several MB made and freed
//! that often go back to the kernel and are faulted in, zeroed, again (on a 741×500 pair
//! the tower's strips took 56 000 page faults, a third of `match`'s system time). A pool
//! keeps the buffers of one loop: a job takes one (or a new one) and gives it back when
//! it ends.

use std::ops::{Deref, DerefMut};
use std::sync::Mutex;

/// Buffers of type `T`, lent one per job.
pub(crate) struct ScratchPool<T> {
    free: Mutex<Vec<T>>,
}

impl<T: Default> ScratchPool<T> {
    pub(crate) fn new() -> Self {
        ScratchPool {
            free: Mutex::new(Vec::new()),
        }
    }

    /// A buffer given back earlier, else a new one; it returns to the pool when dropped.
    pub(crate) fn take(&self) -> Lent<'_, T> {
        let value = self.lock().pop().unwrap_or_default();
        Lent {
            pool: self,
            value: Some(value),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<T>> {
        // A job that panicked while holding the lock left the list whole: keep using it.
        self.free
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

/// A buffer lent by a [`ScratchPool`].
pub(crate) struct Lent<'a, T: Default> {
    pool: &'a ScratchPool<T>,
    value: Option<T>,
}

impl<T: Default> Deref for Lent<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        self.value
            .as_ref()
            .expect("a lent buffer is held until dropped")
    }
}

impl<T: Default> DerefMut for Lent<'_, T> {
    fn deref_mut(&mut self) -> &mut T {
        self.value
            .as_mut()
            .expect("a lent buffer is held until dropped")
    }
}

impl<T: Default> Drop for Lent<'_, T> {
    fn drop(&mut self) {
        if let Some(value) = self.value.take() {
            self.pool.lock().push(value);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn buffers_are_reused_across_jobs_and_never_shared() {
        let pool = ScratchPool::<Vec<usize>>::new();
        let mut out = vec![0usize; 1000];
        out.par_chunks_mut(3).enumerate().for_each_init(
            || pool.take(),
            |buffer, (i, chunk)| {
                buffer.clear();
                buffer.extend(std::iter::repeat_n(i, chunk.len()));
                chunk.copy_from_slice(buffer);
            },
        );
        assert!(out.iter().enumerate().all(|(k, &v)| v == k / 3));
        let kept = pool.lock().len();
        assert!(
            (1..=rayon::current_num_threads()).contains(&kept),
            "{kept} buffers kept"
        );
        // A sequential second loop takes one buffer and gives it back.
        drop(pool.take());
        assert_eq!(pool.lock().len(), kept);
    }
}
