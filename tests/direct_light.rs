//! The lights' direct light drawn per pixel sample in renders (the default with punctual lights
//! or a sun), against `--no-direct-rays` (the solution's per-vertex interpolation).

use mcrad_render::{parse_camera, read_exr};
use std::path::Path;
use std::process::{Command, Output};

fn mcrad(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("mcrad runs")
}

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).to_string_lossy().into_owned()
}

/// A 10 m floor (reflectance 0.5) and a black wall 1 m high along `x = 0`; a delta sun at 45
/// degrees elevation from `-x`, 1000 W/m². Nothing reflects onto the floor (the wall is black,
/// the floor flat), so the exact radiance is `rho E sin(45°) / pi = 112.54 W/(m² sr)` where the
/// sun reaches the floor and 0 in the wall's shadow, `0 < x < 1`.
const FLOOR_WALL_OBJ: &str = "mtllib s.mtl
v -4.7 0 -5
v -4.7 0 5
v 5.3 0 5
v 5.3 0 -5
v 0 0 -5
v 0 0 5
v 0 1 5
v 0 1 -5
usemtl floor
f 1 2 3 4
usemtl wall
f 5 6 7 8
";

const FLOOR_WALL_MTL: &str = "newmtl floor\nKd 0.5 0.5 0.5\nnewmtl wall\nKd 0 0 0\n";

const CAMERA: &str = "eye=1,3,1.5,look=1,0,0,fov=40";
const SIZE: u32 = 96;

/// The floor's `x` seen through pixel `(px, py)`'s centre (the camera's ray met with `y = 0`).
fn floor_x(px: u32, py: u32) -> Option<f32> {
    let camera = parse_camera(CAMERA).unwrap();
    let ray = camera.ray(
        glam::Vec2::new(px as f32 + 0.5, py as f32 + 0.5),
        SIZE,
        SIZE,
    );
    (ray.dir.y < 0.0).then(|| ray.origin.x + ray.dir.x * (-ray.origin.y / ray.dir.y))
}

/// Runs `mcrad` with `args` and `--image image` (an EXR), and reads the image back.
fn rendered(args: &[&str], image: &str) -> mcrad_render::Image {
    let o = mcrad(&[args, &["--image", image]].concat());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    read_exr(Path::new(image)).unwrap()
}

/// Writes the floor and wall's OBJ and MTL into `dir`; the OBJ's path.
fn floor_wall_scene(dir: &Path) -> String {
    std::fs::write(dir.join("s.obj"), FLOOR_WALL_OBJ).unwrap();
    std::fs::write(dir.join("s.mtl"), FLOOR_WALL_MTL).unwrap();
    path(dir, "s.obj")
}

/// The floor and wall solved (`--rays 2e5`, uniform 0.5 m patches) and rendered at `size`²
/// pixels through `camera`, lit as `args` say (with any other options).
fn floor_wall_image(camera: &str, size: u32, args: &[&str]) -> mcrad_render::Image {
    let dir = tempfile::tempdir().unwrap();
    let scene = floor_wall_scene(dir.path());
    let size = format!("{size}x{size}");
    let mut all = vec![
        "solve",
        &*scene,
        "-q",
        "--rays",
        "2e5",
        "--mesh",
        "uniform",
        "--max-edge",
        "0.5",
        "--camera",
        camera,
        "--size",
        &*size,
    ];
    all.extend_from_slice(args);
    rendered(&all, &path(dir.path(), "i.exr"))
}

/// Renders the floor and wall under the sun (uniform 0.5 m patches, their edges off the shadow's
/// edge at `x = 1`) and returns, for the pixels whose centre sees the floor within 3 to 12 cm
/// of the shadow's edge (a pixel spans about 3 cm there), `(x, radiance, exact)`.
fn edge_pixels(extra: &[&str]) -> Vec<(f32, f32, f32)> {
    let picture = floor_wall_image(CAMERA, SIZE, &[&["--sun=-1,1,0,1000,0"], extra].concat());
    let lit = (0.5 * 1000.0 * std::f64::consts::FRAC_1_SQRT_2 / std::f64::consts::PI) as f32;
    let mut out = Vec::new();
    for py in 0..SIZE {
        for px in 0..SIZE {
            let Some(x) = floor_x(px, py) else { continue };
            let d = (x - 1.0).abs();
            if (0.03..0.12).contains(&d) {
                let exact = if x > 1.0 { lit } else { 0.0 };
                out.push((x, picture.get(px, py).unwrap().y, exact));
            }
        }
    }
    out
}

