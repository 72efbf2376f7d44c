//! The job plumbing the gatherers share: work split into jobs of at most [`JOB_RAYS`] rays
//! (the unit of parallel work and of random streams), run in parallel and reduced in a fixed
//! order, so a seed gives the same answer on any number of threads.

use crate::replicates::{Halves, Row};
use glam::DVec3;
use mcrad_meshing::Patch;
use mcrad_random::replicate;
use mcrad_raycast::{Hit, Ray, RayCaster};
use rayon::prelude::*;

/// Rays (or samples) per job: the unit of parallel work and of random streams. A multiple of
/// [`mcrad_random::REPLICATES`], so that a job's ray `t` is of replicate `t mod REPLICATES`.
pub(crate) const JOB_RAYS: u32 = 4096;
/// Sub-stream tag of patch gathering ([`gather_round`](crate::gather_round)); the chunk number is added to it.
pub(crate) const PATCH_GATHER: u64 = 1 << 40;
/// Sub-stream tag of vertex gathering ([`gather_corners`](crate::gather_corners)).
pub(crate) const VERTEX_GATHER: u64 = 2 << 40;
/// Sub-stream tag of direct-light sampling ([`direct`](crate::direct())).
pub(crate) const DIRECT_LIGHT: u64 = 3 << 40;
/// Sub-stream tag of the pilot that sizes direct-light sampling to a ray budget
/// ([`split_with_budget`](crate::direct::split_with_budget)).
pub(crate) const DIRECT_PILOT: u64 = 4 << 40;
/// Sub-stream tag of a patch's quasi-Monte Carlo sequence in shooting
/// ([`shoot`](crate::shoot())); its index is the patch's ray counter over the run's waves.
pub(crate) const SHOOT_QMC: u64 = 5 << 40;

/// Running mean and sum of squared deviations of per-ray samples, per RGB channel (Welford's
/// update, Chan et al.'s merge), in f64. A constant sample has exactly zero deviation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Moments {
    pub n: u64,
    pub mean: DVec3,
    pub m2: DVec3,
}

impl Moments {
    /// Adds one sample.
    #[inline]
    pub fn push(&mut self, x: DVec3) {
        self.n += 1;
        let delta = x - self.mean;
        self.mean += delta / self.n as f64;
        self.m2 += delta * (x - self.mean);
    }

    /// The moments of both sample sets together.
    pub fn merge(self, other: Moments) -> Moments {
        if self.n == 0 {
            return other;
        }
        if other.n == 0 {
            return self;
        }
        let n = self.n + other.n;
        let delta = other.mean - self.mean;
        let w = other.n as f64 / n as f64;
        Moments {
            n,
            mean: self.mean + delta * w,
            m2: self.m2 + other.m2 + delta * delta * (self.n as f64 * w),
        }
    }

    /// The estimated variance of the sample mean, `s² / n` with `s²` the unbiased sample
    /// variance; zero below two samples.
    pub fn variance_of_mean(&self) -> DVec3 {
        if self.n < 2 {
            return DVec3::ZERO;
        }
        (self.m2 / ((self.n - 1) as f64 * self.n as f64)).max(DVec3::ZERO)
    }
}

/// One job: `rays` rays of item `item` (a patch or a vertex group), chunk `chunk` of them.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Job {
    pub item: u32,
    pub chunk: u32,
    pub rays: u32,
}

/// The jobs of `items` items with `per_item` rays each, item by item, chunk by chunk.
pub(crate) fn jobs(items: usize, per_item: u32) -> Vec<Job> {
    let chunks = per_item.div_ceil(JOB_RAYS);
    (0..items as u32)
        .flat_map(|item| {
            (0..chunks).map(move |chunk| Job {
                item,
                chunk,
                rays: (per_item - chunk * JOB_RAYS).min(JOB_RAYS),
            })
        })
        .collect()
}

/// What the rays of one job saw.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Seen {
    pub moments: Moments,
    pub escaped: u64,
    pub back_faces: u64,
    /// Sum over the rays of `F̂_ij V_j` at each front-face hit `j` ([`disc_form_factor`] times
    /// the input's variance there; 0 for the other rays).
    pub inherited: DVec3,
    /// Rays that summed into `inherited`.
    pub inherit_rays: u64,
    /// The sum over the `inherit_rays` rays of the emission `E_j` of the patch `j` hit (0 for
    /// a miss, a back face or a patch that does not emit; recorded with `inherit`), W/m²: the
    /// part of the value seen that is the same in every round of a Jacobi run.
    pub emitted: DVec3,
    /// The sum of the squares of the same, (W/m²)².
    pub emitted_squares: DVec3,
    /// The values split by the replicate of the ray's point in its sequence (ray `t` of a job
    /// is point `chunk * JOB_RAYS + t`, replicate `t mod 2`; [`crate::replicates`]).
    pub halves: Halves,
    /// The sum over the rays of the input's error samples at each front-face hit (0 for the
    /// other rays; recorded where the caller gives them: [`crate::replicates::Row`]).
    pub sketch: Row,
    /// The replicates' estimate of the variance of `sketch` over these rays, summed over the
    /// samples, per channel: `sum_g |a_g - b_g|² 4 n_0 n_1 / n²` with `a_g`, `b_g` the
    /// replicates' sums of sample `g` scaled to the whole (`n / (2 n_r)`). The noise of the
    /// rays' sampling of the input's error, which a gather's own noise (measured from the
    /// values it saw, error included) holds too (`crate::schedule::combined`).
    pub sketch_variance: DVec3,
}

