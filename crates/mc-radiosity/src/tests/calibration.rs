//! Issue 16's defects at high reflectance, as regression tests: the reported variance against
//! the spread between seeds, the power of the mean against the exact furnace answer, and the
//! budget used, on a unit furnace (every face emits `E = 1` and reflects `rho`: exactly
//! `B = 1 / (1 - rho)` on every patch) cut into 4 x 4 patches a face (96 patches).
//!
//! **Spread / reported.** For `SEEDS` runs, per patch and channel: the sample variance of `B`
//! between the seeds over the mean reported variance, pooled (sums over patches and channels).
//! Calibrated, it is 1 up to the noise of the sample variances: 15 degrees of freedom per
//! entry and 288 entries, but strongly correlated at high reflectance (every patch sees most
//! of the box), so take as few as 15 independent degrees of freedom: `chi²(15)/15` is below
//! 1/4 with probability 1.6e-3 and above 4 with 2.5e-7. The bounds are `[1/4, 4]`; before the
//! fix `combined` was at 4 (rho 0.9), 18-21 (0.99) and 1265 (0.999) on the 864-patch furnace
//! of `cargo xtask calibrate`, and `two-pass` at 2.9 (0.999).
//!
//! **Power.** The total power of the mean of the seeds against exact, in standard errors of
//! the runs' powers (Student-t, 15 dof, `P(|t| > 4.5) = 4.2e-4` per value), and within 1% of
//! exact at rho 0.999 (the target; it was 6-9% high for `combined`). Where the runs'
//! powers agree to rounding (shooting conserves power) the standard error is taken as at least
//! 1e-4 / 4.5 of the power, the solvers' own tolerance (`unshot_threshold` 1e-4).
//!
//! With 3 reflectances x 2 methods, the false-failure rate is about 1% from the spread bound
//! at its most conservative (with the correlation measured, far less: the ratios below sit
//! within 1.5) and 0.3% from the power.

use crate::{Method, ScheduleConfig, run};
use crate::{Sampler, StopReason};
use glam::DVec3;
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_scene_io::Scene;
use std::ops::ControlFlow;

use super::common;
use common::{box_faces, bvh, furnace, material};

const SEEDS: u64 = 16;
const RAYS: u64 = 20_000;

/// `(B, var B)` of `SEEDS` runs of `method` and the rays each cast.
fn runs(method: Method, mesh: &Mesh, rays: u64) -> Vec<(Vec<DVec3>, Vec<DVec3>, u64)> {
    runs_by(method, mesh, rays, Sampler::default())
}

/// [`runs`] with rays drawn by `sampler`.
fn runs_by(
    method: Method,
    mesh: &Mesh,
    rays: u64,
    sampler: Sampler,
) -> Vec<(Vec<DVec3>, Vec<DVec3>, u64)> {
    let bvh = bvh(mesh);
    (0..SEEDS)
        .map(|seed| {
            let config = ScheduleConfig {
                rays,
                seed: 7000 + seed,
                sampler,
                ..Default::default()
            };
            let s = run(method, mesh, &bvh, &config, &mut |_| {
                ControlFlow::Continue(())
            })
            .unwrap();
            let e = s.estimate;
            let v = e.variance().expect("a variance").to_vec();
            (e.radiosity().to_vec(), v, e.rays())
        })
        .collect()
}

/// Pooled spread between seeds / mean reported variance ([`common::spread_over_reported`]).
fn spread_over_reported(runs: &[(Vec<DVec3>, Vec<DVec3>, u64)]) -> f64 {
    common::spread_over_reported(runs.iter().map(|r| (&r.0[..], &r.1[..])))
}

/// Rays used / rays asked by one run of `method` with `rays` rays and `seed`.
fn budget_used(method: Method, mesh: &Mesh, bvh: &mcrad_raycast::Bvh, rays: u64, seed: u64) -> f64 {
    let config = ScheduleConfig {
        rays,
        seed,
        ..Default::default()
    };
    let s = run(method, mesh, bvh, &config, &mut |_| {
        ControlFlow::Continue(())
    })
    .unwrap();
    s.estimate.rays() as f64 / rays as f64
}

