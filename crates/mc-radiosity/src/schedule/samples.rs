//! The variance of an estimate built from gathers of a shooting estimate, from error samples
//! (issue 36, item 2): shared by the methods that gather from shooting (`two-pass`,
//! `two-pass-split`, `progressive-gather`, `progressive-two-pass`, `combined`).
//!
//! A gather `G_i = [E_i] + rho_i (1/n) sum_k S(j_k)` (plus, split, the direct light) has two
//! errors: its **own** (its rays and emitter samples given `S`, independent of everything
//! else) and the one it **inherits** from `S`, `rho_i sum_j F̂_ij e^S_j`. Summing the latter as
//! if the `e^S_j` were independent (`rho_i² sum_j F_ij² V_j`) ignores that shooting conserves
//! power: its errors are negatively correlated between patches, and in a closed furnace of one
//! patch per face a gather inherits about `-0.2 rho e^S_i`, a fifth of the independent sum.
//! And under quasi-Monte Carlo rays the own part's independent-ray formula, drawn towards by
//! each round's gain with one replicate difference a patch, overstates stratified rays several
//! times on a face of one patch. Both made `two-pass` and the progressive gathers report
//! 7-10 times their spread between seeds on faces of one patch (`cargo xtask calibrate`).
//!
//! So, as `combined` does:
//!
//! - shooting keeps [`SKETCHES`] error samples `z_g` per patch ([`ShotSamples`],
//!   `Waves::sketch`: `sum_g z_gi z_gj` estimates the covariance of `e^S_i` and `e^S_j`), and
//!   the gathers gather them with their own rays into their images `y_g` ([`GatherSamples`]):
//!   `sum_g y_gi²` estimates the inherited variance with its correlation;
//! - the gathers' own noise is measured by their replicates: per round and patch one signed
//!   difference of the indirect gathering and one of the direct light
//!   ([`Halves::error_of_mean`](crate::replicates::Halves)), squared and merged by rays as the
//!   rounds are, the formula's shape over an input face taking the face's measured scale. It
//!   comes from the values the rays saw, the shooting's error included: `(T̂ - T) e`, which the
//!   image `T̂ z` of the same rays holds too, so each round's measure is taken less the
//!   replicates' variance of its image (`Seen::sketch_variance`). Counted twice, the own noise
//!   was most of a subdivided furnace's reported variance; a scale on the image (the faces'
//!   stratification over the waves, one factor for the scene) made up for it on the patches
//!   whose gathers spread over the scene and left those whose gathers see a few patches up
//!   close (a furnace's edges and corners) at half their spread. Both are gone: on the rho
//!   0.999 furnace `two-pass`'s spread over reported went from 1.9 on the edges and 0.95
//!   inside to 0.73 and 0.84 (`docs/calibration.md`).
//!
//! The estimate `C_i = w_i S_i + (1 - w_i) G_i` (`combined`'s merge; `w = 0` for a gather
//! alone) then has the variance ([`variance`])
//!
//! ```text
//! V_i = (1 - w_i)² own_i + sum_g (w_i z_gi + (1 - w_i) y_gi)² + missed_i
//! ```
//!
//! per channel, with `missed_i` the part of `S`'s variance the samples do not hold (lone rays
//! of a roulette tail and of the late waves): the smaller of that part carried as the held part
//! is over the scene, and the two parts summed as independent, `w_i² m_i + (1 - w_i)² phi H_i`
//! (`m_i` the missed part of `S`'s variance, `phi` its share of the gathers' inherited variance
//! `H_i`). The first is the smooth, conserving error's transfer and overstates a lone ray's
//! error, one deposit that a gather averages away: at rho 0.999 on 864 patches, where nearly
//! every late ray is alone in its wave, `combined`'s median patch reported twice its spread.
//! The second ignores the cancellation of a furnace of one patch per face, where the first
//! holds.
//!
//! **Degrees of freedom.** A face of one patch measures its own noise with one degree of
//! freedom a round and part. An estimate `v̂` of `chi²_k / k` noise makes `z² = e² / v̂` about
//! `k / (k - 2)` times too large on average (infinite for `k <= 2`), so where the gathers
//! measured few differences a face's measured scale is drawn towards the scene's (the sums
//! over every face) with the weight of `prior` faces of the rounds' degrees of freedom: the
//! single gather of `two-pass` has one. Likewise a patch's samples' part, `sum_g y_gi²`, has
//! [`SKETCHES`] degrees of freedom at most: for the gathering methods it is drawn towards its
//! inherited variance by the independent formula times the scene's ratio of the two, with the
//! weight of [`PRIOR_FACES`] patches over its face's (`Parts::sample_prior`; mean `z²` on the
//! rho 0.9 furnace of one patch per face 1.47-1.65 -> 1.13-1.35). `combined` keeps its own:
//! its samples' part mixes the shooting's samples with the gathers' images.

