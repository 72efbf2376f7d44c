//! A control variate for patch gathering that stays unbiased in open scenes (issue 17).
//!
//! A gathering ray of patch `i` sees `x = input[j]` at its first front-face hit `j` and 0
//! otherwise (an escape or a back face), so `E[x] = sum_j F_ij input_j`. With `h` the
//! indicator of a front-face hit, `S_i = E[h] = sum_j F_ij` the share of the cosine-weighted
//! hemisphere that sees the scene's front faces, and a constant `beta_i`,
//!
//! ```text
//! E[x] = beta_i S_i + E[h (x - beta_i)]
//! ```
//!
//! RenderPark's constant control variate takes `S_i = 1`: exact in a closed scene, biased by
//! `beta_i (1 - S_i)` where rays escape (it stalls at 15% error on the Cornell box with
//! blocks). With `S_i` drawn from the same rays, `beta_i Ŝ_i + mean(h (x - beta_i))` is
//! `mean(x)` again: no gain. Here `S_i` is a property of the geometry alone, so every earlier
//! gathering round of the run has measured it: `Ŝ_i = H_i / N_i`, the front-face hits over the
//! rays of the patch's earlier rounds, independent of this round's rays. The estimate
//!
//! ```text
//! mean_i = beta_i Ŝ_i + (1/n) sum_k h_k (x_k - beta_i)
//! ```
//!
//! is unbiased when `beta_i` is independent of `Ŝ_i` (and of this round's rays): `beta_i` is the mean of `x` over the
//! front-face hits of the patch's last round, the minimiser of `Var[h (x - beta)]`, and `Ŝ_i`
//! counts the rounds before that one only (given the count of hits, a mean over them does not
//! depend on it, but the lag makes the independence exact). The per-ray variance drops from
//! `Var[x]` to `Var[h (x - beta)]`: the miss/hit part `beta² S (1 - S)` of a patch near an
//! opening goes, and what `Ŝ_i` costs, `beta_i² Ŝ_i (1 - Ŝ_i) / N_i`, is shared by the rounds
//! that use it (an error common to them, reported apart so that schedules merging rounds add
//! it as correlated).
//!
//! That cost exceeds the gain when the earlier rounds cast fewer rays than this one (`N_i < n`:
//! the doubling rounds of the progressive methods). The estimate above is plain gathering plus
//! `beta_i (Ŝ_i - mean(h))`, a control of known mean zero, so any multiple `w` of it stays
//! unbiased; the variance-minimising one is `w = N_i / (N_i + n)` (the covariance of `mean(h x)`
//! with `mean(h)` is `mu S (1 - S) / n`, the variance of the difference `S (1 - S) (1/N + 1/n)`),
//! so `beta_i` is scaled by it: the control then never adds variance, and removes
//! `w mu² S (1 - S) / n` of it (`mu` the mean over hits). In a closed scene every ray hits a front face, `Ŝ_i = 1` exactly, and the
//! estimate is `mean(x)` to rounding: nothing changes.

use glam::DVec3;
use std::sync::Mutex;

/// Whether patch gathering uses the control variate of this module (the command line's
/// `--control-variate`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ControlVariate {
    /// Plain gathering: a patch's estimate is the mean of what its rays see.
    #[default]
    Off,
    /// A constant control variate per patch, `beta_i` from its last round and the coverage
    /// `S_i` of its hemisphere from the rounds before: unbiased in open scenes (the module
    /// documentation of `control`).
    Constant,
}

impl ControlVariate {
    /// Every choice, in the order the command line lists them.
    pub const ALL: [ControlVariate; 2] = [ControlVariate::Off, ControlVariate::Constant];

    /// The name on the command line and in run statistics: `off` or `constant`.
    pub const fn name(self) -> &'static str {
        match self {
            ControlVariate::Off => "off",
            ControlVariate::Constant => "constant",
        }
    }
}

impl std::str::FromStr for ControlVariate {
    type Err = crate::UnknownName;

    /// The choice of a [name](ControlVariate::name) (exactly).
    fn from_str(s: &str) -> Result<ControlVariate, crate::UnknownName> {
        crate::method::parse_name(
            s,
            &ControlVariate::ALL,
            ControlVariate::name,
            "control variate",
        )
    }
}

