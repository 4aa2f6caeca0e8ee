//! Where a mixture's components live: a fixed-capacity vector of its own
//! ([`super::SogFilter`]), or one victim's share of a component pool shared by several
//! victims ([`PoolShare`], see [`crate::victims`]).
//!
//! The mixture operations (IROS Algorithm 1's update, normalization, pruning, merging,
//! splitting, initialization) only need a resizable slice with a capacity, so they are
//! written once against [`Store`] and run unchanged on either.

use super::gaussian::Component;
use core::ops::{Deref, DerefMut};
use heapless::Vec;

/// A resizable slice of components with a fixed capacity (the subset of
/// `heapless::Vec`'s API the mixture operations use).
pub(crate) trait Store: Deref<Target = [Component]> + DerefMut {
    /// Components this store can hold now.
    fn capacity(&self) -> usize;
    /// Appends `c`, or gives it back when full.
    fn push(&mut self, c: Component) -> Result<(), Component>;
    /// Removes component `i` (the last one takes its place); `None` if out of range.
    fn remove_swap(&mut self, i: usize) -> Option<Component>;
    /// Keeps the first `n` components.
    fn truncate(&mut self, n: usize);

    /// Removes every component.
    fn clear(&mut self) {
        self.truncate(0);
    }

    /// Keeps the components for which `keep` holds, in their order.
    fn retain(&mut self, mut keep: impl FnMut(&Component) -> bool) {
        let mut w = 0;
        for r in 0..self.len() {
            let Some(c) = self.get(r).copied() else {
                break;
            };
            if keep(&c) {
                if let Some(slot) = self.get_mut(w) {
                    *slot = c;
                }
                w += 1;
            }
        }
        self.truncate(w);
    }
}

impl<const N: usize> Store for Vec<Component, N> {
    fn capacity(&self) -> usize {
        N
    }

    fn push(&mut self, c: Component) -> Result<(), Component> {
        Vec::push(self, c)
    }

    fn remove_swap(&mut self, i: usize) -> Option<Component> {
        (i < self.len()).then(|| self.swap_remove(i))
    }

    fn truncate(&mut self, n: usize) {
        Vec::truncate(self, n);
    }
}

/// The tail of a pool, from `start` on, holding one mixture: it may grow up to `cap`
/// components (and no further than the pool's end). The pool's other mixtures lie before
/// `start` and are not touched.
pub(crate) struct PoolShare<'a, const P: usize> {
    pool: &'a mut Vec<Component, P>,
    start: usize,
    cap: usize,
}

impl<'a, const P: usize> PoolShare<'a, P> {
    /// The mixture at `pool[start..]`, limited to `cap` components (at most what the pool
    /// has room for). `start` beyond the pool's length is clamped to it (an empty mixture).
    pub(crate) fn new(pool: &'a mut Vec<Component, P>, start: usize, cap: usize) -> Self {
        let start = start.min(pool.len());
        let cap = cap.min(P - start);
        Self { pool, start, cap }
    }
}

impl<const P: usize> Deref for PoolShare<'_, P> {
    type Target = [Component];
    fn deref(&self) -> &[Component] {
        self.pool.get(self.start..).unwrap_or(&[])
    }
}

impl<const P: usize> DerefMut for PoolShare<'_, P> {
    fn deref_mut(&mut self) -> &mut [Component] {
        self.pool.get_mut(self.start..).unwrap_or(&mut [])
    }
}

impl<const P: usize> Store for PoolShare<'_, P> {
    fn capacity(&self) -> usize {
        self.cap
    }

    fn push(&mut self, c: Component) -> Result<(), Component> {
        if self.pool.len() >= self.start + self.cap {
            return Err(c);
        }
        self.pool.push(c)
    }

    fn remove_swap(&mut self, i: usize) -> Option<Component> {
        let k = self.start.checked_add(i)?;
        (k < self.pool.len()).then(|| self.pool.swap_remove(k))
    }

    fn truncate(&mut self, n: usize) {
        self.pool.truncate(self.start.saturating_add(n));
    }
}

#[cfg(test)]
mod tests {
    use super::super::model::{StateMat, StateVec};
    use super::*;

    fn comp(k: f32) -> Component {
        Component::new(StateVec::repeat(k), &StateMat::identity(), -k)
    }

    #[test]
    fn a_pool_share_grows_within_its_cap_and_leaves_the_rest_alone() {
        let mut pool: Vec<Component, 8> = Vec::new();
        for k in 0..3 {
            pool.push(comp(k as f32)).unwrap();
        }
        {
            let mut s = PoolShare::new(&mut pool, 2, 4);
            assert_eq!((s.len(), s.capacity()), (1, 4));
            for k in 10..13 {
                s.push(comp(k as f32)).unwrap();
            }
            assert!(s.push(comp(99.0)).is_err(), "cap reached");
            assert_eq!(s.remove_swap(0).map(|c| c.log_w), Some(-2.0));
            assert_eq!(s.remove_swap(3), None);
            s.retain(|c| c.log_w != -11.0);
            let w: std::vec::Vec<f32> = s.iter().map(|c| c.log_w).collect();
            assert_eq!(w, [-12.0, -10.0]);
            s.clear();
            assert!(s.is_empty());
        }
        let w: std::vec::Vec<f32> = pool.iter().map(|c| c.log_w).collect();
        assert_eq!(
            w,
            [0.0, -1.0],
            "the mixtures before the share are untouched"
        );
        // The cap never reaches past the pool's end.
        assert_eq!(PoolShare::new(&mut pool, 2, 100).capacity(), 6);
        assert_eq!(PoolShare::new(&mut pool, 50, 4).len(), 0);
    }

    #[test]
    fn vec_retain_keeps_the_order() {
        let mut v: Vec<Component, 8> = Vec::new();
        for k in 0..6 {
            v.push(comp(k as f32)).unwrap();
        }
        Store::retain(&mut v, |c| c.log_w as i32 % 2 == 0);
        let w: std::vec::Vec<f32> = v.iter().map(|c| c.log_w).collect();
        assert_eq!(w, [0.0, -2.0, -4.0]);
    }
}