use crate::replicates::{Row, SKETCHES, sample};
use glam::DVec3;
use mcrad_meshing::Mesh;

/// The error samples of a shooting estimate: [`Row`]s `z_g` (W/m²) and the part of its
/// variance they do not hold ((W/m²)², `Shooting::unsampled`), both merged over shooting
/// passes as the estimate is (by rays).
#[derive(Debug, Clone, Default)]
pub(crate) struct ShotSamples {
    /// Per patch, the [`SKETCHES`] error samples per channel (W/m²).
    pub sketch: Vec<Row>,
    /// Per patch and channel, the variance the samples miss ((W/m²)²).
    pub unsampled: Vec<DVec3>,
}

impl ShotSamples {
    /// The samples of one shooting pass (taken out of it).
    pub(crate) fn take(s: &mut crate::shoot::Shooting) -> ShotSamples {
        ShotSamples {
            sketch: std::mem::take(&mut s.sketch).into_dense(),
            unsampled: std::mem::take(&mut s.unsampled),
        }
    }

    /// These samples merged with `next`'s, an independent pass merged with weight `w` on it.
    pub(crate) fn merge(self, next: ShotSamples, w: f64) -> ShotSamples {
        if self.sketch.is_empty() {
            return next;
        }
        ShotSamples {
            sketch: blend(self.sketch, &next.sketch, w),
            unsampled: by_rays(&self.unsampled, &next.unsampled, w),
        }
    }
}

/// What the gathers of a run measured, merged by rays as the gathers are: the images of the
/// shooting's error samples through their rays, and the squares of their own replicate
/// differences.
#[derive(Debug, Clone, Default)]
pub(crate) struct GatherSamples {
    /// Per patch, the image `y_g` of the shooting's samples (W/m², [`Row`]).
    pub image: Vec<Row>,
    /// Per patch and channel, the gathers' own noise measured ((W/m²)²), less what their
    /// images hold of it where the caller says so ([`GatherSamples::add`]); a patch's may be
    /// negative (the difference of two estimates), its face's sum is what counts.
    pub measured: Vec<DVec3>,
    /// Rays of the gathers so far, and the sum of their squares (the degrees of freedom).
    rays: u64,
    squares: f64,
}

impl GatherSamples {
    /// Adds a gather of `rays` rays merged by rays into the gathers before it: `image` its
    /// image of the shooting's samples, `errors` the signed replicate differences of its
    /// independent parts (the indirect gathering's, the direct light's) per patch, `held`
    /// (empty, or per patch) the part of their squares' expectation that `image` holds
    /// already, taken out of the measured noise.
    pub(crate) fn add(&mut self, image: Vec<Row>, errors: &[&[DVec3]], held: &[DVec3], rays: u64) {
        let n = image.len().max(errors.first().map_or(0, |e| e.len()));
        let mut squares = vec![DVec3::ZERO; n];
        for e in errors {
            for (s, d) in squares.iter_mut().zip(e.iter()) {
                *s += *d * *d;
            }
        }
        for (s, h) in squares.iter_mut().zip(held) {
            *s -= *h;
        }
        self.rays += rays;
        self.squares += (rays as f64).powi(2);
        let w = rays as f64 / self.rays.max(1) as f64;
        self.measured = if self.measured.is_empty() {
            squares
        } else {
            by_rays(&self.measured, &squares, w)
        };
        self.image = if self.image.is_empty() {
            image
        } else {
            blend(std::mem::take(&mut self.image), &image, w)
        };
    }