/// With the direct light drawn per pixel (the default), every pixel 3 to 12 cm from the
/// shadow's edge is within 1% of the lit radiance (exact: a delta sun, no indirect light) on
/// the lit side and black on the other; the solution's interpolation (`--no-direct-rays`)
/// smears the edge over its 0.5 m patches and misses by more than 20% on some of them.
#[test]
fn a_sun_shadow_edge_is_sharp_in_renders() {
    let lit = (0.5 * 1000.0 * std::f64::consts::FRAC_1_SQRT_2 / std::f64::consts::PI) as f32;
    let sharp = edge_pixels(&[]);
    assert!(sharp.len() > 100, "{} pixels near the edge", sharp.len());
    for &(x, l, exact) in &sharp {
        assert!((l - exact).abs() <= 0.01 * lit, "x = {x}: {l} vs {exact}");
    }
    let smeared = edge_pixels(&["--no-direct-rays"]);
    let worst = smeared
        .iter()
        .map(|&(_, l, exact)| (l - exact).abs() / lit)
        .fold(0.0, f32::max);
    assert!(
        worst > 0.2,
        "the interpolated edge is off by {worst} at most"
    );
}

/// A scene lit by emitting faces only (the Cornell box): the per-pixel direct light changes
/// nothing, the picture is the same bit for bit with and without `--no-direct-rays`.
#[test]
fn emitting_faces_render_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let render = |name: &str, extra: &[&str]| {
        let mut args = vec![
            "solve",
            "scenes/cornell-box.obj",
            "-q",
            "--rays",
            "1e5",
            "--size",
            "48x48",
        ];
        args.extend_from_slice(extra);
        rendered(&args, &path(dir.path(), name))
    };
    let with = render("a.exr", &["--gather-rays", "0"]);
    let without = render("b.exr", &["--no-direct-rays"]);
    assert_eq!(with.pixels, without.pixels);
}

