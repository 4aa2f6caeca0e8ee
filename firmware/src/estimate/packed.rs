//! Packed storage of symmetric matrices: only the upper triangle, row by row.
//!
//! A 10×10 covariance takes 55 floats (220 bytes) instead of 100 (400 bytes), which is
//! what lets a few hundred Gaussians fit the STM32F405's RAM.

use nalgebra::SMatrix;

/// Index of element `(i, j)`, `i <= j`, in the packed upper triangle of a `D×D` matrix.
const fn packed_index(d: usize, i: usize, j: usize) -> usize {
    i * d - i * i.saturating_sub(1) / 2 + (j - i)
}

/// Packs the upper triangle of `m` (the lower one is assumed equal).
pub(crate) fn pack<const D: usize, const L: usize>(m: &SMatrix<f32, D, D>) -> [f32; L] {
    const { assert!(L == D * (D + 1) / 2) };
    let mut out = [0.0; L];
    let mut k = 0;
    for i in 0..D {
        for j in i..D {
            if let Some(slot) = out.get_mut(k) {
                *slot = m[(i, j)];
            }
            k += 1;
        }
    }
    out
}

/// Unpacks into a full symmetric matrix.
pub(crate) fn unpack<const D: usize, const L: usize>(a: &[f32; L]) -> SMatrix<f32, D, D> {
    const { assert!(L == D * (D + 1) / 2) };
    let mut m = SMatrix::<f32, D, D>::zeros();
    let mut k = 0;
    for i in 0..D {
        for j in i..D {
            let v = a.get(k).copied().unwrap_or(0.0);
            m[(i, j)] = v;
            m[(j, i)] = v;
            k += 1;
        }
    }
    m
}

/// Element `(i, j)` of a packed `D×D` symmetric matrix (either triangle).
pub(crate) fn get<const L: usize>(a: &[f32; L], d: usize, i: usize, j: usize) -> f32 {
    let (i, j) = if i <= j { (i, j) } else { (j, i) };
    a.get(packed_index(d, i, j)).copied().unwrap_or(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_indexing() {
        let mut m = SMatrix::<f32, 10, 10>::zeros();
        for i in 0..10 {
            for j in 0..10 {
                m[(i, j)] = (i.min(j) * 10 + i.max(j)) as f32;
            }
        }
        let p: [f32; 55] = pack(&m);
        assert_eq!(unpack::<10, 55>(&p), m);
        for i in 0..10 {
            for j in 0..10 {
                assert_eq!(get(&p, 10, i, j), m[(i, j)], "({i},{j})");
            }
        }
    }
}