    /// The degrees of freedom of a patch's measured noise per replicate difference: the
    /// rounds' effective number, `(sum_k n_k)² / sum_k n_k²` (a round's own variance falls
    /// as its rays grow while its weight grows with them: `n_k` is its share of the sum).
    pub(crate) fn rounds(&self) -> f64 {
        if self.squares > 0.0 {
            (self.rays as f64).powi(2) / self.squares
        } else {
            0.0
        }
    }
}

/// The shooting estimate's variance and samples, and the gathering estimate's, that
/// [`variance`] reads.
pub(crate) struct Parts<'a> {
    /// The shooting estimate's samples.
    pub shot: &'a ShotSamples,
    /// The shooting estimate's variance per patch and channel ((W/m²)²).
    pub shot_variance: &'a [DVec3],
    /// The gathering estimate's whole variance by the formulas (own plus inherited as
    /// independent, [`Gathers::estimate`](super::Gathers)).
    pub gathered: &'a [DVec3],
    /// Its own part by the independent-ray formula ([`Gathers::own`](super::Gathers)).
    pub own: &'a [DVec3],
    /// The gathers' samples.
    pub gathers: &'a GatherSamples,
    /// Whether the gathers' own noise is taken from their replicates (quasi-Monte Carlo
    /// rays); otherwise the formula stands.
    pub measured: bool,
    /// The weight, in faces of the rounds' degrees of freedom, of the scene's measured scale
    /// in a face's ([module](self)); 0: each face its own.
    pub prior: f64,
    /// The weight, in patches, of the scene's transfer of the inherited variance in a face's
    /// samples' part ([module](self), "Degrees of freedom"); 0: each patch its own samples.
    pub sample_prior: f64,
}

/// The variance of `w S + (1 - w) G` per patch and channel ((W/m²)², [module](self)), `w`
/// given per patch and channel by `weights` (all 0: the gathering estimate alone), and per
/// face the factor of the correlation between its patches
/// ([`factors_of`](crate::correlation::factors_of)). `None` when the samples do not fit the
/// mesh (a shooting that kept none).
pub(crate) fn variance(
    mesh: &Mesh,
    parts: &Parts<'_>,
    weights: &[DVec3],
) -> Option<(Vec<DVec3>, Vec<DVec3>)> {
    if weights.len() != parts.own.len() {
        return None;
    }
    variance_with(mesh, parts, |i| weights[i])
}

/// The patches grouped by input face in a counting sort (stable: a face's patches in mesh
/// order), so that a face's sums are made in registers, one face at a time, instead of in
/// arrays over the faces: `order[first[f]..first[f + 1]]` are the patches of face `f`
/// (4 bytes a patch and a face).
struct ByFace {
    first: Vec<u32>,
    order: Vec<u32>,
}

impl ByFace {
    fn new(mesh: &Mesh) -> ByFace {
        let faces = mesh.face_count();
        let n = mesh.patches().len();
        let mut first = vec![0u32; faces + 1];
        for p in mesh.patches() {
            first[p.face as usize + 1] += 1;
        }
        for f in 0..faces {
            first[f + 1] += first[f];
        }
        // `first[f]` runs as face `f`'s cursor, ending where face `f + 1` starts; shifted
        // back by one face after.
        let mut order = vec![0u32; n];
        for (i, p) in mesh.patches().iter().enumerate() {
            let cursor = &mut first[p.face as usize];
            order[*cursor as usize] = i as u32;
            *cursor += 1;
        }
        for f in (1..=faces).rev() {
            first[f] = first[f - 1];
        }
        first[0] = 0;
        ByFace { first, order }
    }

