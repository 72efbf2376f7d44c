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

/// `sum_g |a_g - b_g|² 4 n_0 n_1 / n²` ([`Seen::sketch_variance`]) of a sum of samples over
/// `n` rays, `odd` the odd rays' part of `all`: unbiased for the variance of the sum per
/// channel, summed over the samples; 0 below two rays.
fn replicate_variance(all: &Row, odd: &Row, n: u64) -> DVec3 {
    let (n0, n1) = (n.div_ceil(2) as f64, (n / 2) as f64);
    if n1 == 0.0 {
        return DVec3::ZERO;
    }
    let n = n as f64;
    let mut v = DVec3::ZERO;
    for g in 0..crate::replicates::SKETCHES {
        let b = crate::replicates::sample(odd, g);
        let a = crate::replicates::sample(all, g) - b;
        let d = a * (n / (2.0 * n0)) - b * (n / (2.0 * n1));
        v += d * d;
    }
    v * (4.0 * n0 * n1 / (n * n))
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

/// Runs `jobs` in parallel and merges each item's chunks in chunk order.
pub(crate) fn run<F: Fn(&Job) -> Seen + Sync + Send>(
    items: usize,
    jobs: &[Job],
    f: F,
) -> Vec<Seen> {
    let mut seen: Vec<Seen> = jobs.par_iter().map(f).collect();
    // Jobs item by item, every item from 0 on with a job ([`jobs`]): an item's slot is at or
    // before its first job's, so its chunks fold into it in place, without a second vector.
    let dense = jobs.first().is_none_or(|j| j.item == 0)
        && jobs
            .windows(2)
            .all(|w| w[1].item >= w[0].item && w[1].item - w[0].item <= 1)
        && jobs.last().is_none_or(|j| j.item as usize + 1 == items);
    if dense {
        for (k, job) in jobs.iter().enumerate() {
            let item = job.item as usize;
            let first = k == 0 || jobs[k - 1].item != job.item;
            let acc = if first { Seen::default() } else { seen[item] };
            seen[item] = acc.merge(seen[k]);
        }
        seen.truncate(items);
        seen.resize(items, Seen::default());
        return seen;
    }
    let mut out = vec![Seen::default(); items];
    for (job, s) in jobs.iter().zip(seen) {
        out[job.item as usize] = out[job.item as usize].merge(s);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replicates::{SKETCHES, ZERO_ROW, add_sample};

    /// [`replicate_variance`] is unbiased for the variance of a sum of `n` independent rows,
    /// even and odd `n`: rows of uniform entries in `[0, 1)` (variance 1/12 each, mean 1/2, so
    /// a difference of unequal halves unscaled would not have mean zero), 20,000 sums; the
    /// mean estimate within 5 standard errors of `8 n / 12` per channel.
    #[test]
    fn the_replicates_measure_the_variance_of_a_sum_of_rows() {
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