/// The relative bias of the mean power and its standard error.
fn power_bias(mesh: &Mesh, runs: &[(Vec<DVec3>, Vec<DVec3>, u64)], exact: f64) -> (f64, f64) {
    let powers: Vec<f64> = runs
        .iter()
        .map(|r| {
            mesh.patches()
                .iter()
                .zip(&r.0)
                .map(|(p, b)| p.area * (b.x + b.y + b.z))
                .sum()
        })
        .collect();
    let exact_power = exact * 3.0 * mesh.patches().iter().map(|p| p.area).sum::<f64>();
    let n = powers.len() as f64;
    let mean = powers.iter().sum::<f64>() / n;
    let var = powers.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (
        (mean - exact_power) / exact_power,
        (var / n).sqrt() / exact_power,
    )
}

#[test]
fn combined_and_two_pass_are_calibrated_and_unbiased_at_high_reflectance() {
    // Measured (seeds 7000-7015, 2e4 rays), spread/reported and bias/SE at rho 0.9/0.99/0.999:
    // combined 1.19/1.48/1.39, -1.3/+0.1/+0.7; two-pass 0.98/1.08/1.19, -1.4/-1.3/+1.5.
    for rho in [0.9f32, 0.99, 0.999] {
        let mesh = Mesh::build(&furnace(rho), Subdivision::MaxEdge(0.25)).unwrap();
        assert_eq!(mesh.patches().len(), 96);
        let exact = 1.0 / (1.0 - rho as f64);
        for method in [Method::Combined, Method::TwoPass] {
            let r = runs(method, &mesh, RAYS);
            let ratio = spread_over_reported(&r);
            let (bias, se) = power_bias(&mesh, &r, exact);
            let t = bias / se.max(1e-4 / 4.5);
            assert!(
                (0.25..=4.0).contains(&ratio),
                "{method:?} rho {rho}: spread between seeds / reported variance {ratio:.3}"
            );
            assert!(
                t.abs() <= 4.5,
                "{method:?} rho {rho}: power of the mean {bias:+.3e} relative, {t:.1} SE"
            );
            if rho >= 0.999 {
                assert!(bias.abs() < 0.01, "{method:?} rho {rho}: power {bias:+.3e}");
            }
        }
    }
}

#[test]
fn combined_spends_its_budget() {
    // Issue 16: combined and two-pass-split used 94-97% of `--rays` (direct-light samples
    // were budgeted at two rays each, while a sample casts a shadow ray only when the emitter
    // faces the patch). Deterministic given the seed: every run within 95-105% of its budget.
    let mesh = Mesh::build(&furnace(0.5), Subdivision::MaxEdge(0.25)).unwrap();
    let bvh = bvh(&mesh);
    for method in [Method::Combined, Method::TwoPassSplit] {
        for seed in 0..4 {
            let used = budget_used(method, &mesh, &bvh, 50_000, seed);
            assert!(
                (0.95..=1.05).contains(&used),
                "{method:?} seed {seed}: {:.1}% of the budget",
                100.0 * used
            );
        }
    }
}