    /// The number of faces.
    fn faces(&self) -> usize {
        self.first.len() - 1
    }

    /// The patches of face `f`, in mesh order.
    fn patches(&self, f: usize) -> impl Iterator<Item = usize> + '_ {
        self.order[self.first[f] as usize..self.first[f + 1] as usize]
            .iter()
            .map(|&i| i as usize)
    }

    /// The number of patches of face `f`.
    fn count(&self, f: usize) -> u32 {
        self.first[f + 1] - self.first[f]
    }
}

/// A face's sums over its patches ((W/m²)² per channel): `S`'s variance, the part its samples
/// hold, the part they miss, the gathers' own noise by the formula and as measured.
#[derive(Clone, Copy, Default)]
struct FaceSums {
    shot: DVec3,
    held: DVec3,
    unsampled: DVec3,
    own: DVec3,
    measured: DVec3,
}

/// [`variance`] with the weight of patch `i` (per channel) given by `weight(i)`. Holds no
/// per-patch array but the result and the patches' order by face (4 bytes a patch): a patch's
/// samples' sums are made again where needed, a face's sums one face at a time, each sum in
/// the order the arrays were summed in before, so the result is the same bit for bit.
pub(crate) fn variance_with(
    mesh: &Mesh,
    parts: &Parts<'_>,
    weight: impl Fn(usize) -> DVec3,
) -> Option<(Vec<DVec3>, Vec<DVec3>)> {
    let Parts {
        shot,
        shot_variance: shot_v,
        gathered: whole,
        own,
        gathers,
        measured,
        prior,
        sample_prior,
    } = *parts;
    let n = own.len();
    let image = &gathers.image;
    if shot.sketch.len() != n
        || image.len() != n
        || shot.unsampled.len() != n
        || (measured && gathers.measured.len() != n)
    {
        return None;
    }
    let measured = measured.then_some(&gathers.measured[..]);
    let total = |v: &[DVec3]| v.iter().map(|x| x.element_sum()).sum::<f64>();
    let share = |part: &[DVec3]| {
        if total(shot_v) > 0.0 {
            (total(part) / total(shot_v)).clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    let phi = share(&shot.unsampled);
    // Patch `i`'s samples' part, `sum_g (w z_g + (1 - w) y_g)²`, and what `S`'s samples
    // hold, `sum_g z_g²`, per channel.
    let samples_of = |i: usize| {
        let (mut sampled, mut held) = (DVec3::ZERO, DVec3::ZERO);
        let weight = weight(i);
        for c in 0..3 {
            let w = weight[c];
            for g in 0..SKETCHES {
                let (z, y) = (
                    f64::from(shot.sketch[i][3 * g + c]),
                    f64::from(image[i][3 * g + c]),
                );
                sampled[c] += (w * z + (1.0 - w) * y).powi(2);
                held[c] += z * z;
            }
        }
        (sampled, held)
    };
    // Per input face (its patches see nearly the same scene; one patch's samples alone would
    // make a noisy share): the share of `S`'s variance the samples hold, and the gathers' own
    // noise measured against the formula's.
    let by_face = ByFace::new(mesh);
    let face_sums = |f: usize| {
        let mut s = FaceSums::default();
        for i in by_face.patches(f) {
            s.shot += shot_v[i];
            s.held += samples_of(i).1;
            s.unsampled += shot.unsampled[i];
            s.own += own[i];
            if let Some(m) = measured {
                s.measured += m[i];
            }
        }
        s
    };
    let face_of = |i: usize| mesh.patches()[i].face as usize;
    // The samples' part drawn towards the scene's transfer (`shrink`), or as it is.
    let inherited = |i: usize| (whole[i] - own[i]).max(DVec3::ZERO);
    let pull_to = (sample_prior > 0.0).then(|| {
        let (s, h): (DVec3, DVec3) = (
            (0..n).map(|i| samples_of(i).0).sum(),
            (0..n).map(inherited).sum(),
        );
        DVec3::new(ratio(s.x, h.x), ratio(s.y, h.y), ratio(s.z, h.z))
    });
    let sampled_of = |i: usize| {
        let (sampled, held) = samples_of(i);
        let sampled = match pull_to {
            Some(r) => shrink(
                sampled,
                r,
                inherited(i),
                sample_prior,
                by_face.count(face_of(i)),
            ),
            None => sampled,
        };
        (sampled, held)
    };
    // The own noise's scale per face: measured over formula, drawn towards the scene's with
    // the weight of `prior` faces of one patch's degrees of freedom.
    let scene_scale = {
        let (mut m, mut o) = (DVec3::ZERO, DVec3::ZERO);
        for f in 0..by_face.faces() {
            let (mut fm, mut fo) = (DVec3::ZERO, DVec3::ZERO);
            for i in by_face.patches(f) {
                fo += own[i];
                if let Some(measured) = measured {
                    fm += measured[i];
                }
            }
            m += fm;
            o += fo;
        }
        DVec3::new(ratio(m.x, o.x), ratio(m.y, o.y), ratio(m.z, o.z)).max(DVec3::ZERO)
    };
    let rounds = gathers.rounds().max(1.0);
    // A face's numerator and denominator of that scale.
    let face_scale = |f: usize, s: &FaceSums| {
        let pull = prior / (rounds * f64::from(by_face.count(f).max(1)));
        let (m, o) = (s.measured, s.own);
        if pull > 0.0 {
            (m + pull * scene_scale * o, (1.0 + pull) * o)
        } else {
            (m, o)
        }
    };
    // How the samples' part of `S`'s variance reaches the estimate, over the scene (a face
    // of one patch holds 8 samples: its own ratio, in the denominator, made rare patches
    // report thousands of times their spread).
    let (ts, th) = {
        let (mut ts, mut th) = (DVec3::ZERO, DVec3::ZERO);
        for i in 0..n {
            let (s, h) = sampled_of(i);
            ts += s;
            th += h;
        }
        (ts, th)
    };
    let transfer = DVec3::new(ratio(ts.x, th.x), ratio(ts.y, th.y), ratio(ts.z, th.z));
    let mut variance = vec![DVec3::ZERO; n];
    for f in 0..by_face.faces() {
        let sums = face_sums(f);
        let scale = face_scale(f, &sums);
        for i in by_face.patches(f) {
            let weight = weight(i);
            let sampled = sampled_of(i).0;
            let mut v = DVec3::ZERO;
            for c in 0..3 {
                let w = weight[c];
                let own_i = match measured {
                    Some(_) if sums.own[c] > 0.0 => own[i][c] * scale.0[c] / scale.1[c],
                    Some(m) => m[i][c],
                    None => own[i][c],
                };
                // (Measured less what the images hold, a face's estimate can fall below 0.)
                v[c] = (1.0 - w).powi(2) * own_i.max(0.0)
                    + if sums.held[c] > 0.0 {
                        let missed = (sums.shot[c] - sums.held[c])
                            .max(0.0)
                            .min(sums.unsampled[c]);
                        let share = ratio(missed, sums.unsampled[c]);
                        let missed = share * shot.unsampled[i][c];
                        let inherited = (whole[i][c] - own[i][c]).max(0.0);
                        let independent = w * w * missed + (1.0 - w).powi(2) * phi * inherited;
                        sampled[c] + (transfer[c] * missed).min(independent)
                    } else {
                        let inherited = (whole[i][c] - own[i][c]).max(0.0);
                        let unsampled = shot.unsampled[i][c];
                        (1.0 - w).powi(2) * phi * inherited + w * w * unsampled + sampled[c]
                    };
            }
            variance[i] = v;
        }
    }
    // The correlation between a face's patches: their samples `w z + (1 - w) y`, and the rest
    // of their variance as independent (the gathers' own noise, the samples' missed part).
    let factors = crate::correlation::factors_of(
        mesh,
        |i, g| {
            let (z, y) = (sample(&shot.sketch[i], g), sample(&image[i], g));
            let w = weight(i);
            w * z + (DVec3::ONE - w) * y
        },
        |i| (variance[i] - sampled_of(i).0).max(DVec3::ZERO),
        1.0,
    );
    Some((variance, factors))
}

/// Draws a patch's samples' part of a gather's variance (`sampled`: `[SKETCHES]` degrees
/// of freedom at most) towards its inherited variance by the independent formula
/// (`inherited`, `whole - own`) times the scene's ratio of the two (`r = sum s / sum h` per
/// channel), with the weight of `prior` patches spread over the `n_f` patches of its face
/// (`face_patches`): `(s_i + (prior / n_f) r h_i) / (1 + prior / n_f)`. The formula's shape
/// is wrong by the correlation of the shooting's errors, which the scene's ratio puts right
/// where the patches are alike (a closed furnace of one patch per face: about a fifth); its
/// noise is that of the scene's samples, not one patch's (module, "Degrees of freedom": `z²`
/// about `k / (k - 2)` too large from a variance of `k` degrees of freedom).
fn shrink(sampled: DVec3, r: DVec3, inherited: DVec3, prior: f64, face_patches: u32) -> DVec3 {
    let pull = prior / f64::from(face_patches.max(1));
    (sampled + pull * r * inherited) / (1.0 + pull)
}

/// `a / b`, 0 where `b` is not positive.
fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 { a / b } else { 0.0 }
}

/// `(1 - w)² a + w² b` per patch and channel: variances of two independent estimates merged
/// with weight `w` on the second.
pub(crate) fn by_rays(a: &[DVec3], b: &[DVec3], w: f64) -> Vec<DVec3> {
    a.iter()
        .zip(b)
        .map(|(a, b)| *a * (1.0 - w).powi(2) + *b * (w * w))
        .collect()
}

/// `(1 - w) a + w b`, sample by sample: error samples of two independent estimates merged
/// with weight `w` on the second.
pub(crate) fn blend<'a>(mut a: Vec<Row>, b: impl IntoIterator<Item = &'a Row>, w: f64) -> Vec<Row> {
    let w = w as f32;
    for (a, b) in a.iter_mut().zip(b) {
        for (a, b) in a.iter_mut().zip(b) {
            *a = *a * (1.0 - w) + *b * w;
        }
    }
    a
}

