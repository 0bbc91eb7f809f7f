//! Synthetic fleet descriptors, for benchmarks and load tests.
//!
//! `humem bench scan` and `humem load` both need stores shaped like a
//! fleet's: robots that pass places in short runs and come back to them,
//! each descriptor its place's centre plus noise, unit length. One
//! generator here keeps the two measuring the same kind of store, seeded
//! and cheap (a xorshift, no dependency), and not a real random source: it
//! is for data, never for anything secret.

/// A xorshift generator: fast, seeded, good enough for synthetic vectors.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator seeded with `seed` (any value, 0 included).
    pub fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    /// The next 64 random bits.
    #[allow(
        clippy::should_implement_trait,
        reason = "a generator, not an iterator: it never ends"
    )]
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// Uniform in [−0.5, 0.5).
    pub fn centred(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    }
}

/// The place `robot` sees at its keyframe `step`, among `places`: each
/// robot passes places in runs of 4 keyframes and comes back to them later.
pub fn place_of(places: u64, robot: u64, step: u64) -> u64 {
    Rng::new(step / 4 * 31 + robot).next() % places.max(1)
}

/// A descriptor of length `dim` seen at `place`: the place's centre (the
/// same for every robot) plus 0.6 × `noise`, scaled to unit length.
pub fn place_descriptor(dim: usize, place: u64, noise: &mut Rng) -> Vec<f32> {
    let mut centre = Rng::new(place + 7);
    let mut descriptor: Vec<f32> = (0..dim)
        .map(|_| centre.centred() + 0.6 * noise.centred())
        .collect();
    let norm = descriptor.iter().map(|v| v * v).sum::<f32>().sqrt();
    if norm > 0.0 {
        descriptor.iter_mut().for_each(|v| *v /= norm);
    }
    descriptor
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn descriptors_are_unit_length_and_a_place_looks_alike_for_every_robot() {
        let mut noise = Rng::new(1);
        assert_eq!(place_of(1, 3, 40), 0);
        assert_eq!(place_of(500, 2, 8), place_of(500, 2, 11), "runs of 4");
        let a = place_descriptor(256, 0, &mut noise);
        let b = place_descriptor(256, 0, &mut noise);
        let norm = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>().sqrt();
        assert!((norm(&a) - 1.0).abs() < 1e-5 && (norm(&b) - 1.0).abs() < 1e-5);
        let same: f32 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
        let other = place_descriptor(256, 1, &mut noise);
        let apart: f32 = a.iter().zip(&other).map(|(x, y)| x * y).sum();
        assert!(same > 0.5 && apart < 0.3, "{same} {apart}");
    }
}