#[test]
fn gather_adds_the_series_remainder_it_could_not_afford() {
    // Issue 16: `gather` at rho 0.99 with `--no-subdivide` was 89.5% low with a variance of 0
    // (the Jacobi series cut after the rounds the budget paid for; every ray of a furnace
    // sees the same value). A budget of 100 rounds at rho 0.999 sums 9.6% of the series; the
    // geometric remainder of the last increments restores the rest. In a furnace every round
    // is a uniform multiple of the last, so the answer is exact up to the rays that slip past the box's edges:
    // within 1e-4 of `1 / (1 - rho)`, with a variance above 0 (the remainder's uncertainty)
    // that covers the error, or exact with a variance of 0 when no round had noise.
    let rho = 0.999f32;
    let mesh = Mesh::build(&furnace(rho), Subdivision::None).unwrap();
    // the mesh's reflectance is the `f32` nearest 0.999, 1.3e-8 above it: B = 1000.0129
    let exact = 1.0 / (1.0 - f64::from(rho));
    let config = ScheduleConfig {
        rays: 1200,
        seed: 1,
        ..Default::default()
    };
    let s = run(Method::Gather, &mesh, &bvh(&mesh), &config, &mut |_| {
        ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!(s.steps, 100);
    let v = s.estimate.variance().unwrap();
    for (b, v) in s.estimate.radiosity().iter().zip(v) {
        for c in 0..3 {
            assert!(
                (b[c] - exact).abs() < 1e-4 * exact,
                "B = {} against {exact}",
                b[c]
            );
            // a variance of 0 only for an exact answer: no round had noise, so the
            // geometric remainder is exact (see the next test)
            assert!(
                v[c] > 0.0 || (b[c] - exact).abs() <= 1e-9 * exact,
                "variance 0 for B = {} against {exact}",
                b[c]
            );
            assert!(
                (b[c] - exact).powi(2) <= 16.0 * v[c] || (b[c] - exact).abs() <= 1e-9 * exact,
                "B = {}, var {}",
                b[c],
                v[c]
            );
        }
    }
}

#[test]
fn repeated_gathers_from_one_shooting_add_its_noise_as_correlated() {
    // Issue 16: progressive-gather gathers again and again from one shooting solution and
    // merged the gathers as independent, so the noise every gather inherits from that solution
    // was divided by the number of gathers: spread/reported 2.0-2.4 at every reflectance in
    // `cargo xtask calibrate`. At rho 0.5 the patches' errors are nearly independent (288
    // entries of 15 dof), so the pooled ratio has a relative standard deviation of a few
    // percent even if only 50 entries were independent (sqrt(2 / 750) = 5%): bounds
    // [0.6, 1.6] are 8 of them from 1 (false failure far below 1e-6 per value).
    // Measured (seeds 7000-7015, 2e4 rays): progressive-gather 1.05, progressive-two-pass 0.90;
    // with the inherited parts merged as independent, progressive-gather 2.05.
    let mesh = Mesh::build(&furnace(0.5), Subdivision::MaxEdge(0.25)).unwrap();
    for method in [Method::ProgressiveGather, Method::ProgressiveTwoPass] {
        // Independent rays: the correlation between the gathers is the subject. (Under the
        // default quasi-Monte Carlo rays progressive-two-pass reports 1.9x its spread on this
        // 4 x 4-patch face furnace (0.54), conservative; calibrate's 12 x 12: 0.71.)
        let ratio = spread_over_reported(&runs_by(method, &mesh, RAYS, Sampler::Random));
        assert!(
            (0.6..=1.6).contains(&ratio),
            "{method:?}: spread between seeds / reported variance {ratio:.3}"
        );
    }
}

#[test]
fn bidirectional_reports_the_variance_of_fixed_ray_counts_and_inherits_its_input_noise() {
    // Issue 16: bidirectional reported `sum c²` of the contributions a patch received, the
    // variance of a Poisson number of rays, while a patch's rays are drawn a fixed number at a
    // time: spread/reported 0.55 at rho 0.5 and 0.70 at 0.9 in `cargo xtask calibrate`. With
    // each source's sample mean taken out it under-reported at high reflectance instead (1.67
    // at rho 0.99) until the noise every step inherits from the solution it steps from was
    // added (as gathers do). Bounds as in the test above (false failure far below 1e-6).
    let mesh = Mesh::build(&furnace(0.5), Subdivision::MaxEdge(0.25)).unwrap();
    let ratio = spread_over_reported(&runs(Method::Bidirectional, &mesh, RAYS));
    assert!(
        (0.6..=1.6).contains(&ratio),
        "spread between seeds / reported variance {ratio:.3}"
    );
}

#[test]
fn gather_in_a_noise_free_furnace_is_exact_with_variance_zero() {
    // Issue 16: gather on the calibration furnaces (864 patches, no ray slips past an edge)
    // is exact, yet the series remainder reported a variance of (1e-3 of the remainder)², so
    // mean z² was 0.000. When no round had noise (every ray of a patch saw the same value, none
    // escaped) the rounds are the Jacobi iterates and the geometric remainder is exact: the
    // answer must be exact to 1e-9 with variance 0. Deterministic given the seed; checked on
    // two seeds, and only where the run was noise-free (else the variance must cover the
    // error as in the test above).
    // One patch per face at rho 0.99 (issue 36's case) too: there the series runs far enough
    // that rounding alone moves the increments' ratio by more than 1e-9.
    for (rho, rays, subdivision) in [
        (0.9f32, 200_000, Subdivision::MaxEdge(0.25)),
        (0.999, 200_000, Subdivision::MaxEdge(0.25)),
        (0.99, 200_000, Subdivision::None),
    ] {
        let mesh = Mesh::build(&furnace(rho), subdivision).unwrap();
        let exact = 1.0 / (1.0 - f64::from(rho));
        let mut noise_free = 0;
        for seed in 0..2 {
            let config = ScheduleConfig {
                rays,
                seed,
                ..Default::default()
            };
            let s = run(Method::Gather, &mesh, &bvh(&mesh), &config, &mut |_| {
                ControlFlow::Continue(())
            })
            .unwrap();
            let v = s.estimate.variance().unwrap();
            let all_zero = v.iter().all(|v| *v == DVec3::ZERO);
            noise_free += usize::from(all_zero);
            for (b, v) in s.estimate.radiosity().iter().zip(v) {
                for c in 0..3 {
                    let error = (b[c] - exact).abs();
                    if all_zero {
                        assert!(error <= 1e-9 * exact, "rho {rho}: B = {} with var 0", b[c]);
                    } else {
                        assert!(
                            error.powi(2) <= 25.0 * v[c],
                            "rho {rho}: B = {}, var {}",
                            b[c],
                            v[c]
                        );
                    }
                }
            }
        }
        assert!(
            noise_free > 0,
            "rho {rho}: no noise-free run (rays slip past the edges?)"
        );
    }
}

#[test]
fn gather_on_a_non_uniform_closed_box_spends_its_budget() {
    // Issue 16: gather stops when a round changes little. In a furnace that is right (the
    // rounds are noise-free), on a box lit by one face at rho 0.9 / 0.99 a stop would cut an
    // unconverged series: the noise of every round keeps the change above the threshold, so
    // the run must spend its budget (StopReason::BudgetSpent, >= 95% of the rays). A
    // deterministic check per seed, two seeds per reflectance.
    for rho in [0.9f32, 0.99] {
        let (mut p, mut f) = (Vec::new(), Vec::new());
        box_faces(1.0, &mut p, &mut f, [1, 0, 0, 0, 0, 0]);
        let materials = vec![material("wall", rho, 0.0), material("light", rho, 1.0)];
        let scene = Scene::new(p, f, materials).unwrap().0;
        let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.25)).unwrap();
        let bvh = bvh(&mesh);
        for seed in 0..2 {
            let config = ScheduleConfig {
                rays: 100_000,
                seed,
                ..Default::default()
            };
            let s = run(Method::Gather, &mesh, &bvh, &config, &mut |_| {
                ControlFlow::Continue(())
            })
            .unwrap();
            let used = s.estimate.rays() as f64 / config.rays as f64;
            assert_eq!(s.stop, StopReason::BudgetSpent, "rho {rho} seed {seed}");
            assert!(used >= 0.95, "rho {rho} seed {seed}: {:.1}%", 100.0 * used);
        }
    }
}

