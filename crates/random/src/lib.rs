//! Independent random streams keyed by what they are for.
//!
//! Every random number mcrad draws comes from a [`Stream`]: the estimators' rays, the reference
//! solver's shadow-ray jitter. A stream is a pure function of its key, so a result is the same
//! on any number of threads and in any scheduling.
//!
//! A stream is a PCG32 generator whose state and increment are hashes of
//! `(seed, pass, item, sub)`: the random numbers a patch uses in a pass do not depend on which
//! thread runs it or on what ran before.
//!
//! A key also names a randomised quasi-Monte Carlo sequence ([`Sobol`]): Owen-scrambled Sobol
//! points in `[0, 1)^8`, indexed by the item's own sample counter, the scramble a hash of the
//! key. Points of one key are stratified against each other; points of different keys are
//! independent randomisations.

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

    /// The quasi-Monte Carlo sequence of this key ([`Sobol::new`]).
    pub fn sobol(self) -> Sobol {
        Sobol::new(self)
    }
}

/// Points of one Owen-scrambled Sobol sequence block: [`Sobol`] draws the sequence in blocks of
/// this many points (`2^16`, the most one scramble of `sobol_burley` holds).
pub const SOBOL_BLOCK: u64 = 1 << 16;

/// Interleaved randomisations in one [`Sobol`] sequence: point `k` is point `k / REPLICATES`
/// of the sequence's scramble number `k mod REPLICATES` ([`replicate`]).
pub const REPLICATES: u64 = 2;

/// The replicate (independent scramble) point `index` of a [`Sobol`] sequence belongs to, in
/// `0..REPLICATES`.
#[inline]
pub fn replicate(index: u64) -> usize {
    (index % REPLICATES) as usize
}

/// A randomised quasi-Monte Carlo sequence of points in `[0, 1)^8`, a pure function of its
/// [`StreamKey`]: Owen-scrambled Sobol points (Burley's hash-based scrambling, the
/// `sobol_burley` crate), point `k` given by [`Sobol::point`] (dimensions 0-3) and
/// [`Sobol::point_next`] (dimensions 4-7).
///
/// Each point is uniform on the unit cube (the scramble is random), so an estimator averaging a
/// function over the points is unbiased. The sequence interleaves [`REPLICATES`] independent
/// randomisations: point `k` is point `k / REPLICATES` of scramble `k mod REPLICATES`, so the
/// means over the even and the odd points of an estimator are independent and identically
/// distributed, and their difference is an honest measure of the stratified points' error
/// (which the independent-sample formula `s² / n` overstates). Within a replicate the points
/// are stratified: any aligned run of `2^m` of its indices (`k / REPLICATES = j 2^m .. (j + 1)
/// 2^m`, `2^m <= 2^16`) is a `(0, m, 2)`-net in dimensions 0-1 (every elementary interval of
/// area `2^-m` holds one point) and a `(2, m, 2)`-net in dimensions 2-3 (every one of area
/// `2^(2-m)` holds four), the Sobol sequence's own `t` values, which Owen scrambling keeps.
/// A replicate comes in blocks of [`SOBOL_BLOCK`] points: its point `j` is point `j mod 2^16`
/// of a scramble keyed by the key, the replicate and the block `j / 2^16`, so past `2^16`
/// points it goes on with an independent randomisation. Different keys give independent
/// randomisations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sobol {
    hash: u64,
}

impl Sobol {
    /// The sequence of `key`.
    pub fn new(key: StreamKey) -> Sobol {
        let mut h = mix(key.seed ^ 0x5851_f42d_4c95_7f2d);
        for x in [key.pass, key.item, key.sub] {
            h = mix(h ^ mix(x.wrapping_add(0x1405_7b7e_f767_814f)));
        }
        Sobol { hash: h }
    }

    /// The index within its scramble, and the scramble's seed, of point `index`.
    #[inline]
    fn locate(&self, index: u64) -> (u32, u32) {
        let (r, j) = (index % REPLICATES, index / REPLICATES);
        let block = j / SOBOL_BLOCK;
        let seed = mix(self.hash
            ^ mix(block.wrapping_add(0x2545_f491_4f6c_dd1d))
            ^ mix(r.wrapping_add(0x6a09_e667_f3bc_c909)));
        ((j % SOBOL_BLOCK) as u32, (seed >> 32) as u32)
    }