/// The weight of the scene's measured scale in a face's own noise for the methods whose
/// gathers measure it with few degrees of freedom ([module](self)): as many faces of the
/// rounds' degrees of freedom as [`PRIOR_PATCHES`](crate::replicates::PRIOR_PATCHES) (a face
/// of one patch and one round takes a fifth of its own measure).
pub(crate) const PRIOR_FACES: f64 = crate::replicates::PRIOR_PATCHES;

/// The gathers of a run from one shooting (or from nested merges of its passes), merged by
/// rays ([`Gathers`](super::Gathers)), with their images of the shooting's error samples and
/// their own noise measured ([`GatherSamples`]): what [`gathered`] reads.
#[derive(Default)]
pub(crate) struct GatherRun {
    gathers: super::Gathers,
    samples: GatherSamples,
}

impl GatherRun {
    /// Adds a gather: its estimate (with its whole variance by the formulas), the part of
    /// that variance it inherits from the shooting, its image of the shooting's samples, the
    /// signed replicate differences of its independent parts, and the replicates' variance
    /// of its image over its rays (the part of its own noise the image holds:
    /// [`GatherSamples::add`]).
    pub(crate) fn add(
        &mut self,
        estimate: mcrad_combine::Estimate,
        inherited: &[DVec3],
        image: Vec<Row>,
        errors: &[&[DVec3]],
        held: &[DVec3],
    ) -> Result<(), crate::error::Error> {
        self.samples.add(image, errors, held, estimate.rays());
        self.gathers.add(estimate, inherited)
    }