/// The floor and wall baked under the sun: the lightmap holds the incident irradiance `H`,
/// `E sin(45°) = 707.1 W/m²` where the sun reaches a texel's point (the black wall's front
/// too: the solution says nothing of a black surface's light, so only the direct light shows
/// there) and 0 in the shadow, nothing else since no light is reflected onto the floor. With
/// the direct light per texel (the default) every texel is one or the other within 0.1%
/// (but for the padding's averages where the edge meets a chart's border); interpolated
/// (`--no-direct-rays`) the texels along the shadow's edge take values between.
#[test]
fn a_sun_shadow_edge_is_sharp_in_bakes() {
    let texels = |extra: &[&str]| -> Vec<f32> {
        let dir = tempfile::tempdir().unwrap();
        let scene = floor_wall_scene(dir.path());
        let out = path(dir.path(), "o.glb");
        let mut args = vec![
            "bake",
            &*scene,
            "--out",
            &out,
            "--texel",
            "0.05",
            "-q",
            "--rays",
            "2e5",
            "--mesh",
            "uniform",
            "--max-edge",
            "0.5",
            "--sun=-1,1,0,1000,0",
        ]
        .into_iter()
        .map(str::to_string)
        .collect::<Vec<_>>();
        args.extend(extra.iter().map(|s| s.to_string()));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = mcrad(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let exr = read_exr(&dir.path().join("o.lightmap.exr")).unwrap();
        exr.pixels.iter().map(|h| h.y).collect()
    };
    let lit = (1000.0 * std::f64::consts::FRAC_1_SQRT_2) as f32;
    let between = |h: &[f32]| {
        h.iter()
            .filter(|&&h| h > 1e-3 * lit && (h - lit).abs() > 1e-3 * lit)
            .count()
    };
    let sharp = texels(&[]);
    let lit_texels = sharp
        .iter()
        .filter(|&&h| (h - lit).abs() <= 1e-3 * lit)
        .count();
    // 100 m² of floor less 10 of shadow, and 10 m² of wall, at 0.05 m a texel
    assert!(lit_texels > 40_000, "{lit_texels} lit texels");
    // only padding texels where the shadow's edge meets a chart's border: the dilation
    // averages lit and dark neighbours there (28 of them)
    assert!(between(&sharp) <= 40, "{} texels between", between(&sharp));
    let smeared = texels(&["--no-direct-rays"]);
    assert!(
        between(&smeared) > 1000,
        "{} texels between",
        between(&smeared)
    );
}

/// The fraction of the sky a floor point `(x, 0, z)` sees past the wall `x = 0`, `-5 <= z <= 5`,
/// `0 <= y <= 1` of [`FLOOR_WALL_OBJ`]: 1 less the wall's view factor from an upward
/// differential area, by Lambert's contour formula `F = (1 / 2 pi) sum_k beta_k (n · g_k)` over
/// the wall's edges (`beta_k` the angle an edge subtends, `g_k` the unit normal of the plane
/// through the point and the edge).
fn sky_fraction(x: f64, z: f64) -> f64 {
    use glam::DVec3;
    let corners = [
        DVec3::new(0.0, 0.0, -5.0),
        DVec3::new(0.0, 0.0, 5.0),
        DVec3::new(0.0, 1.0, 5.0),
        DVec3::new(0.0, 1.0, -5.0),
    ];
    let p = DVec3::new(x, 0.0, z);
    let mut f = 0.0;
    for k in 0..4 {
        let (a, b) = (corners[k] - p, corners[(k + 1) % 4] - p);
        let g = a.cross(b);
        if g.length() > 0.0 {
            f += a.angle_between(b) * g.normalize().y;
        }
    }
    1.0 - (f / (2.0 * std::f64::consts::PI)).abs()
}

/// A uniform sky (radiance 10 W/(m² sr)) over the floor and black wall: nothing reflects onto
/// the floor, so a floor point's exact radiance is `rho L s(x)`, `s` the sky fraction it sees
/// past the wall ([`sky_fraction`]: 0.52 at the wall's foot, 0.65 at 30 cm). The camera looks
/// down at the wall's foot; the pixels whose centre sees the floor 2 to 40 cm from the wall,
/// in bands of 2 cm, are scored (each pixel's value against the exact one at its centre's
/// point, its footprint about 1 cm). With the sky's direct light drawn per pixel
/// (`--sky-rays 16`: 256 stratified cosine rays a pixel) each band's mean is within 4 standard errors of the pixels'
/// spread (or 1%) of the exact value, and no pixel is more than 20% off; interpolated from the
/// mesh's 0.5 m patches (the default, as every render was before), the bands nearest
/// the wall are more than 5% too bright.
#[test]
fn the_sky_at_a_contact_line_is_exact_per_pixel_in_renders() {
    const CAMERA: &str = "eye=0.25,1.5,-0.3,look=0.25,0,0,fov=30";
    const SIZE: u32 = 64;
    let render = |extra: &[&str]| -> Vec<(f64, f64)> {
        let picture = floor_wall_image(CAMERA, SIZE, &[&["--sky", "10,10,10"], extra].concat());
        let camera = parse_camera(CAMERA).unwrap();
        let mut out = Vec::new();
        for py in 0..SIZE {
            for px in 0..SIZE {
                let pixel = glam::Vec2::new(px as f32 + 0.5, py as f32 + 0.5);
                let ray = camera.ray(pixel, SIZE, SIZE);
                let t = -ray.origin.y / ray.dir.y;
                let (x, z) = (ray.origin.x + ray.dir.x * t, ray.origin.z + ray.dir.z * t);
                if (0.02..0.4).contains(&x) {
                    let exact = 0.5 * 10.0 * sky_fraction(f64::from(x), f64::from(z));
                    let l = f64::from(picture.get(px, py).unwrap().y);
                    out.push((f64::from(x), l / exact));
                }
            }
        }
        out
    };
    // per band of 2 cm: (mean ratio, its standard error, pixels)
    let bands = |pixels: &[(f64, f64)]| -> Vec<(f64, f64, usize)> {
        (1..20)
            .map(|b| {
                let r: Vec<f64> = pixels
                    .iter()
                    .filter(|(x, _)| (*x / 0.02).floor() as i32 == b)
                    .map(|&(_, r)| r)
                    .collect();
                let n = r.len() as f64;
                let mean = r.iter().sum::<f64>() / n;
                let var = r.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
                (mean, (var / n).sqrt(), r.len())
            })
            .collect()
    };
    // the sky drawn per pixel, and a final gather (which reads the sky where its rays leave
    // and the black wall's nothing where they land)
    for drawn_by in [["--sky-rays", "16"], ["--gather-rays", "16"]] {
        let drawn = render(&drawn_by);
        assert!(drawn.len() > 1500, "{} pixels", drawn.len());
        for &(x, r) in &drawn {
            assert!(
                (r - 1.0).abs() < 0.2,
                "{drawn_by:?}: x = {x}: {r} of the exact radiance"
            );
        }
        for (b, &(mean, se, n)) in bands(&drawn).iter().enumerate() {
            assert!(n > 50, "band {b}: {n} pixels");
            assert!(
                (mean - 1.0).abs() <= (4.0 * se).max(0.01),
                "{drawn_by:?}: band {b}: mean {mean} ± {se} of the exact radiance"
            );
        }
    }
    let interpolated = bands(&render(&["--gather-rays", "0"]));
    let (near, _, _) = interpolated[0];
    assert!(
        near > 1.05,
        "the interpolated band next to the wall: {near}"
    );
}

/// The floor and wall under the sky and the sun, rendered on 1 and on 2 threads: the per-pixel
/// sky rays come from streams keyed by the pixel, so the pictures are the same bit for bit; and
/// without a sky, `--sky-rays` changes nothing (the sun's picture is the same with 0 and 16).
#[test]
fn the_sky_per_pixel_is_the_same_on_any_thread_count_and_absent_without_a_sky() {
    let dir = tempfile::tempdir().unwrap();
    let scene = floor_wall_scene(dir.path());
    let render = |name: &str, extra: &[&str]| {
        let mut args = vec![
            "solve", &*scene, "-q", "--rays", "5e4", "--size", "32x32", "--camera", CAMERA,
        ];
        args.extend_from_slice(extra);
        rendered(&args, &path(dir.path(), name)).pixels
    };
    let sky = ["--sky", "10,10,10", "--sun=-1,1,0,1000", "--sky-rays", "4"];
    let one = render("1.exr", &[&sky[..], &["--threads", "1"]].concat());
    let two = render("2.exr", &[&sky[..], &["--threads", "2"]].concat());
    assert_eq!(one, two);
    let none = render("n.exr", &["--sun=-1,1,0,1000", "--sky-rays", "0"]);
    let many = render("m.exr", &["--sun=-1,1,0,1000", "--sky-rays", "16"]);
    assert_eq!(none, many);
    // and with the sky, the rays do change the picture
    let zero = render("z.exr", &["--sky", "10,10,10", "--sun=-1,1,0,1000"]);
    assert_ne!(one, zero);
}

/// `--gather-rays auto` under a ray budget: half the solve's rays spread over the image's
/// samples, at most 1024 a pixel, and none when a pixel would get fewer than 512 (the run's
/// statistics say what was used); a count given is used as it is.
#[test]
fn the_final_gather_by_default_gathers_what_the_rays_afford() {
    let dir = tempfile::tempdir().unwrap();
    let scene = floor_wall_scene(dir.path());
    let gathered = |size: &str, extra: &[&str]| -> u64 {
        let (image, stats) = (path(dir.path(), "g.exr"), path(dir.path(), "g.json"));
        let mut args = vec![
            "solve", &*scene, "-q", "--rays", "2e5", "--camera", CAMERA, "--size", size, "--sky",
            "10,10,10", "--image", &*image, "--stats", &*stats,
        ];
        args.extend_from_slice(extra);
        let o = mcrad(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
        json["gather_rays"].as_u64().unwrap()
    };
    // 2e5 rays over 8 x 8 pixels of 16 samples: 1e5 / 1024 = 97 a sample, 1024 a pixel at most
    assert_eq!(gathered("8x8", &[]), 64);
    // over 32 x 32: 6 a sample, 96 a pixel: too few, none
    assert_eq!(gathered("32x32", &[]), 0);
    // with 256 samples a pixel over 16 x 16: 1e5 / 65536 = 1.5, 1 a sample, 256 a pixel: none;
    // over 8 x 8: 6 a sample, 4 at most
    assert_eq!(gathered("16x16", &["--spp", "256"]), 0);
    assert_eq!(gathered("8x8", &["--spp", "256"]), 4);
    // as given
    assert_eq!(gathered("32x32", &["--gather-rays", "3"]), 3);
    assert_eq!(gathered("8x8", &["--gather-rays", "0"]), 0);
    // the solution's own direct light: auto does not gather, a count is refused
    assert_eq!(gathered("8x8", &["--no-direct-rays"]), 0);
    let o = mcrad(&[
        "solve",
        &*scene,
        "-q",
        "--rays",
        "1e4",
        "--no-direct-rays",
        "--gather-rays",
        "4",
        "--image",
        &*path(dir.path(), "x.exr"),
    ]);
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("--no-direct-rays"), "{stderr}");
}

/// A final gather changes the picture only: the GLB's vertex radiosity (the solution's, with
/// the sun's direct light in it) is the same byte for byte with and without it.
#[test]
fn a_final_gather_leaves_the_glb_as_it_was() {
    let dir = tempfile::tempdir().unwrap();
    let scene = floor_wall_scene(dir.path());
    let glb = |name: &str, gather: &str| {
        let out = path(dir.path(), name);
        let o = mcrad(&[
            "solve",
            &*scene,
            "-q",
            "--rays",
            "5e4",
            "--size",
            "16x16",
            "--camera",
            CAMERA,
            "--sun=-1,1,0,1000,0",
            "--sky",
            "10,10,10",
            "--image",
            &*path(dir.path(), "i.exr"),
            "--gltf",
            &*out,
            "--gather-rays",
            gather,
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(&out).unwrap()
    };
    assert_eq!(glb("a.glb", "0"), glb("b.glb", "4"));
}
