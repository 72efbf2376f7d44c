//! The library's solve on the bundled closed furnace (every face `E = 1` W/m², `rho = 0.5`:
//! exact `B = E / (1 - rho) = 2` W/m² everywhere), and what it promises around the method:
//! budgets, observers, cancelling, continuing a saved run.

use mcrad_mc_radiosity::Method;
use mcrad_scene_io::Scene;
use mcrad_solve::{Budget, Error, MeshPlan, Problem, RunState, Settings, solve};
use std::ops::ControlFlow;
use std::sync::atomic::AtomicBool;

fn furnace() -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/furnace.obj");
    mcrad_scene_io::load(&path).unwrap().scene
}

fn go(_: &mcrad_solve::Progress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

/// The area-weighted mean radiosity (channels averaged) and the variance of that mean from the
/// reported variances (patches taken as independent).
fn mean_and_variance(answer: &mcrad_solve::Answer) -> (f64, f64) {
    let patches = answer.mesh.patches();
    let total: f64 = patches.iter().map(|p| p.area).sum();
    let variance = answer.estimate.variance().expect("a variance");
    let (mut mean, mut var) = (0.0, 0.0);
    for (i, p) in patches.iter().enumerate() {
        let w = p.area / total;
        mean += w * answer.estimate.radiosity()[i].element_sum() / 3.0;
        var += w * w * variance[i].element_sum() / 9.0;
    }
    (mean, var)
}

#[test]
fn the_default_solve_of_a_closed_furnace_is_exact_within_its_error_bars() {
    let scene = furnace();
    // k = 4 standard errors over 4 seeds: a false failure about 1 in 15 000 for normal errors.
    const K: f64 = 4.0;
    let mut sum = 0.0;
    let mut var = 0.0;
    for seed in 0..4 {
        let mut problem = Problem::new(&scene);
        problem.settings.seed = seed;
        problem.budget.rays = Some(200_000);
        let answer = solve(&problem, &mut go).unwrap();
        assert!(
            answer.stats.refinement.is_some(),
            "the default mesh is adaptive"
        );
        assert!(
            answer.state.is_some(),
            "a progressive run has a state to continue"
        );
        let (m, v) = mean_and_variance(&answer);
        sum += m;
        var += v;
    }
    let (mean, se) = (sum / 4.0, var.sqrt() / 4.0);
    assert!(
        (mean - 2.0).abs() <= K * se.max(1e-9) + 1e-4,
        "mean {mean} against 2 ± {se}"
    );
}

#[test]
fn a_continued_run_merges_its_pieces_and_refuses_other_settings() {
    let scene = furnace();
    let mut problem = Problem::new(&scene);
    problem.settings.seed = 5;
    problem.budget.rays = Some(100_000);
    let first = solve(&problem, &mut go).unwrap();
    let state = first.state.clone().expect("a state");
    // written and read back bit for bit
    let mut bytes = Vec::new();
    state.write(&mut bytes).unwrap();
    let state = RunState::read(bytes.as_slice()).unwrap();
    assert_eq!(state.estimate().unwrap(), first.estimate);
    assert!(matches!(
        RunState::read(&b"not a state"[..]),
        Err(Error::NotAState)
    ));

    // The continuation takes the saved settings (the adaptive mesh included).
    let mut next = Problem::new(&scene);
    next.settings = state.settings();
    next.budget.rays = Some(100_000);
    next.resume = Some(&state);
    let second = solve(&next, &mut go).unwrap();
    assert_eq!(second.patch, first.patch, "the saved mesh");
    // the piece's rays (its whole budget: no refinement on a saved mesh) add to the saved ones
    let added = second.estimate.rays() - first.estimate.rays();
    assert!((90_000..=105_000).contains(&added), "{added} rays added");
    assert_eq!(second.stats.rays, second.estimate.rays());
    let (_, v1) = mean_and_variance(&first);
    let (m2, v2) = mean_and_variance(&second);
    assert!(v2 < 0.75 * v1, "two pieces: variance {v2} against {v1}");
    assert!((m2 - 2.0).abs() <= 4.0 * v2.sqrt() + 1e-4, "mean {m2}");

    // A setting that differs is named with both values.
    let mut other = next;
    other.settings.seed = 6;
    match solve(&other, &mut go) {
        Err(Error::Disagree { what, saved, given }) => {
            assert_eq!((what, saved.as_str(), given.as_str()), ("seed", "5", "6"))
        }
        r => panic!("not refused: {:?}", r.map(|a| a.stats)),
    }
}

#[test]
fn an_observer_stops_the_run_and_a_cancel_before_the_first_step_has_no_answer() {
    let scene = furnace();
    let mut problem = Problem::new(&scene);
    problem.settings.mesh = MeshPlan::Uniform { max_edge: None };
    problem.settings.method = Method::Prr;
    problem.budget.rays = Some(1_000_000);
    let mut steps = 0;
    let answer = solve(&problem, &mut |p| {
        steps += 1;
        assert_eq!(p.step, steps);
        assert_eq!(p.mesh().patches().len(), p.radiosity().unwrap().len());
        ControlFlow::Break(())
    })
    .unwrap();
    assert_eq!((steps, answer.stats.iterations), (1, 1));
    assert_eq!(answer.stats.stop, mcrad_mc_radiosity::StopReason::Stopped);
    assert!(answer.estimate.rays() < 1_000_000);

    let cancelled = AtomicBool::new(true);
    problem.cancel = Some(&cancelled);
    assert!(matches!(
        solve(&problem, &mut go),
        Err(Error::CancelledEarly)
    ));
}

#[test]
fn an_error_target_ends_a_progressive_run_early() {
    let scene = furnace();
    let settings = Settings {
        mesh: MeshPlan::Uniform { max_edge: None },
        ..Settings::default()
    };
    let mut problem = Problem::new(&scene);
    problem.settings = settings;
    problem.budget = Budget {
        rays: Some(20_000_000),
        target_error: Some(0.05),
        ..Budget::default()
    };
    let answer = solve(&problem, &mut go).unwrap();
    assert!(answer.target_reached);
    assert!(
        answer.stats.rays < 20_000_000 / 4,
        "{} rays",
        answer.stats.rays
    );
}

/// The furnace loaded with `sky` and `sun` added.
fn furnace_lit(sky: Option<mcrad_scene_io::Sky>, sun: Option<mcrad_scene_io::Light>) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/furnace.obj");
    let options = mcrad_scene_io::LoadOptions {
        sky,
        lights: sun.into_iter().collect(),
        ..Default::default()
    };
    mcrad_scene_io::load_with(&path, &options).unwrap().scene
}

