//! Per-face error bars that carry the correlation between a face's patches (issue 36, item 3).
//!
//! An input face split into patches is reported (`--per-face`, a bake's per-face figures) by
//! the area-weighted mean of its patches, `B_f = sum_i a_i B_i` with `a_i = A_i / A_f`, whose
//! variance is
//!
//! ```text
//! Var B_f = sum_i a_i² V_i + sum_{i != j} a_i a_j Cov(B_i, B_j).
//! ```
//!
//! The first sum alone takes the patches as independent. They are not: `combined`'s gathers
//! all read one shooting solution, so the patches of a face inherit nearly the same error from
//! it (positively correlated), and shooting conserves power, so its errors on neighbours are
//! often negatively correlated. The schedules that carry error samples `z_gi` (W/m² per
//! channel, [`Row`]: `E[sum_g z_gi z_gj]` is the covariance of the errors of patches `i` and
//! `j`) and a remainder `u_i` ((W/m²)², independent between patches: the gathers' own rays,
//! the lone rays of a roulette tail) estimate the face's variance from them; what they give
//! the caller is the factor between that and the independent sum,
//!
//! ```text
//! k_f = (sum_g (sum_i A_i z_gi)² + sum_i A_i² u_i) / (sum_i A_i² (sum_g z_gi² + u_i))
//! ```
//!
//! per channel, 1 for a face of one patch, so `k_f sum_i a_i² V_i` is the face's variance
//! whatever scale the patches' reported `V_i` were calibrated to (the samples give the
//! correlation's shape, the patches' variances its scale), and the factor survives the
//! pipeline's pooling of a face's patches with estimates of the same face (face-wide
//! weights).
//!
//! With [`SKETCHES`] samples, the numerator's correlated part has 8 degrees of freedom: a
//! face's factor is noisy (a relative error near `sqrt(2 / 8) = 50%` where the correlation
//! dominates). So it is drawn towards the factor of the faces of the same patch count band
//! over the scene ([`PRIOR_FACES`]), whose faces share the geometry of the correlation (a
//! face's patches reading the same gathers), as the gains of `crate::replicates` are.
//!
//! Shooting's samples are its waves' replicate differences, scaled by the share of the
//! per-wave variance the whole run keeps over the scene (`Waves::kappa_by_sources`): a patch's rays
//! continue one sequence over the waves, stratified across them too, and over a whole face
//! much more so than over one patch. So the samples' variance of a face's total takes
//! `Waves::face_scale` as well, the same share measured on the faces' totals.
//!
//! Measured (mean over faces of the spread between 16 seeds over the reported variance, the
//! small-light room of `tests/variance.rs`, 393 patches on 10 faces): `combined` 1.87 with the
//! patches as independent, 1.07 with the factors; `prr` 0.23 (a wall's mean has a tenth of
//! the variance of its patches summed), 0.47 with the samples' factors, 0.72 with the face
//! scale. `cargo xtask bake-check` (a textured room, 8 seeds, per-face texel means), pooled
//! spread / reported and mean `z²`: `combined` 2.11 and 2.41 before, 0.87 and 1.07 with the
//! factors; `prr` 0.43 and 0.36 before, 0.70 and 0.78.

use crate::replicates::{Row, SKETCHES};
use glam::DVec3;
use mcrad_meshing::Mesh;

/// The weight, in faces, of the scene's factor (over faces of a similar patch count) in each
/// face's own ([module](self)).
const PRIOR_FACES: f64 = 4.0;

/// The number of patch-count bands: faces of `2^b .. 2^(b+1)` patches share a prior.
const BANDS: usize = 24;

/// Each patch's face as outputs number it: its input face, plus
/// [`Mesh::back_face_offset`] for the back side of a two-sided face (`back` that offset).
#[inline]
pub(crate) fn face_key(mesh: &Mesh, i: usize, back: u32) -> usize {
    let p = &mesh.patches()[i];
    (p.face + if p.back { back } else { 0 }) as usize
}

/// The factors `k_f` ([module](self)) per face as outputs number it
/// ([`face_key`]), per channel, from error samples `rows` (W/m², one per patch) and the
/// independent remainder `independent` ((W/m²)² per patch). Faces of one patch get exactly 1;
/// a face whose patches hold no error at all, 1.
/// `face_scale` multiplies the samples' variance of a face's total (the numerator's first
/// term; shooting's `Waves::face_scale`), 1 where the samples hold it as it is.
pub(crate) fn face_factors(
    mesh: &Mesh,
    rows: &[Row],
    independent: &[DVec3],
    face_scale: f64,
) -> Vec<DVec3> {
    factors_of(
        mesh,
        |i, g| crate::replicates::sample(&rows[i], g),
        |i| independent[i],
        face_scale,
    )
}

