//! The closure report ([`mcrad_solve::Closure`]): power emitted, absorbed and escaped, and
//! their balance within its standard error, on a closed scene, an open one and a scene whose
//! light ends on a black (`rho = 0`) patch. Fixed seeds; k = 4 standard errors per run and
//! channel (a false failure about 1 in 15 000 per comparison for normal errors).

use glam::Vec3;
use mcrad_mc_radiosity::Method;
use mcrad_scene_io::{Face, Material, Scene};
use mcrad_solve::{Answer, Closure, MeshPlan, Problem, solve};
use std::ops::ControlFlow;

const K: f64 = 4.0;

fn bundled(name: &str) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name);
    mcrad_scene_io::load(&path).unwrap().scene
}

fn run(problem: &Problem) -> Answer {
    solve(problem, &mut |_: &mcrad_solve::Progress| {
        ControlFlow::Continue(())
    })
    .unwrap()
}

/// Asserts the balance of every channel is within `K` standard errors, and no warning.
fn balances(c: &Closure, warnings: &[String]) {
    let se = c.balance_se.expect("a standard error");
    for (k, ((b, se), e)) in c.balance.iter().zip(se).zip(c.emitted).enumerate() {
        assert!(b.abs() <= K * se + 1e-9 * e, "channel {k}: {c:?}");
    }
    assert!(
        !warnings.iter().any(|w| w.contains("conserve power")),
        "{warnings:?}"
    );
}

#[test]
fn a_closed_furnace_balances_and_nothing_escapes() {
    let scene = bundled("furnace.obj");
    for seed in 0..3 {
        let mut problem = Problem::new(&scene);
        problem.closure = true;
        problem.settings.seed = seed;
        problem.budget.rays = Some(200_000);
        let answer = run(&problem);
        let c = answer.stats.closure.expect("asked for");
        // six unit faces at E = 1 W/m²
        assert!((c.emitted[0] - 6.0).abs() < 1e-9, "{c:?}");
        assert_eq!(c.escaped, [0.0; 3]);
        assert!(c.rays >= 2 * answer.stats.patches as u64);
        balances(&c, &answer.warnings);
    }
}

#[test]
fn the_open_cornell_box_balances_over_seeds() {
    // The bundled Cornell box has no front wall: light escapes through it.
    let scene = bundled("cornell-box.obj");
    let (mut sum, mut var) = ([0.0; 3], [0.0; 3]);
    for seed in 0..4 {
        let mut problem = Problem::new(&scene);
        problem.closure = true;
        problem.settings.seed = seed;
        problem.settings.mesh = MeshPlan::Uniform { max_edge: None };
        problem.budget.rays = Some(500_000);
        let answer = run(&problem);
        let c = answer.stats.closure.expect("asked for");
        assert!(
            c.escaped.iter().zip(c.emitted).all(|(x, e)| *x > 0.1 * e),
            "{c:?}"
        );
        balances(&c, &answer.warnings);
        let se = c.balance_se.unwrap();
        sum = std::array::from_fn(|k| sum[k] + c.balance[k]);
        var = std::array::from_fn(|k| var[k] + se[k] * se[k]);
    }
    for k in 0..3 {
        assert!(
            sum[k].abs() <= K * var[k].sqrt(),
            "channel {k}: {sum:?} ± {var:?}"
        );
    }
}