#[test]
fn prr_keeps_its_budget_at_rho_0_999() {
    // Issue 16: PRR at rho 0.999 used up to 105.1% of its rays (`cargo xtask calibrate`, 864
    // patches, 2e5 rays): each pass overruns by its finishing roulette's tail (0-30% of it,
    // random) and the last pass's overrun was charged to nobody, so every run overran. The
    // last pass is now sized to what is left over the share cast per ray asked so far, and
    // what it leaves goes to further passes. The same furnace's patches here (12 x 12 a face),
    // seeds 0..6; budget use is a deterministic function of the seed. Every seed within
    // 95-105%, and the mean use within 0.85% of the budget: before, 100.9% (every seed
    // 100.1-101.5%); after, 100.05% with a spread of 0.95% between seeds (standard error of
    // a 6-seed mean 0.39%, so the bound is 2.2 standard errors: a false-failure rate of about
    // 3% for another set of seeds).
    let mesh = Mesh::build(&furnace(0.999), Subdivision::MaxEdge(1.0 / 12.0 + 1e-4)).unwrap();
    assert_eq!(mesh.patches().len(), 864);
    let bvh = bvh(&mesh);
    let mut mean = 0.0;
    for seed in 0..6 {
        let used = budget_used(Method::Prr, &mesh, &bvh, 200_000, seed);
        assert!(
            (0.95..=1.05).contains(&used),
            "seed {seed}: {:.1}% of the budget",
            100.0 * used
        );
        mean += used / 6.0;
    }
    assert!(
        (mean - 1.0).abs() <= 0.0085,
        "mean use {:.2}% of the budget",
        100.0 * mean
    );
}