/// [`face_factors`] with patch `i`'s sample `g` given by `sample(i, g)` and its independent
/// remainder by `independent(i)`.
pub(crate) fn factors_of(
    mesh: &Mesh,
    sample: impl Fn(usize, usize) -> DVec3,
    independent: impl Fn(usize) -> DVec3,
    face_scale: f64,
) -> Vec<DVec3> {
    let back = mesh.back_face_offset();
    let n = mesh.patches().len();
    let faces = (0..n)
        .map(|i| face_key(mesh, i, back) + 1)
        .max()
        .unwrap_or(0);
    let mut count = vec![0u32; faces];
    for i in 0..n {
        count[face_key(mesh, i, back)] += 1;
    }
    // Faces of several patches get a slot for their sums (faces of one patch need none).
    let mut slot = vec![u32::MAX; faces];
    let mut slots = 0usize;
    for (s, &c) in slot.iter_mut().zip(&count) {
        if c > 1 {
            *s = slots as u32;
            slots += 1;
        }
    }
    // The patches grouped by face (a counting sort), so that one face's sums are made at a
    // time: the samples' sums of a face are 8 vectors, and a scene may have millions of faces.
    let mut first = vec![0u32; faces + 1];
    for (f, &c) in count.iter().enumerate() {
        first[f + 1] = first[f] + c;
    }
    let mut order = vec![0u32; n];
    let mut next = first.clone();
    for i in 0..n {
        let f = face_key(mesh, i, back);
        order[next[f] as usize] = i as u32;
        next[f] += 1;
    }
    drop(next);
    // Per slot: the correlated numerator and the independent sum (the denominator).
    let mut correlated = vec![DVec3::ZERO; slots];
    let mut alone = vec![DVec3::ZERO; slots];
    for (f, &s) in slot.iter().enumerate() {
        if s == u32::MAX {
            continue;
        }
        let (mut sums, mut own, mut independent_sum) =
            ([DVec3::ZERO; SKETCHES], DVec3::ZERO, DVec3::ZERO);
        for &i in &order[first[f] as usize..first[f + 1] as usize] {
            let i = i as usize;
            let a = mesh.patches()[i].area;
            let mut held = DVec3::ZERO;
            for (g, sum) in sums.iter_mut().enumerate() {
                let z = sample(i, g);
                *sum += a * z;
                held += z * z;
            }
            let u = independent(i);
            own += a * a * u;
            independent_sum += a * a * (held + u);
        }
        correlated[s as usize] = face_scale * sums.iter().map(|x| *x * *x).sum::<DVec3>() + own;
        alone[s as usize] = independent_sum;
    }
    // The scene's factor per band of patch counts: the prior each face is drawn towards.
    let band = |c: u32| (c.max(1).ilog2() as usize).min(BANDS - 1);
    let mut prior = [(DVec3::ZERO, DVec3::ZERO); BANDS];
    for (f, &s) in slot.iter().enumerate() {
        if s != u32::MAX {
            let p = &mut prior[band(count[f])];
            p.0 += correlated[s as usize];
            p.1 += alone[s as usize];
        }
    }
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 1.0 };
    slot.iter()
        .zip(&count)
        .map(|(&s, &c)| {
            if s == u32::MAX {
                return DVec3::ONE;
            }
            let s = s as usize;
            let (pn, pd) = prior[band(c)];
            let mut k = DVec3::ONE;
            for ch in 0..3 {
                // k_f = (N_f + c K D_f) / ((1 + c) D_f): the face's own ratio N_f / D_f,
                // drawn towards the band's K = sum N / sum D with the weight of `c` faces.
                let (num, den) = (correlated[s][ch], alone[s][ch]);
                let scene = ratio(pn[ch], pd[ch]);
                k[ch] = ratio(num + PRIOR_FACES * scene * den, (1.0 + PRIOR_FACES) * den);
            }
            k
        })
        .collect()
}

/// `factors` ([`face_factors`], per face as [`face_key`] numbers them) of an estimate of
/// variances `before(i)` (patch `i`) once a part independent between patches, of variances
/// `added(i)`, is added to it (the lights' direct light, sampled per patch): per face and
/// channel `k'_f = (k_f sum_i A_i² V_i + sum_i A_i² D_i) / sum_i A_i² (V_i + D_i)`.
pub(crate) fn with_independent(
    mesh: &Mesh,
    factors: &mut [DVec3],
    before: impl Fn(usize) -> DVec3,
    added: impl Fn(usize) -> DVec3,
) {
    let back = mesh.back_face_offset();
    // the patches by face, each face's in patch order (a table of sums per face would be as
    // long as `factors`, whose faces a coarser mesh's patches may be far fewer than)
    let patches = mesh.patches();
    let mut order: Vec<(usize, usize)> = (0..patches.len())
        .map(|i| (face_key(mesh, i, back), i))
        .collect();
    order.sort_unstable();
    for face in order.chunk_by(|a, b| a.0 == b.0) {
        let (mut v, mut d) = (DVec3::ZERO, DVec3::ZERO);
        for &(_, i) in face {
            let a2 = patches[i].area * patches[i].area;
            v += a2 * before(i);
            d += a2 * added(i);
        }
        let k = &mut factors[face[0].0];
        for c in 0..3 {
            let total = v[c] + d[c];
            if total > 0.0 {
                k[c] = (k[c] * v[c] + d[c]) / total;
            }
        }
    }
}