/// A lit floor (1 m², `E = 1` W/m², `rho = 0.5`) under a black panel (`rho = 0`) half its
/// size, nothing else: the floor's light escapes or dies on the panel, which reflects nothing.
/// `B = E` exactly, so the absorbed power is only what the probe sees reach the panel.
#[test]
fn light_on_a_black_patch_is_absorbed_by_the_probe() {
    let positions = vec![
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
        // the panel, facing down
        Vec3::new(0.0, 0.0, 0.5),
        Vec3::new(0.0, 0.5, 0.5),
        Vec3::new(1.0, 0.5, 0.5),
        Vec3::new(1.0, 0.0, 0.5),
    ];
    let faces = vec![
        Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        },
        Face {
            vertices: vec![4, 5, 6, 7],
            material: 1,
            source: 1,
        },
    ];
    let materials = vec![
        Material {
            name: "floor".into(),
            reflectance: Vec3::splat(0.5),
            emission: Vec3::ONE,
        },
        Material {
            name: "black".into(),
            reflectance: Vec3::ZERO,
            emission: Vec3::ZERO,
        },
    ];
    let scene = Scene::new(positions, faces, materials).unwrap().0;
    for method in [Method::Combined, Method::Prr] {
        let mut problem = Problem::new(&scene);
        problem.closure = true;
        problem.settings.method = method;
        problem.settings.seed = 3;
        problem.settings.mesh = MeshPlan::Uniform {
            max_edge: Some(0.25),
        };
        problem.budget.rays = Some(200_000);
        let answer = run(&problem);
        let c = answer.stats.closure.expect("asked for");
        assert!((c.emitted[0] - 1.0).abs() < 1e-6);
        // about a fifth of the floor's light reaches the panel
        assert!(c.absorbed[0] > 0.1 && c.escaped[0] > 0.5, "{c:?}");
        balances(&c, &answer.warnings);
    }
}

#[test]
fn a_point_lit_cornell_box_balances_and_counts_the_lights_power() {
    // The bundled Cornell box with its area light dark and a point light of the same power
    // hanging below it: the power the light delivers is estimated by the probe's own shadow
    // rays; the balance holds over seeds (it failed by hundreds of standard errors while the
    // lights' power went uncounted).
    use mcrad_scene_io::{Light, PointLight};
    let base = bundled("cornell-box.obj");
    let lamp = Light::Point(PointLight {
        position: Vec3::new(0.278, 0.5388, 0.2795),
        intensity: glam::DVec3::new(0.0185, 0.013, 0.0043),
        range: None,
    });
    let materials: Vec<Material> = base
        .materials()
        .iter()
        .map(|m| Material {
            emission: Vec3::ZERO,
            ..m.clone()
        })
        .collect();
    let scene = Scene::new_lit(
        base.positions().to_vec(),
        base.faces().to_vec(),
        materials,
        vec![lamp],
    )
    .unwrap()
    .0;
    for seed in 0..3 {
        let mut problem = Problem::new(&scene);
        problem.closure = true;
        problem.settings.seed = seed;
        problem.budget.rays = Some(400_000);
        let answer = run(&problem);
        let c = answer.stats.closure.expect("asked for");
        assert!(c.emitted[0] > 0.0, "{c:?}");
        balances(&c, &answer.warnings);
    }
}

/// The generated boxes room (a few hundred bottomless boxes on the floor, two panels hanging
/// below the ceiling) on the default adaptive mesh: its splits separate parts of elements whose
/// light ends on back faces (the floor under a box, the ceiling over a panel) from the rest.
/// The refinement's estimates, made on the coarser meshes before those splits, were pooled
/// into the answer and left it short of light: summed over four seeds the balance was +5 (`shoot`)
/// and +7 (`gather`) standard errors at 2e6 rays. The answer is the method's own solution of
/// the refined mesh, balanced. The sum over the seeds is judged at `K` standard errors.
#[test]
fn the_adaptive_boxes_room_balances_over_seeds() {
    let scene = bundled("boxes-room.obj");
    for method in [Method::Shoot, Method::Gather] {
        let (mut sum, mut var) = ([0.0; 3], [0.0; 3]);
        for seed in 0..4 {
            let mut problem = Problem::new(&scene);
            problem.closure = true;
            problem.settings.method = method;
            problem.settings.seed = seed;
            problem.budget.rays = Some(2_000_000);
            let answer = run(&problem);
            assert!(answer.stats.refinement.is_some(), "the default is adaptive");
            let c = answer.stats.closure.expect("asked for");
            let se = c.balance_se.expect("a standard error");
            sum = std::array::from_fn(|k| sum[k] + c.balance[k]);
            var = std::array::from_fn(|k| var[k] + se[k] * se[k]);
        }
        for k in 0..3 {
            assert!(
                sum[k].abs() <= K * var[k].sqrt(),
                "{method:?}, channel {k}: {sum:?} ± {:?}",
                var.map(f64::sqrt)
            );
        }
    }
}