impl std::fmt::Display for ControlVariate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What the earlier rounds of a run learned about one patch's hemisphere.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Learned {
    /// Rays of the rounds before the last one.
    rays: u64,
    /// Their front-face hits.
    hits: u64,
    /// Rays of the last round.
    last_rays: u64,
    /// Its front-face hits.
    last_hits: u64,
    /// The mean value its front-face hits saw (W/m² per channel); 0 before any.
    beta: DVec3,
}

/// The control of one patch for one round: `offset = w beta Ŝ` (W/m² per channel) is added to
/// the mean of `h (x - w beta)`, and `offset_variance = (w beta)² Ŝ (1 - Ŝ) / N` ((W/m²)²) is
/// the variance `Ŝ` brings, shared by every round that uses the same `Ŝ`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Control {
    /// `w_i beta_i` (W/m² per channel): what a front-face hit subtracts; 0 for no control.
    pub beta: DVec3,
    /// `w_i beta_i Ŝ_i` (W/m² per channel).
    pub offset: DVec3,
    /// `(w_i beta_i)² Ŝ_i (1 - Ŝ_i) / N_i` ((W/m²)² per channel).
    pub offset_variance: DVec3,
}

/// The per-patch state of the control variate over a run: rounds of patch gathering read it
/// before they cast ([`Coverage::controls`]) and add what their rays saw after
/// ([`Coverage::learn`]), in the order the run calls them (rounds are sequential, so the
/// state and every result depend on the seed only).
#[derive(Debug, Default)]
pub(crate) struct Coverage {
    learned: Mutex<Vec<Learned>>,
}

impl Coverage {
    /// The controls of the next round for `patches` patches casting `n` rays each: none for a
    /// patch without a round before its last one (`beta = 0`: plain gathering).
    pub fn controls(&self, patches: usize, n: u32) -> Vec<Control> {
        let learned = self.learned.lock().unwrap_or_else(|e| e.into_inner());
        (0..patches)
            .map(|i| match learned.get(i) {
                Some(l) if l.rays > 0 && l.last_hits > 0 => {
                    let s = l.hits as f64 / l.rays as f64;
                    let beta = l.beta * (l.rays as f64 / (l.rays as f64 + f64::from(n)));
                    Control {
                        beta,
                        offset: beta * s,
                        offset_variance: beta * beta * (s * (1.0 - s) / l.rays as f64),
                    }
                }
                _ => Control::default(),
            })
            .collect()
    }

    /// Records a round: per patch its rays, front-face hits and the mean value those hits saw
    /// (W/m² per channel; ignored without hits).
    pub fn learn(&self, rounds: impl ExactSizeIterator<Item = (u64, u64, DVec3)>) {
        let mut learned = self.learned.lock().unwrap_or_else(|e| e.into_inner());
        if learned.len() < rounds.len() {
            learned.resize(rounds.len(), Learned::default());
        }
        for (l, (rays, hits, hit_mean)) in learned.iter_mut().zip(rounds) {
            l.rays += l.last_rays;
            l.hits += l.last_hits;
            l.last_rays = rays;
            l.last_hits = hits;
            if hits > 0 {
                l.beta = hit_mean;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_control_before_two_rounds_then_the_lagged_coverage() {
        let c = Coverage::default();
        assert_eq!(c.controls(2, 10), vec![Control::default(); 2]);
        c.learn([(10, 5, DVec3::ONE), (10, 0, DVec3::ZERO)].into_iter());
        // One round: beta known, but no coverage independent of it yet.
        assert_eq!(c.controls(2, 10), vec![Control::default(); 2]);
        c.learn([(10, 10, DVec3::splat(2.0)), (10, 4, DVec3::splat(3.0))].into_iter());
        // The next round casts 30 rays per patch: w = 10 / (10 + 30).
        let k = c.controls(2, 30);
        // Patch 0: coverage 5/10 from round 1, beta 2 from round 2.
        assert_eq!(k[0].beta, DVec3::splat(0.5));
        assert_eq!(k[0].offset, DVec3::splat(0.25));
        assert!((k[0].offset_variance.x - 0.25 * 0.25 / 10.0).abs() < 1e-12);
        // Patch 1: its first round saw nothing, so its coverage (0 of 10) and its beta (3)
        // still give a control.
        assert_eq!(k[1].beta, DVec3::splat(0.75));
        assert_eq!(k[1].offset, DVec3::ZERO);
    }
}