    /// Gathers one round (emission included) from `shooting` with `rays_per_patch` rays a
    /// patch, its rays keyed by `key`, carrying `shot`'s samples; returns the rays it cast
    /// and how many escaped.
    pub(crate) fn round<C: mcrad_raycast::RayCaster>(
        &mut self,
        ctx: &crate::context::Context<C>,
        shooting: &mcrad_combine::Estimate,
        shot: Option<&ShotSamples>,
        rays_per_patch: u32,
        key: mcrad_random::StreamKey,
    ) -> Result<(u64, u64), crate::error::Error> {
        let (r, inherited) = crate::gather::gather_round_parts(
            ctx,
            shooting,
            shot.map(|s| &s.sketch[..]),
            crate::gather::Emission::Include,
            rays_per_patch,
            key,
        )?;
        let (rays, escaped) = (r.estimate.rays(), r.escaped_rays);
        self.add(
            r.estimate,
            &inherited,
            r.sketch,
            &[&r.errors],
            &r.sketch_variance,
        )?;
        Ok((rays, escaped))
    }

    /// The gathers' estimate with the variance [`gathered`] gives it, from `shot`'s samples
    /// and the variance of the shooting they gathered from (`shot_variance`); `measured`:
    /// the own noise from the replicates (quasi-Monte Carlo rays).
    pub(crate) fn estimate(
        &self,
        mesh: &Mesh,
        shot: Option<&ShotSamples>,
        shot_variance: Option<&[DVec3]>,
        measured: bool,
    ) -> Result<(mcrad_combine::Estimate, Option<Vec<DVec3>>), crate::error::Error> {
        gathered(
            mesh,
            shot,
            shot_variance,
            &self.gathers,
            &self.samples,
            measured,
        )
    }
}

