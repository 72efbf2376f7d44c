//! Memory bounded before the work: [`Problem::memory_estimate`] bounds the elements every mesh
//! plan makes on the bundled scenes, and a budget below the estimate refuses the problem
//! before anything is meshed ([`Error::Memory`]), with the estimate in the message.

use mcrad_mc_radiosity::Method;
use mcrad_scene_io::Scene;
use mcrad_solve::{
    BYTES_FIXED, BYTES_PER_ELEMENT, Budget, Error, MAX_GROWN_PATCHES, MeshPlan, PATCH_RAYS,
    Problem, Settings, peak_bytes, solve,
};
use std::ops::ControlFlow;

fn scene(name: &str) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name);
    mcrad_scene_io::load(&path).unwrap().scene
}

fn go(_: &mcrad_solve::Progress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

const SCENES: [&str; 5] = [
    "cornell-box.obj",
    "cornell-small-light.obj",
    "furnace.obj",
    "table-room.obj",
    "boxes-room.obj",
];

/// Every plan's mesh has at most the elements its estimate counts, and its mesh arrays hold
/// well under [`BYTES_PER_ELEMENT`] per element (the rest is the run's state and the BVH).
#[test]
fn the_estimate_bounds_every_plans_elements() {
    for name in SCENES {
        let scene = scene(name);
        for plan in [
            MeshPlan::default(),
            MeshPlan::Uniform { max_edge: None },
            MeshPlan::PerFace,
        ] {
            let mut problem = Problem::new(&scene);
            problem.settings = Settings {
                mesh: plan,
                ..Settings::default()
            };
            problem.budget.rays = Some(200_000);
            problem.threads = Some(2);
            let estimate = problem.memory_estimate();
            let answer = solve(&problem, &mut go).unwrap();
            let elements = answer.mesh.patches().len() as u64;
            assert!(
                elements <= estimate.elements,
                "{name} {plan:?}: {elements} elements, estimated at most {}",
                estimate.elements
            );
            let mesh_bytes = answer.mesh.heap_bytes() as u64;
            assert!(
                mesh_bytes <= elements * BYTES_PER_ELEMENT / 2,
                "{name} {plan:?}: the mesh alone holds {mesh_bytes} bytes for {elements} elements"
            );
            assert!(estimate.bytes > estimate.scene_bytes + elements * BYTES_PER_ELEMENT / 2);
        }
    }
}

/// The estimate follows the ray budget and bounds the model's terms of what a run did: for
/// methods that shoot, gather and combine, on the adaptive and uniform plans, at budgets of
/// 2e4 to 2e5 rays, the estimate made before the run is at least [`peak_bytes`] of the
/// elements the run made and the rays it cast; it does not fall as the rays grow and, under a
/// time budget alone, is that of unlimited rays (every element reached and gathered).
#[test]
fn the_estimate_follows_the_rays_and_bounds_the_runs_terms() {
    for name in ["cornell-box.obj", "table-room.obj"] {
        let scene = scene(name);
        for method in [Method::Shoot, Method::Gather, Method::Combined] {
            for plan in [MeshPlan::default(), MeshPlan::Uniform { max_edge: None }] {
                let mut problem = Problem::new(&scene);
                problem.settings = Settings {
                    mesh: plan,
                    method,
                    ..Settings::default()
                };
                problem.threads = Some(2);
                let mut last = 0;
                for rays in [20_000u64, 60_000, 200_000] {
                    problem.budget.rays = Some(rays);
                    let estimate = problem.memory_estimate();
                    assert_eq!(estimate.rays, rays);
                    assert!(
                        estimate.bytes >= last,
                        "{name} {method:?} {plan:?}: the estimate fell as the rays grew"
                    );
                    last = estimate.bytes;
                    let answer = solve(&problem, &mut go).unwrap();
                    let (elements, cast) = (answer.mesh.patches().len() as u64, answer.stats.rays);
                    let model = peak_bytes(elements, cast, method, estimate.scene_bytes);
                    assert!(
                        estimate.bytes >= model,
                        "{name} {method:?} {plan:?} {rays} rays: estimated {} bytes, the model \
                         of the run's {elements} elements and {cast} rays {model}",
                        estimate.bytes
                    );
                }
                problem.budget.rays = None;
                problem.budget.seconds = Some(1.0);
                let timed = problem.memory_estimate();
                assert_eq!(timed.rays, u64::MAX);
                assert_eq!(
                    timed.bytes,
                    peak_bytes(timed.elements, u64::MAX, method, timed.scene_bytes)
                );
                assert!(timed.bytes >= last);
            }
        }
    }
}

/// The model's constants bound the peaks measured on the generated atrium of about 10^6
/// elements (docs/atrium.md, "Memory and scale": peak RSS of `mcrad solve`, `combined`, 2
/// threads, the largest of the runs, `--clusters pool`), with the scene counted as nothing
/// (it is dropped before the peak): at 2e6 rays 658,952 KiB (before the cuts of
/// docs/meshing.md, "Memory per element"; 577,000-623,000 KiB after), at 2e7 rays 1,171,908
/// KiB (1,139,000-1,147,000 after). The
/// per-element terms beyond the fixed part are at most a fifth above what these peaks need at
/// 2e7 rays, where the budget reaches every element.
#[test]
fn the_model_bounds_the_measured_peaks() {
    for (elements, rays, peak_kib) in [
        (1_003_480u64, 2_000_000u64, 658_952u64),
        (1_014_758, 20_000_000, 1_171_908),
    ] {
        let model = peak_bytes(elements, rays, Method::Combined, 0);
        assert!(
            model >= peak_kib * 1024,
            "{elements} elements, {rays} rays: model {model} below the measured {} bytes",
            peak_kib * 1024
        );
    }
    let full = peak_bytes(1_014_758, 20_000_000, Method::Combined, 0) - BYTES_FIXED;
    let measured = 1_171_908u64 * 1024 - BYTES_FIXED;
    assert!(
        full * 5 <= measured * 6,
        "the model {full} is loose against {measured}"
    );
}

/// A budget one byte below the estimate refuses the problem, before any work, and says the
/// estimate and the limit; the estimate itself is enough.
#[test]
fn a_budget_below_the_estimate_refuses_the_problem() {
    let scene = scene("cornell-box.obj");
    let mut problem = Problem::new(&scene);
    problem.budget = Budget {
        rays: Some(100_000),
        ..Budget::default()
    };
    let estimate = problem.memory_estimate();
    // the default plan: at most the adaptive budget of 40,000 elements
    assert_eq!(estimate.elements, 40_000);
    problem.budget.memory = Some(estimate.bytes - 1);
    match solve(&problem, &mut go) {
        Err(e @ Error::Memory { .. }) => {
            let message = e.to_string();
            assert!(
                message.contains("40000 elements") && message.contains("MiB"),
                "{message}"
            );
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    problem.budget.memory = Some(estimate.bytes);
    assert!(solve(&problem, &mut go).is_ok());
    // a uniform cut finer than the budget allows is refused too; a coarser one fits
    problem.settings.mesh = MeshPlan::Uniform {
        max_edge: Some(0.005),
    };
    assert!(matches!(
        solve(&problem, &mut go),
        Err(Error::Memory { .. })
    ));
    problem.settings.mesh = MeshPlan::Uniform {
        max_edge: Some(0.1),
    };
    assert!(problem.memory_estimate().bytes <= estimate.bytes);
    assert!(solve(&problem, &mut go).is_ok());
}

/// A scene handed over ([`Input::SceneOnce`]) is taken and dropped once meshed: the answer is
/// the borrowed scene's, bit for bit, for the adaptive and the uniform plan and a continued
/// (replayed) run; the mutex is empty afterwards, a second solve of it is refused
/// ([`Error::SceneTaken`]), and so is none at all; the memory check still reads the scene.
#[test]
fn a_scene_handed_over_gives_the_same_answer_and_is_dropped() {
    use mcrad_solve::Input;
    use std::sync::Mutex;
    let scene = scene("cornell-box.obj");
    let plans = [
        MeshPlan::default(),
        MeshPlan::Uniform {
            max_edge: Some(0.1),
        },
    ];
    for plan in plans {
        let mut problem = Problem::new(&scene);
        problem.settings.mesh = plan;
        problem.budget = Budget {
            rays: Some(50_000),
            ..Budget::default()
        };
        let borrowed = solve(&problem, &mut go).unwrap();
        let handed = Mutex::new(Some(scene.clone()));
        let mut once = problem;
        once.input = Input::SceneOnce(&handed);
        let estimate = once.memory_estimate();
        assert_eq!(estimate, problem.memory_estimate());
        let answer = solve(&once, &mut go).unwrap();
        assert!(
            handed.lock().unwrap().is_none(),
            "{plan:?}: the scene is dropped"
        );
        assert_eq!(answer.estimate.radiosity(), borrowed.estimate.radiosity());
        assert_eq!(answer.estimate.variance(), borrowed.estimate.variance());
        assert_eq!(answer.stats.patches, borrowed.stats.patches);
        assert!(matches!(solve(&once, &mut go), Err(Error::SceneTaken)));
        // a continued run replays the adaptive mesh from the scene handed over
        if let Some(state) = &borrowed.state {
            let mut resumed = problem;
            resumed.resume = Some(state);
            let again = solve(&resumed, &mut go).unwrap();
            let handed = Mutex::new(Some(scene.clone()));
            resumed.input = Input::SceneOnce(&handed);
            let once_again = solve(&resumed, &mut go).unwrap();
            assert_eq!(once_again.estimate.radiosity(), again.estimate.radiosity());
        }
    }
}

/// The default patch budget grows with the rays (one element per [`PATCH_RAYS`]), all the way
/// ([`MAX_GROWN_PATCHES`]) under a time budget alone, and no further than a memory limit
/// leaves room for: such a limit caps the growth instead of refusing a problem the default
/// budget fits. A budget the caller set does not grow.
#[test]
fn the_default_patch_budget_grows_with_the_rays_within_the_memory_limit() {
    let scene = scene("cornell-box.obj");
    let mut problem = Problem::new(&scene);
    problem.budget.rays = Some(100_000);
    assert_eq!(problem.grown_patches(), mcrad_meshing::DEFAULT_MAX_PATCHES);
    problem.budget.rays = Some(200 * PATCH_RAYS * 1000);
    assert_eq!(problem.grown_patches(), 200_000);
    assert_eq!(problem.memory_estimate().elements, 200_000);
    problem.budget = Budget {
        seconds: Some(10.0),
        ..Budget::default()
    };
    assert_eq!(problem.grown_patches(), MAX_GROWN_PATCHES);
    let full = problem.memory_estimate();
    assert_eq!(full.elements, MAX_GROWN_PATCHES as u64);
    // a limit between the default budget's estimate and the grown one's: the largest budget
    // that fits, which the problem is then not refused for
    let mut small = Problem::new(&scene);
    small.budget = Budget {
        rays: Some(1_000_000_000),
        ..Budget::default()
    };
    small.settings.mesh = MeshPlan::Adaptive {
        max_patches: Some(mcrad_meshing::DEFAULT_MAX_PATCHES),
        min_edge: None,
    };
    let default_bytes = small.memory_estimate().bytes;
    assert!(default_bytes < full.bytes);
    let limit = (default_bytes + full.bytes) / 2;
    problem.budget.memory = Some(limit);
    let capped = problem.grown_patches();
    assert!(
        capped > mcrad_meshing::DEFAULT_MAX_PATCHES && capped < MAX_GROWN_PATCHES,
        "{capped}"
    );
    let estimate = problem.memory_estimate();
    assert!(estimate.bytes <= limit, "{estimate:?} over {limit}");
    assert_eq!(estimate.elements, capped as u64);
    // a budget the caller set stays as it is
    problem.settings.mesh = MeshPlan::Adaptive {
        max_patches: Some(5_000),
        min_edge: None,
    };
    assert_eq!(problem.memory_estimate().elements, 5_000);
}