/// Mean `z² = (B - R)² / (var_B + var_R)` over the walls' patches and channels of `seeds`
/// runs of `method` with 2e5 rays in a unit box (rho 0.5, 600 patches) lit by a 0.05 x 0.05
/// light (E = 4000) hanging just below the ceiling, facing down, and the number of values.
/// Reference: `two-pass-split` (direct light by emitter sampling, calibrated: spread/reported
/// 1.00 in the calibration suite) with 4e6 rays.
fn tiny_light_z2(method: Method, seeds: u64) -> (f64, usize) {
    let (mut p, mut f) = (Vec::new(), Vec::new());
    box_faces(1.0, &mut p, &mut f, [0; 6]);
    let base = p.len() as u32;
    let (lo, hi, y) = (0.475f32, 0.525f32, 0.99f32);
    p.extend([
        glam::Vec3::new(lo, y, lo),
        glam::Vec3::new(hi, y, lo),
        glam::Vec3::new(hi, y, hi),
        glam::Vec3::new(lo, y, hi),
    ]);
    // Counter-clockwise seen from below: normal -y.
    f.push(common::quad([base, base + 1, base + 2, base + 3], 1, 6));
    let materials = vec![material("wall", 0.5, 0.0), material("light", 0.0, 4000.0)];
    let scene = Scene::new(p, f, materials).unwrap().0;
    let mesh = Mesh::build(&scene, Subdivision::MaxEdge(0.1)).unwrap();
    let bvh = bvh(&mesh);
    let solve = |method, rays, seed| {
        let config = ScheduleConfig {
            rays,
            seed,
            ..Default::default()
        };
        run(method, &mesh, &bvh, &config, &mut |_| {
            ControlFlow::Continue(())
        })
        .unwrap()
        .estimate
    };
    let reference = solve(Method::TwoPassSplit, 4_000_000, 99);
    let (r, vr) = (reference.radiosity(), reference.variance().unwrap());
    let walls: Vec<usize> = (0..mesh.patches().len())
        .filter(|&i| mesh.patches()[i].emission == glam::Vec3::ZERO)
        .collect();
    let (mut z2, mut n) = (0.0, 0usize);
    for seed in 0..seeds {
        let e = solve(method, 200_000, seed);
        let (b, v) = (e.radiosity(), e.variance().unwrap());
        for &i in &walls {
            for c in 0..3 {
                let var = v[i][c] + vr[i][c];
                if var > 0.0 {
                    z2 += (b[i][c] - r[i][c]).powi(2) / var;
                    n += 1;
                }
            }
        }
    }
    (z2 / n as f64, n)
}

#[test]
fn gathered_variances_do_not_follow_a_patchs_own_luck_with_a_tiny_light() {
    // Issue 16: in a room lit by a tiny light, most gathering rays miss it. A patch whose few
    // rays missed it reports a low value; its variance must not be low for the same reason.
    // The variance of a gathered patch was half its own sample variance (which follows its luck)
    // and half its face's; mean z² was 0.35-0.42 for two-pass in the calibration's tiny-light
    // room. Now it is the face's, over all its patches' rays.
    //
    // 8 seeds of `two-pass` (`tiny_light_z2`): 14,400 z² values, strongly skewed by the rare
    // hits, so the bounds are wide, [0.6, 1.6]: measured 1.00 (1.13 with the other patches' rays only) with these seeds;
    // the old estimate gives 0.44.
    let (mean, n) = tiny_light_z2(Method::TwoPass, 8);
    assert!(n > 14_000, "only {n} values with a variance");
    assert!(
        (0.6..=1.6).contains(&mean),
        "mean z² {mean:.3} over {n} values"
    );
}

#[test]
fn jacobi_gathering_keeps_the_direct_light_noise_of_its_rounds_with_a_tiny_light() {
    // Issue 16: pure Jacobi gathering re-gathers the direct light every round. With a tiny
    // light most rounds' rays on a face miss it; the last round's sample variance then claimed
    // no direct-light noise while the value was as far off as ever (the calibration's
    // tiny-light room: mean z² 51.7, one seed's wall 7 times too dark with a standard
    // deviation of a fifth of its value). The emission seen is pooled over the run's rounds.
    //
    // 8 seeds of `gather` (`tiny_light_z2`), bounds [0.6, 1.6] as above: measured
    // 0.81; without the pooling over rounds 2.64.
    let (mean, n) = tiny_light_z2(Method::Gather, 8);
    assert!(n > 14_000, "only {n} values with a variance");
    assert!(
        (0.6..=1.6).contains(&mean),
        "mean z² {mean:.3} over {n} values"
    );
}