impl Seen {
    fn merge(self, other: Seen) -> Seen {
        Seen {
            moments: self.moments.merge(other.moments),
            escaped: self.escaped + other.escaped,
            back_faces: self.back_faces + other.back_faces,
            inherited: self.inherited + other.inherited,
            inherit_rays: self.inherit_rays + other.inherit_rays,
            emitted: self.emitted + other.emitted,
            emitted_squares: self.emitted_squares + other.emitted_squares,
            halves: self.halves.merge(other.halves),
            sketch: std::array::from_fn(|k| self.sketch[k] + other.sketch[k]),
            sketch_variance: self.sketch_variance + other.sketch_variance,
        }
    }

    /// The sum of squared deviations from their mean of the emission the `inherit_rays` rays
    /// saw, `sum e² - (sum e)² / n` ((W/m²)²; 0 without rays).
    pub(crate) fn emitted_m2(&self) -> DVec3 {
        if self.inherit_rays == 0 {
            return DVec3::ZERO;
        }
        (self.emitted_squares - self.emitted * self.emitted / self.inherit_rays as f64)
            .max(DVec3::ZERO)
    }

    /// The estimate of `sum_j F_ij² V_j`: the mean over the rays of `F̂_ij V_j` (a ray of patch
    /// `i` hits `j` with probability `F_ij`, and `F̂_ij` estimates `F_ij` from the hit's
    /// geometry); 0 without rays.
    pub(crate) fn inherited_mean(&self) -> DVec3 {
        if self.inherit_rays == 0 {
            DVec3::ZERO
        } else {
            self.inherited / self.inherit_rays as f64
        }
    }
}

/// Casts `n` rays from `ray` and records `input` at each first front-face hit, less `beta`
/// (the control variate of `crate::control`; 0 for none), and 0 otherwise; with `inherit`
/// (the input's variance per patch, and the patches), also the noise it carries into the rays' mean
/// ([`Seen::inherited_mean`]) and the emission seen ([`Seen::emitted`]).
#[inline]
pub(crate) fn look<C: RayCaster>(
    n: u32,
    caster: &C,
    input: &[DVec3],
    inherit: Option<(&[DVec3], &[Patch])>,
    beta: DVec3,
    ray: impl FnMut() -> Ray,
) -> Seen {
    look_with(n, caster, input, inherit, None, beta, ray, |_, _| {
        DVec3::ZERO
    })
}

/// [`look`], each front-face hit recording `input` of the patch hit plus `extra(ray, hit)` (the
/// cosine half of the direct light's multiple importance sampling, which rides on gathering
/// rays: `direct::CosineLight`), less `beta`; with `sketch` (the input's error samples per
/// patch), also their sum over the hits ([`Seen::sketch`]).
#[inline]
#[allow(clippy::too_many_arguments)]
pub(crate) fn look_with<C: RayCaster>(
    n: u32,
    caster: &C,
    input: &[DVec3],
    inherit: Option<(&[DVec3], &[Patch])>,
    sketch: Option<&[Row]>,
    beta: DVec3,
    mut ray: impl FnMut() -> Ray,
    extra: impl Fn(&Ray, &Hit) -> DVec3,
) -> Seen {
    let mut seen = Seen::default();
    // The odd rays' sum of the samples ([`Seen::sketch_variance`]).
    let mut odd = crate::replicates::ZERO_ROW;
    for t in 0..n {
        let r = ray();
        let hit = caster.closest_hit(&r);
        let x = match hit {
            Some(hit) if hit.front => {
                if let Some(z) = sketch {
                    let z = &z[hit.id as usize];
                    crate::replicates::add_row(&mut seen.sketch, z);
                    if replicate(u64::from(t)) == 1 {
                        crate::replicates::add_row(&mut odd, z);
                    }
                }
                input[hit.id as usize] + extra(&r, &hit) - beta
            }
            Some(_) => {
                seen.back_faces += 1;
                DVec3::ZERO
            }
            None => {
                seen.escaped += 1;
                DVec3::ZERO
            }
        };
        seen.moments.push(x);
        seen.halves.push(replicate(u64::from(t)), x);
        if let Some((v, patches)) = inherit {
            seen.inherit_rays += 1;
            if let Some(h) = hit.filter(|h| h.front) {
                let j = h.id as usize;
                seen.inherited += v[j] * disc_form_factor(&r, &h, &patches[j]);
                // Most rays see no emitter: only those that do add to the sums.
                if patches[j].emission != glam::Vec3::ZERO {
                    let e = patches[j].emission.as_dvec3();
                    seen.emitted += e;
                    seen.emitted_squares += e * e;
                }
            }
        }
    }
    if sketch.is_some() {
        seen.sketch_variance = replicate_variance(&seen.sketch, &odd, u64::from(n));
    }
    seen
}