    /// Dimensions 0-3 of point `index`, each in `[0, 1)`.
    #[inline]
    pub fn point(&self, index: u64) -> [f32; 4] {
        let (k, seed) = self.locate(index);
        sobol_burley::sample_4d(k, 0, seed)
    }

    /// Dimensions 4-7 of point `index`, each in `[0, 1)`: with [`Sobol::point`], an 8-D point.
    #[inline]
    pub fn point_next(&self, index: u64) -> [f32; 4] {
        let (k, seed) = self.locate(index);
        sobol_burley::sample_4d(k, 1, seed)
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

#[cfg(test)]
mod sobol_tests {
    use super::*;

    /// The smallest `t` for which `points` (a set of `2^m`) is a `(t, m, 2)`-net in dimensions
    /// `a` and `b`: every box `[i 2^-p, (i+1) 2^-p) x [j 2^-q, (j+1) 2^-q)` with `p + q = m - t`
    /// holds exactly `2^t` points.
    pub(crate) fn t_value(points: &[[f32; 8]], a: usize, b: usize) -> u32 {
        let m = points.len().trailing_zeros();
        assert_eq!(points.len(), 1 << m);
        (0..=m)
            .find(|&t| {
                (0..=m - t).all(|p| {
                    let q = m - t - p;
                    let mut cells = vec![0u32; 1 << (m - t)];
                    for x in points {
                        let i = (x[a] * (1u64 << p) as f32) as usize;
                        let j = (x[b] * (1u64 << q) as f32) as usize;
                        cells[(i << q) | j] += 1;
                    }
                    cells.iter().all(|&c| c == 1 << t)
                })
            })
            .expect("t = m always holds")
    }

    /// The first `n` points of `s` as 8-D points, from `start`.
    fn points(s: &Sobol, start: u64, n: u64) -> Vec<[f32; 8]> {
        (start..start + n)
            .map(|k| {
                let (p, q) = (s.point(k), s.point_next(k));
                [p[0], p[1], p[2], p[3], q[0], q[1], q[2], q[3]]
            })
            .collect()
    }

    /// Points `start, start + REPLICATES, ...` of `s` (one replicate's), `n` of them.
    fn replicate_points(s: &Sobol, start: u64, n: u64) -> Vec<[f32; 8]> {
        points(s, 0, start + n * REPLICATES)
            .into_iter()
            .skip(start as usize)
            .step_by(REPLICATES as usize)
            .collect()
    }

    /// Stratification, exact: in each replicate, every aligned run of `2^m` points (the first
    /// ones, and ones further on, as a patch's counter continues across waves) is a
    /// `(0, m, 2)`-net in dimensions 0-1 and a `(2, m, 2)`-net in dimensions 2-3, for several
    /// keys; and so is a run that crosses into the second block of `2^16` (a fresh scramble,
    /// still a net).
    #[test]
    fn aligned_runs_are_nets() {
        for key in 0..4u64 {
            let s = StreamKey::new(key).item(7 * key + 1).substream(3).sobol();
            for r in 0..REPLICATES {
                for m in [1u32, 4, 7, 10] {
                    for j in [0u64, 1, 5] {
                        let start = r + (j << m) * REPLICATES;
                        let pts = replicate_points(&s, start, 1 << m);
                        assert_eq!(t_value(&pts, 0, 1), 0, "key {key} r {r} m {m} run {j}");
                        assert!(t_value(&pts, 2, 3) <= 2, "key {key} r {r} m {m} run {j}");
                    }
                }
            }
            let pts = replicate_points(&s, SOBOL_BLOCK * REPLICATES, 1 << 10);
            assert_eq!(t_value(&pts, 0, 1), 0);
        }
    }

    /// The replicates are independent randomisations: their points differ, the replicate of
    /// an index is its residue, and the correlation of the two replicates' means of a smooth
    /// function over 4096 keys is within 4.5 standard errors of 0 (`1/sqrt(4096)` each; a false
    /// failure rate below 1e-5), where one scramble's halves would be strongly anti-correlated.
    #[test]
    fn replicates_are_independent() {
        assert_eq!((replicate(0), replicate(1), replicate(2)), (0, 1, 0));
        let s = StreamKey::new(3).sobol();
        assert_ne!(replicate_points(&s, 0, 16), replicate_points(&s, 1, 16));
        let f = |p: [f32; 4]| f64::from(p[0] * p[1] + p[2] * p[2] - p[3]);
        let (n, keys) = (16u64, 4096u64);
        let means: Vec<[f64; 2]> = (0..keys)
            .map(|key| {
                let s = StreamKey::new(key).item(1).sobol();
                let mut m = [0.0; 2];
                for k in 0..n * REPLICATES {
                    m[replicate(k)] += f(s.point(k)) / n as f64;
                }
                m
            })
            .collect();
        let mean = |c: usize| means.iter().map(|m| m[c]).sum::<f64>() / keys as f64;
        let (a, b) = (mean(0), mean(1));
        let cov = means.iter().map(|m| (m[0] - a) * (m[1] - b)).sum::<f64>();
        let var = |c: usize, mu: f64| means.iter().map(|m| (m[c] - mu).powi(2)).sum::<f64>();
        let corr = cov / (var(0, a) * var(1, b)).sqrt();
        assert!(
            corr.abs() < 4.5 / (keys as f64).sqrt(),
            "correlation {corr}"
        );
    }

    /// Points of one key are reproducible; other keys and the next block give other points.
    #[test]
    fn keys_and_blocks_give_independent_scrambles() {
        let key = StreamKey::new(1).pass(2).item(3).substream(4);
        assert_eq!(points(&key.sobol(), 0, 16), points(&Sobol::new(key), 0, 16));
        let a = points(&key.sobol(), 0, 16);
        for other in [
            key.pass(0),
            key.item(0),
            key.substream(0),
            StreamKey::new(0).pass(2).item(3).substream(4),
        ] {
            assert_ne!(a, points(&other.sobol(), 0, 16));
        }
        assert_ne!(a, points(&key.sobol(), SOBOL_BLOCK, 16));
    }

    /// Uniformity: Pearson's chi-square of 4-D points on a 4^4 grid, pooled over 64 keys of 256
    /// points each (256 cells, 64 points expected per cell). For independent uniform points
    /// the statistic is chi-square with 255 degrees of freedom; the test fails above its
    /// 1 - 1e-6 quantile (about 372; a false failure rate of 1e-6 for random points, lower for
    /// stratified ones, whose counts vary less). A biased scramble or a broken map to the unit
    /// cube would put tens of thousands here.
    #[test]
    fn four_d_points_are_uniform() {
        let mut cells = [0u32; 256];
        for key in 0..64u64 {
            let s = StreamKey::new(key).item(key * 3).sobol();
            for k in 0..256 {
                let p = s.point(k);
                let c = p
                    .iter()
                    .fold(0usize, |c, &x| c * 4 + ((x * 4.0) as usize).min(3));
                cells[c] += 1;
            }
        }
        let expected = 64.0 * 256.0 / 256.0;
        let chi2: f64 = cells
            .iter()
            .map(|&o| (o as f64 - expected).powi(2) / expected)
            .sum();
        // The 1 - 1e-6 quantile of chi-square(255), by Wilson and Hilferty's approximation.
        let (df, z) = (255.0f64, 4.753);
        let h = 2.0 / (9.0 * df);
        let quantile = df * (1.0 - h + z * h.sqrt()).powi(3);
        assert!(chi2 < quantile, "chi2 {chi2} >= {quantile}: {cells:?}");
        for key in 0..4u64 {
            for p in points(&StreamKey::new(key).sobol(), 0, 1 << 12) {
                assert!(p.iter().all(|x| (0.0..1.0).contains(x)), "{p:?}");
            }
        }
    }
}