/// The gathering estimate of `gathers` (merged by rays) with the variance [`variance`] gives it
/// alone (`w = 0`), from the samples of the shooting estimate it gathers from (`shot`, and that
/// estimate's variance `shot_variance`) and of the gathers; and the per-face correlation
/// factors. Where the samples do not fit (a shooting that kept none, the ambient term), the
/// gathers' estimate by the formulas and no factors.
fn gathered(
    mesh: &Mesh,
    shot: Option<&ShotSamples>,
    shot_variance: Option<&[DVec3]>,
    gathers: &super::Gathers,
    gather_samples: &GatherSamples,
    measured: bool,
) -> Result<(mcrad_combine::Estimate, Option<Vec<DVec3>>), crate::error::Error> {
    let whole = gathers.estimate()?;
    let (Some(shot), Some(shot_variance), Some(own)) = (
        shot,
        shot_variance,
        gathers.own().and_then(|o| o.variance()),
    ) else {
        return Ok((whole, None));
    };
    let Some(gathered) = whole.variance() else {
        return Ok((whole, None));
    };
    let parts = Parts {
        shot,
        shot_variance,
        gathered,
        own,
        gathers: gather_samples,
        measured,
        prior: PRIOR_FACES,
        sample_prior: PRIOR_FACES,
    };
    let weights = vec![DVec3::ZERO; own.len()];
    let Some((variance, factors)) = variance(mesh, &parts, &weights) else {
        return Ok((whole, None));
    };
    let estimate =
        mcrad_combine::Estimate::new(whole.radiosity().to_vec(), Some(variance), whole.rays())?;
    Ok((estimate, Some(factors)))
}