#[test]
fn bidirectional_charges_its_first_shootings_tail_to_later_passes() {
    // Issue 16: `bidirectional` opens with a shooting pass, whose finishing roulette's tail at
    // rho 0.999 casts several times the pass's rays; nobody was charged for them, and runs used
    // up to 107.6% of the budget (`cargo xtask calibrate`, 16 seeds). The tail now comes out of
    // the later passes. The calibration's furnace (864 patches, 2e5 rays), seeds 0..8; budget
    // use is a deterministic function of the seed: before, 100.0-103.3% (4 seeds beyond 101%);
    // after, 99.97-100.03% (what is left is the stochastic rounding of the later passes' ray
    // counts), so every seed within 1%.
    let mesh = Mesh::build(&furnace(0.999), Subdivision::MaxEdge(1.0 / 12.0 + 1e-4)).unwrap();
    let bvh = bvh(&mesh);
    for seed in 0..8 {
        let used = budget_used(Method::Bidirectional, &mesh, &bvh, 200_000, seed);
        assert!(
            (0.99..=1.01).contains(&used),
            "seed {seed}: {:.1}% of the budget",
            100.0 * used
        );
    }
}

#[test]
fn shooting_at_rho_0_99999_keeps_its_budget_and_extrapolates_the_rest() {
    // Issue 16: at rho 0.99999 light bounces 1e5 times, five times a budget of 2e4 rays. The
    // shooting's finishing roulette shipped all the power left at the budget's end, and the
    // default run cast 26-28 times its rays. Where the tail cannot fit (three standard
    // deviations of its random cost included) in `max_overrun` of the budget (5%, plus the
    // later passes' rays in a progressive schedule), the run stops and extrapolates the light
    // still to come, `|U| r / (1 - r)` spread as the reflected light so far, exact in a
    // uniform closed furnace. Every shooting method, 16 seeds of 2e4 rays: every run within
    // 110% of its budget (the gathers' two rays per patch and pass round small budgets up),
    // and the power of the mean within 4.5 standard errors and 1% of exact.
    let rho = 0.99999f32;
    let mesh = Mesh::build(&furnace(rho), Subdivision::MaxEdge(0.25)).unwrap();
    let exact = 1.0 / (1.0 - rho as f64);
    for method in [
        Method::Shoot,
        Method::Prr,
        Method::Combined,
        Method::TwoPass,
        Method::ProgressiveTwoPass,
        Method::Bidirectional,
    ] {
        let r = runs(method, &mesh, RAYS);
        for (seed, run) in r.iter().enumerate() {
            let used = run.2 as f64 / RAYS as f64;
            assert!(used <= 1.10, "{method:?} seed {seed}: {:.1}%", 100.0 * used);
        }
        let (bias, se) = power_bias(&mesh, &r, exact);
        let t = bias / se.max(1e-4 / 4.5);
        assert!(
            t.abs() <= 4.5 && bias.abs() < 0.01,
            "{method:?}: power of the mean {bias:+.3e} relative, {t:.1} SE"
        );
    }
}

#[test]
fn a_run_capped_by_its_observer_at_rho_0_9999999_ends_at_the_cap() {
    // Issue 16: `--time 2` at rho 0.9999999 was still running after 40 s: the finishing
    // roulette of a shooting pass, which no observer sees, shipped 1e7 bounces. A run without
    // a ray budget whose observer caps the rays left (what `--time` does) now ends near the
    // cap, the light it could not shoot extrapolated. Cap 5e4 rays; the first pass of a run
    // without a budget is 1e5 rays, so a run may end at its first pass: at most 1.1e5 rays.
    let mesh = Mesh::build(&furnace(0.9999999), Subdivision::MaxEdge(0.25)).unwrap();
    let bvh = bvh(&mesh);
    for method in [
        Method::Shoot,
        Method::Combined,
        Method::Prr,
        Method::TwoPass,
    ] {
        let config = ScheduleConfig {
            rays: u64::MAX,
            seed: 1,
            ..Default::default()
        };
        let cap = 50_000u64;
        let s = run(method, &mesh, &bvh, &config, &mut |step| {
            step.limit_rays_left(cap.saturating_sub(step.rays));
            ControlFlow::Continue(())
        })
        .unwrap();
        let rays = s.estimate.rays();
        assert!(rays <= 110_000, "{method:?}: {rays} rays");
        let b = s.estimate.radiosity()[0].y;
        assert!(b.is_finite() && b > 0.0, "{method:?}: B {b}");
    }
}