/// The replicates' variance of a sum of samples over `n` rays, per channel and summed over
/// the samples ([`Seen::sketch_variance`]), `odd` the odd rays' part of `all`: `n²` times
/// the square of [`Halves::error_of_mean`] of each sample's split, unbiased for the
/// variance of the sum; 0 below two rays.
fn replicate_variance(all: &Row, odd: &Row, n: u64) -> DVec3 {
    (0..crate::replicates::SKETCHES)
        .map(|g| {
            let b = crate::replicates::sample(odd, g);
            let a = crate::replicates::sample(all, g) - b;
            let e = Halves { sum: [a, b] }.error_of_mean(n) * n as f64;
            e * e
        })
        .sum()
}

/// The form factor from the ray's origin to the patch `hit` hit, as from a point to a disc of
/// the patch's area facing it at the hit's distance (Wallace et al. 1989):
/// `A_j cos_i cos_j / (pi r² + A_j)`, bounded by 1 however near the patch.
fn disc_form_factor(ray: &Ray, hit: &Hit, patch: &Patch) -> f64 {
    let cos_i = f64::from(ray.dir.dot(ray.origin_normal).max(0.0));
    let cos_j = f64::from((-ray.dir.dot(patch.normal)).max(0.0));
    let r2 = f64::from(hit.distance).powi(2);
    patch.area * cos_i * cos_j / (std::f64::consts::PI * r2 + patch.area)
}

/// Jobs [`fold`] runs at once: their results are all it holds besides the caller's (a job's
/// [`Seen`] is about 300 bytes; a block of them, 5 MB).
const BLOCK_JOBS: usize = 1 << 14;

/// Runs the [`jobs`] of `items` items with `per_item` rays each, in parallel, a block of
/// about [`BLOCK_JOBS`] jobs at a time, and hands each item's chunks, merged in chunk order,
/// to `take` in item order, as they come: nothing is held per job beyond a block (the
/// gatherers keep per item only what they read of it). Same answer on any number of
/// threads: the blocks and the merge order do not depend on them.
pub(crate) fn fold<F: Fn(&Job) -> Seen + Sync + Send>(
    items: usize,
    per_item: u32,
    f: F,
    take: impl FnMut(usize, Seen),
) {
    fold_with(items, per_item, f, Seen::merge, take);
}

/// [`fold`] of jobs whose results are `T`s, an item's chunks merged by `merge` in chunk order
/// from `T::default()`.
pub(crate) fn fold_with<T: Default + Send, F: Fn(&Job) -> T + Sync + Send>(
    items: usize,
    per_item: u32,
    f: F,
    merge: impl Fn(T, T) -> T,
    mut take: impl FnMut(usize, T),
) {
    let chunks = per_item.div_ceil(JOB_RAYS).max(1) as usize;
    let block_items = (BLOCK_JOBS / chunks).max(1);
    let mut first = 0;
    while first < items {
        let last = (first + block_items).min(items);
        let block: Vec<Job> = jobs(last - first, per_item)
            .into_iter()
            .map(|j| Job {
                item: j.item + first as u32,
                ..j
            })
            .collect();
        let seen: Vec<T> = block.par_iter().map(&f).collect();
        // Jobs item by item, chunk by chunk: an item's chunks are consecutive.
        let mut jobs = block.iter().zip(seen).peekable();
        for item in first..last {
            let mut acc = T::default();
            while let Some((_, s)) = jobs.next_if(|(j, _)| j.item as usize == item) {
                acc = merge(acc, s);
            }
            take(item, acc);
        }
        first = last;
    }
}

/// What an item's rays saw, reduced to what the gatherers read of it after the fold: a
/// [`Seen`] without its error samples' sums (taken as they come), with the inherited and
/// emission sums turned into [`Seen::inherited_mean`] and [`Seen::emitted_m2`] (168 bytes
/// where a `Seen` takes 296).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Tally {
    /// The rays' values ([`Seen::moments`]).
    pub moments: Moments,
    /// Rays that hit nothing (at most the item's rays, a `u32`).
    pub escaped: u32,
    /// Rays whose first hit was a back face.
    pub back_faces: u32,
    /// Every ray recorded the inherited noise and the emission (`inherit_rays == n`).
    pub tracked: bool,
    /// [`Seen::inherited_mean`], (W/m²)².
    pub inherited_mean: DVec3,
    /// [`Seen::emitted_m2`], (W/m²)².
    pub emitted_m2: DVec3,
    /// [`Seen::halves`].
    pub halves: Halves,
}