#[test]
fn a_continued_run_refuses_another_sky_or_sun() {
    use glam::{DVec3, Vec3};
    use mcrad_scene_io::{Light, Sky, Sun};
    let sky = |l: f64| Some(Sky::Uniform(DVec3::splat(l)));
    let sun = Light::Sun(Sun {
        direction: Vec3::Y,
        irradiance: DVec3::splat(100.0),
        diameter: 0.0,
    });
    let scene = furnace_lit(sky(1.0), None);
    let mut problem = Problem::new(&scene);
    problem.budget.rays = Some(20_000);
    let first = solve(&problem, &mut go).unwrap();
    let state = first.state.clone().expect("a state");
    let resume = |scene: &Scene| {
        let mut next = Problem::new(scene);
        next.settings = state.settings();
        next.budget.rays = Some(20_000);
        next.resume = Some(&state);
        solve(&next, &mut go).map(|a| a.estimate.rays())
    };
    // the same sky continues (the uniform mesh made again: no adaptive history)
    let same = furnace_lit(sky(1.0), None);
    assert!(resume(&same).unwrap() > first.estimate.rays());
    for other in [
        furnace_lit(sky(2.0), None),
        furnace_lit(None, Some(sun.clone())),
        furnace_lit(sky(1.0), Some(sun)),
    ] {
        match resume(&other) {
            Err(e @ Error::StateLighting) => {
                assert!(e.to_string().contains("another sky"), "{e}")
            }
            r => panic!("not refused: {r:?}"),
        }
    }
}

/// Under a time budget, the caller's work after the solve ([`Problem::after`], asked once with
/// the solved mesh) gets its time: when it claims the whole budget the run stops after its
/// first step, where without it the ray budget ends the run (an hour is far more than 1e6
/// rays need).
#[test]
fn a_time_budget_leaves_the_callers_work_after_the_solve_its_time() {
    let scene = furnace();
    let mut problem = Problem::new(&scene);
    problem.settings.mesh = MeshPlan::Uniform { max_edge: None };
    problem.settings.method = Method::Prr;
    problem.budget.rays = Some(1_000_000);
    problem.budget.seconds = Some(3600.0);
    let free = solve(&problem, &mut go).unwrap();
    assert!(free.stats.iterations > 1);
    assert!(free.estimate.rays() >= 990_000, "{}", free.estimate.rays());

    let asked = std::sync::atomic::AtomicUsize::new(0);
    let patches = free.mesh.patches().len();
    let after = |mesh: &mcrad_meshing::Mesh, _: &mcrad_raycast::Bvh| {
        asked.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        assert_eq!(mesh.patches().len(), patches);
        3600.0
    };
    problem.after = Some(mcrad_solve::AfterSolve(&after));
    let busy = solve(&problem, &mut go).unwrap();
    assert_eq!(asked.load(std::sync::atomic::Ordering::SeqCst), 1);
    assert_eq!(busy.stats.iterations, 1);
    assert!(busy.estimate.rays() < free.estimate.rays() / 4);
    assert_eq!(busy.stats.stop, mcrad_mc_radiosity::StopReason::BudgetSpent);
}

/// The answer carries, per face, the factor of the correlation between its patches
/// (`Answer::face_correlation`, what `--per-face` and a bake's per-face figures take): on the
/// default adaptive mesh one for every face, finite and positive, through the refinement's
/// pool; exactly 1 on faces of one patch, where there is no other patch to correlate with.
#[test]
fn the_answer_carries_each_faces_correlation_factor() {
    let scene = furnace();
    let mut problem = Problem::new(&scene);
    problem.budget.rays = Some(200_000);
    let answer = solve(&problem, &mut go).unwrap();
    let k = answer.face_correlation.expect("combined gives the factors");
    let faces = answer.mesh.patches().iter().map(|p| p.face).max().unwrap() as usize + 1;
    assert_eq!(k.len(), faces);
    assert!(
        k.iter().all(|k| k.is_finite() && k.min_element() > 0.0),
        "{k:?}"
    );
    assert!(k.iter().any(|k| *k != glam::DVec3::ONE), "{k:?}");
    problem.settings.mesh = MeshPlan::PerFace;
    let answer = solve(&problem, &mut go).unwrap();
    let k = answer.face_correlation.expect("combined gives the factors");
    assert!(k.iter().all(|k| *k == glam::DVec3::ONE), "{k:?}");
}
