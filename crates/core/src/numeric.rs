//! Small numeric helpers shared by the scan engine and the scoring layers.
//!
//! They sit in a leaf module of their own so that every layer can use them
//! without importing from a parent (the scoring layers would otherwise
//! reach up into `vpr`, and `vpr` down into them again).

/// `clip(x, 0, 1)`, with NaN mapped to 0 and −0 to +0 so that scores always
/// order sensibly.
pub(crate) fn clip01(x: f32) -> f32 {
    if x > 0.0 {
        x.min(1.0)
    } else {
        0.0
    }
}

/// Copies of the rows `order` lists, in that order, from a row-major table
/// of `stride` values a row: the read-only half of a reordering
/// (descriptor codes, thumbnails).
pub(crate) fn gather_rows<T: Copy>(data: &[T], stride: usize, order: &[usize]) -> Vec<T> {
    let mut gathered = Vec::with_capacity(order.len() * stride);
    for &row in order {
        gathered.extend_from_slice(&data[row * stride..(row + 1) * stride]);
    }
    gathered
}

/// FNV-1a (64 bits) over `parts`, a 0xff byte between each two (no UTF-8
/// string holds one, so the parts cannot run into each other): the hash
/// of a key that every process and build computes alike (graph keys,
/// saved graphs' names, the null model's sample tags).
pub(crate) fn fnv1a(parts: &[&[u8]]) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for (i, part) in parts.iter().enumerate() {
        let separator: &[u8] = if i == 0 { &[] } else { &[0xff] };
        for &b in separator.iter().chain(part.iter()) {
            hash ^= u64::from(b);
            hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    hash
}

/// Asks the CPU to start loading `data` into its caches, one hint per
/// 64-byte line (x86-64; elsewhere nothing). For reads whose addresses the
/// hardware prefetcher cannot foresee: rows scattered over a large table.
pub(crate) fn prefetch<T>(data: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let start = data.as_ptr().cast::<u8>();
        for offset in (0..std::mem::size_of_val(data)).step_by(64) {
            #[allow(
                unsafe_code,
                reason = "_mm_prefetch is a #[target_feature(sse)] intrinsic; SSE is part of x86-64"
            )]
            // SAFETY: a prefetch is a hint: it reads nothing the program
            // sees and cannot fault, and the address is within `data`.
            unsafe {
                _mm_prefetch::<_MM_HINT_T0>(start.add(offset).cast())
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = data;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clip01_orders_nan_and_negative_zero_first() {
        assert_eq!(clip01(f32::NAN).to_bits(), 0.0f32.to_bits());
        assert_eq!(clip01(-0.0).to_bits(), 0.0f32.to_bits());
        assert_eq!(clip01(-3.0), 0.0);
        assert_eq!(clip01(0.25), 0.25);
        assert_eq!(clip01(7.0), 1.0);
    }

    #[test]
    fn gather_rows_copies_the_listed_rows_in_order() {
        let table = [1, 2, 3, 4, 5, 6];
        assert_eq!(gather_rows(&table, 2, &[2, 0]), vec![5, 6, 1, 2]);
        assert!(gather_rows(&table, 2, &[]).is_empty());
    }
}
