//! Independent random streams keyed by what they are for.
//!
//! Every random number mcrad draws comes from a [`Stream`]: the estimators' rays, the reference
//! solver's shadow-ray jitter. A stream is a pure function of its key, so a result is the same
//! on any number of threads and in any scheduling.
//!
//! A stream is a PCG32 generator whose state and increment are hashes of
//! `(seed, pass, item, sub)`: the random numbers a patch uses in a pass do not depend on which
//! thread runs it or on what ran before.

use rand_core::Rng;
use rand_pcg::Pcg32;

/// What a stream is for: the run's `seed`, the `pass` (wave, round) of a schedule, the `item`
/// (patch, vertex) and a sub-stream `sub` (a purpose tag plus a chunk of the item's work).
/// Built up field by field, e.g. `StreamKey::new(seed).pass(k).item(i).substream(TAG + chunk)`; the
/// stream is a pure function of the four numbers ([`StreamKey::stream`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct StreamKey {
    /// The run seed (or a seed derived from it, [`StreamKey::derive`]).
    pub seed: u64,
    /// The pass (wave, round) within the sub-run.
    pub pass: u64,
    /// The item: a patch or a vertex group.
    pub item: u64,
    /// The sub-stream: a purpose tag plus a chunk number.
    pub sub: u64,
}

impl StreamKey {
    /// The key of run seed `seed`, pass, item and sub-stream 0.
    pub fn new(seed: u64) -> StreamKey {
        StreamKey {
            seed,
            ..StreamKey::default()
        }
    }

    /// This key with pass `pass`.
    pub fn pass(self, pass: u64) -> StreamKey {
        StreamKey { pass, ..self }
    }

    /// This key with item `item`.
    pub fn item(self, item: u64) -> StreamKey {
        StreamKey { item, ..self }
    }

    /// This key with sub-stream `sub`.
    pub fn substream(self, sub: u64) -> StreamKey {
        StreamKey { sub, ..self }
    }

    /// The key of an independent sub-run tagged `tag` (a pass of a progressive schedule, an
    /// estimator within it): seed [`derive_seed`]`(seed, tag)`, pass, item and sub-stream 0.
    pub fn derive(self, tag: u64) -> StreamKey {
        StreamKey::new(derive_seed(self.seed, tag))
    }

    /// The stream of this key: [`Stream::new`]`(seed, pass, item, sub)`.
    pub fn stream(self) -> Stream {
        Stream::new(self.seed, self.pass, self.item, self.sub)
    }
}

/// A random stream for one `(seed, pass, item, sub)` ([`StreamKey`]).
#[derive(Debug, Clone)]
pub struct Stream(Pcg32);

/// SplitMix64's finaliser: a bijective 64-bit mix.
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A seed for an independent sub-run (a pass of a progressive schedule, an estimator within
/// it): a hash of the run's `seed` and a `tag`. Different tags give unrelated streams.
pub fn derive_seed(seed: u64, tag: u64) -> u64 {
    mix(mix(seed ^ 0x2545_f491_4f6c_dd1d) ^ mix(tag.wrapping_add(0x9e37_79b9_7f4a_7c15)))
}

impl Stream {
    /// The stream for run seed `seed`, pass (wave, round) `pass`, item (patch, vertex) `item` and
    /// sub-stream `sub` (a purpose tag or a chunk of the item's work).
    pub fn new(seed: u64, pass: u64, item: u64, sub: u64) -> Stream {
        let mut h = mix(seed ^ 0x9e37_79b9_7f4a_7c15);
        for x in [pass, item, sub] {
            h = mix(h ^ mix(x.wrapping_add(0x632b_e59b_d9b4_e019)));
        }
        Stream(Pcg32::new(h, mix(h ^ 0xd1b5_4a32_d192_ed03)))
    }

    /// A uniform `f32` in `[0, 1)` (24 random bits).
    #[inline]
    pub fn uniform(&mut self) -> f32 {
        (self.0.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    /// A uniform `f64` in `[0, 1)` (53 random bits).
    #[inline]
    pub fn uniform_f64(&mut self) -> f64 {
        let hi = (self.0.next_u32() as u64) << 21;
        let lo = (self.0.next_u32() >> 11) as u64;
        (hi | lo) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: Vec<f32> = (0..8)
            .map({
                let mut s = Stream::new(1, 2, 3, 4);
                move |_| s.uniform()
            })
            .collect();
        let b: Vec<f32> = (0..8)
            .map({
                let mut s = Stream::new(1, 2, 3, 4);
                move |_| s.uniform()
            })
            .collect();
        assert_eq!(a, b);
        for key in [
            (0, 2, 3, 4),
            (1, 0, 3, 4),
            (1, 2, 0, 4),
            (1, 2, 3, 0),
            (1, 3, 2, 4),
        ] {
            let mut s = Stream::new(key.0, key.1, key.2, key.3);
            let c: Vec<f32> = (0..8).map(|_| s.uniform()).collect();
            assert_ne!(a, c, "{key:?}");
        }
    }

    #[test]
    fn keys_give_the_streams_of_their_numbers() {
        let key = StreamKey::new(1).pass(2).item(3).substream(4);
        let (mut a, mut b) = (key.stream(), Stream::new(1, 2, 3, 4));
        for _ in 0..8 {
            assert_eq!(a.uniform().to_bits(), b.uniform().to_bits());
        }
        let derived = StreamKey::new(9).pass(5).derive(7);
        assert_eq!(derived, StreamKey::new(derive_seed(9, 7)));
    }

    #[test]
    fn uniforms_lie_in_the_unit_interval() {
        let mut s = Stream::new(7, 0, 0, 0);
        for _ in 0..100_000 {
            let (x, y) = (s.uniform(), s.uniform_f64());
            assert!((0.0..1.0).contains(&x) && (0.0..1.0).contains(&y));
        }
    }
}