impl From<&Seen> for Tally {
    fn from(s: &Seen) -> Tally {
        Tally {
            moments: s.moments,
            // An item's counts are at most its rays, a `u32`.
            escaped: u32::try_from(s.escaped).unwrap_or(u32::MAX),
            back_faces: u32::try_from(s.back_faces).unwrap_or(u32::MAX),
            tracked: s.inherit_rays == s.moments.n,
            inherited_mean: s.inherited_mean(),
            emitted_m2: s.emitted_m2(),
            halves: s.halves,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A job's made-up result: a few values that depend on its item and chunk.
    fn seen_of(job: &Job) -> Seen {
        let mut s = Seen {
            escaped: u64::from(job.chunk),
            inherit_rays: u64::from(job.rays),
            ..Seen::default()
        };
        for t in 0..job.rays.min(5) {
            let x = DVec3::splat(f64::from(job.item) * 0.37 + f64::from(job.chunk) - f64::from(t));
            s.moments.push(x);
            s.halves.push(replicate(u64::from(t)), x);
            s.inherited += x;
            s.sketch[t as usize] += x.x as f32;
        }
        s
    }

    /// `fold` hands every item, in order, the merge of its chunks in chunk order, bit for bit
    /// the serial merge of [`jobs`], whether an item's chunks fill many blocks or a block holds
    /// many items, on 1 and 3 threads.
    #[test]
    fn fold_merges_each_items_chunks_in_order_on_any_thread_count() {
        for (items, per_item) in [
            (BLOCK_JOBS * 2 + 7, 2),
            (5, JOB_RAYS * 3 + 11),
            (3, JOB_RAYS * (BLOCK_JOBS as u32 + 2)),
            (0, 8),
        ] {
            let mut expected = vec![Seen::default(); items];
            for job in jobs(items, per_item) {
                let i = job.item as usize;
                expected[i] = expected[i].merge(seen_of(&job));
            }
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut got = Vec::new();
                pool.install(|| {
                    fold(items, per_item, seen_of, |i, s| {
                        assert_eq!(i, got.len(), "items in order");
                        got.push(s);
                    })
                });
                assert_eq!(got.len(), items);
                for (g, e) in got.iter().zip(&expected) {
                    assert_eq!(g.moments, e.moments);
                    assert_eq!(g.halves, e.halves);
                    assert_eq!(g.inherited, e.inherited);
                    assert_eq!(g.sketch, e.sketch);
                    assert_eq!((g.escaped, g.inherit_rays), (e.escaped, e.inherit_rays));
                }
            }
        }
    }

    /// [`replicate_variance`] is unbiased for the variance of a sum of `n` independent rows,
    /// even and odd `n`: rows of uniform entries in `[0, 1)` (variance 1/12 each, mean 1/2, so
    /// a difference of unequal halves unscaled would not have mean zero), 20,000 sums; the
    /// mean estimate within 5 standard errors of `8 n / 12` per channel.
    #[test]
    fn the_replicates_measure_the_variance_of_a_sum_of_rows() {
        use crate::replicates::{SKETCHES, ZERO_ROW, add_sample};
        let mut stream = mcrad_random::Stream::new(11, 0, 0, 0);
        for n in [2u64, 5, 16] {
            let trials = 20_000;
            let estimates: Vec<f64> = (0..trials)
                .map(|_| {
                    let (mut all, mut odd) = (ZERO_ROW, ZERO_ROW);
                    for t in 0..n {
                        let mut row = ZERO_ROW;
                        for g in 0..SKETCHES {
                            let x = DVec3::new(
                                stream.uniform_f64(),
                                stream.uniform_f64(),
                                stream.uniform_f64(),
                            );
                            add_sample(&mut row, g, x);
                        }
                        crate::replicates::add_row(&mut all, &row);
                        if replicate(t) == 1 {
                            crate::replicates::add_row(&mut odd, &row);
                        }
                    }
                    replicate_variance(&all, &odd, n).x
                })
                .collect();
            let m = trials as f64;
            let mean = estimates.iter().sum::<f64>() / m;
            let sd = (estimates.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (m - 1.0)).sqrt();
            let want = SKETCHES as f64 * n as f64 / 12.0;
            assert!(
                (mean - want).abs() < 5.0 * sd / m.sqrt(),
                "n = {n}: {mean:.4} against {want:.4} (± {:.4})",
                sd / m.sqrt()
            );
        }
    }
}
