//! OBJ + MTL loading through `mcrad_scene_io::load`: a valid box, the repairs, and one test per
//! kind of bad input asserting that the message names the file and the offending value.

use glam::Vec3;
use mcrad_scene_io::{Loaded, Material, SceneError, Warning, load};
use std::fs;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

const MTL: &str = "\
# materials of the test box
newmtl white
Kd 0.7 0.7 0.7
newmtl red
Kd 0.6 0.05 0.05
newmtl green
Kd 0.1 0.5 0.1
newmtl light
Kd 0.78 0.78 0.78
Ke 17 12 4
";

/// 12 vertices: the unit cube's corners, then a small light below the ceiling.
const VERTICES: &str = "\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
v 0.4 0.99 0.4
v 0.6 0.99 0.4
v 0.6 0.99 0.6
v 0.4 0.99 0.6
";

/// An open box of inward-facing quads (floor, ceiling, back, left, right) and a light, over two
/// objects and four materials.
fn box_obj() -> String {
    format!(
        "# test box\nmtllib box.mtl\n{VERTICES}o walls\nusemtl white\n\
         f 1 5 6 2\nf 4 3 7 8\nf 1 2 3 4\nusemtl red\nf 1 4 8 5\nusemtl green\nf 2 6 7 3\n\
         o light\nusemtl light\nf 9 10 11 12\n"
    )
}

/// Writes `files` (name, contents) into a new temporary directory.
fn write(files: &[(&str, &str)]) -> TempDir {
    let dir = TempDir::new().unwrap();
    for (name, text) in files {
        fs::write(dir.path().join(name), text).unwrap();
    }
    dir
}

fn load_ok(dir: &TempDir, name: &str) -> Loaded {
    match load(&dir.path().join(name)) {
        Ok(l) => l,
        Err(e) => panic!("{name} should load: {e}"),
    }
}

/// Loads `obj` (with `mtl` as box.mtl) and returns the error message.
fn load_err(obj: &str, mtl: &str) -> (String, SceneError) {
    let dir = write(&[("box.obj", obj), ("box.mtl", mtl)]);
    match load(&dir.path().join("box.obj")) {
        Ok(_) => panic!("expected an error for:\n{obj}"),
        Err(e) => (e.to_string(), e),
    }
}

fn assert_contains(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(
            message.contains(p),
            "message {message:?} should contain {p:?}"
        );
    }
}

fn obj_vertex(n: usize) -> Vec3 {
    let line = VERTICES.lines().nth(n - 1).unwrap();
    let c: Vec<f32> = line[2..]
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    Vec3::new(c[0], c[1], c[2])
}

#[test]
fn box_loads_with_quads_sources_and_materials() {
    let dir = write(&[("box.obj", &box_obj()), ("box.mtl", MTL)]);
    let Loaded {
        scene, warnings, ..
    } = load_ok(&dir, "box.obj");
    assert!(warnings.is_empty(), "{warnings:?}");

    let faces = scene.faces();
    assert_eq!(faces.len(), 6);
    assert!(
        faces.iter().all(|f| f.vertices.len() == 4),
        "quads stay quads"
    );
    let sources: Vec<u32> = faces.iter().map(|f| f.source).collect();
    assert_eq!(sources, vec![0, 1, 2, 3, 4, 5]);

    // Every face has the positions the file gives it (indices offset correctly when merging).
    let file_faces: [[usize; 4]; 6] = [
        [1, 5, 6, 2],
        [4, 3, 7, 8],
        [1, 2, 3, 4],
        [1, 4, 8, 5],
        [2, 6, 7, 3],
        [9, 10, 11, 12],
    ];
    for (face, expected) in faces.iter().zip(file_faces) {
        let got: Vec<Vec3> = face
            .vertices
            .iter()
            .map(|&v| scene.positions()[v as usize])
            .collect();
        let want: Vec<Vec3> = expected.iter().map(|&n| obj_vertex(n)).collect();
        assert_eq!(got, want, "face {}", face.source);
    }

    let material = |face: usize| &scene.materials()[faces[face].material as usize];
    let names: Vec<&str> = (0..6).map(|f| material(f).name.as_str()).collect();
    assert_eq!(names, ["white", "white", "white", "red", "green", "light"]);
    assert_eq!(material(3).reflectance, Vec3::new(0.6, 0.05, 0.05));
    assert_eq!(material(3).emission, Vec3::ZERO);
    assert_eq!(material(5).reflectance, Vec3::splat(0.78));
    assert_eq!(
        material(5).emission,
        Vec3::new(17.0, 12.0, 4.0),
        "Ke is E in W/m²"
    );

    assert!((scene.face_area(&faces[0]) - 1.0).abs() < 1e-12);
    assert_eq!(
        scene.face_normal(&faces[0]),
        Vec3::Y,
        "floor faces into the box"
    );
    assert_eq!(scene.face_normal(&faces[5]), -Vec3::Y, "light faces down");
}

#[test]
fn missing_kd_unknown_and_absent_materials_are_defaulted_with_warnings() {
    let mtl = "newmtl lamp\nKe 1 1 1\nnewmtl grey\nKd 0.25\n";
    let obj = format!(
        "mtllib box.mtl\n{VERTICES}f 1 5 6 2\nusemtl lamp\nf 9 10 11\nf -4 -3 -1\n\
         usemtl gold\nf 1 2 3 4\nusemtl grey\nf 1 4 8 5\n"
    );
    let dir = write(&[("box.obj", &obj), ("box.mtl", mtl)]);
    let Loaded {
        scene, warnings, ..
    } = load_ok(&dir, "box.obj");
    assert_eq!(
        warnings,
        vec![
            Warning::MaterialDefaulted {
                name: "lamp".into(),
                what: "no Kd; reflectance set to 0.5 grey".into()
            },
            Warning::UnknownMaterial {
                name: "gold".into(),
                line: 18
            },
            Warning::DefaultMaterial { faces: 2 },
        ]
    );
    let m = scene.materials();
    assert_eq!(m.len(), 3);
    assert_eq!(m[0].reflectance, Vec3::splat(0.5));
    assert_eq!(m[1].reflectance, Vec3::splat(0.25), "Kd r means r r r");
    assert_eq!(m[2], Material::builtin_default());
    let by_source: Vec<(u32, &str, usize)> = scene
        .faces()
        .iter()
        .map(|f| {
            let name = m[f.material as usize].name.as_str();
            (f.source, name, f.vertices.len())
        })
        .collect();
    assert_eq!(
        by_source,
        vec![
            (0, "default", 4),
            (1, "lamp", 3),
            (2, "lamp", 3),
            (3, "default", 4),
            (4, "grey", 4)
        ]
    );
    // `f -4 -3 -1` after 12 vertices is `f 9 10 12`.
    let relative: Vec<Vec3> = scene.faces()[2]
        .vertices
        .iter()
        .map(|&v| scene.positions()[v as usize])
        .collect();
    assert_eq!(
        relative,
        vec![obj_vertex(9), obj_vertex(10), obj_vertex(12)]
    );
}

#[test]
fn degenerate_face_is_dropped_and_sources_are_kept() {
    // Face 1 repeats a vertex (zero area); face 3 is three collinear points.
    let obj = format!(
        "mtllib box.mtl\n{VERTICES}usemtl white\nf 1 5 6 2\nf 1 5 5\nf 4 3 7 8\nf 1 2 2 1\n\
         usemtl light\nf 9 10 11 12\nv 2 0 0\nv 3 0 0\nusemtl white\nf 1 13 14\n"
    );
    let dir = write(&[("box.obj", &obj), ("box.mtl", MTL)]);
    let Loaded {
        scene, warnings, ..
    } = load_ok(&dir, "box.obj");
    assert_eq!(
        warnings,
        vec![Warning::DegenerateFacesDropped {
            count: 3,
            first_source: 1,
            emitters: 0
        }]
    );
    let sources: Vec<u32> = scene.faces().iter().map(|f| f.source).collect();
    assert_eq!(sources, vec![0, 2, 4]);
}

#[test]
fn concave_and_non_planar_faces_are_split_with_a_warning() {
    // Face 1: a concave outline no vertex can fan (area 5). Face 2: a bent quad.
    let obj = format!(
        "mtllib box.mtl\n{VERTICES}\
         v 0 0 2\nv 3 0 2\nv 3 3 2\nv 2 1 2\nv 1 1 2\nv 0 3 2\n\
         v 0 0 5\nv 1 0 5\nv 1 1 5.5\nv 0 1 5\n\
         usemtl light\nf 9 10 11 12\nusemtl white\nf 13 14 15 16 17 18\nf 19 20 21 22\n"
    );
    let dir = write(&[("box.obj", &obj), ("box.mtl", MTL)]);
    let Loaded {
        scene, warnings, ..
    } = load_ok(&dir, "box.obj");
    assert_eq!(
        warnings,
        vec![Warning::FacesSplit {
            count: 2,
            first_source: 1
        }]
    );
    let sources: Vec<u32> = scene.faces().iter().map(|f| f.source).collect();
    assert_eq!(sources, vec![0, 1, 1, 1, 1, 2, 2]);
    assert!(scene.faces()[1..].iter().all(|f| f.vertices.len() == 3));
    let area1: f64 = scene.faces()[1..5].iter().map(|f| scene.face_area(f)).sum();
    assert!((area1 - 5.0).abs() < 1e-9, "split keeps the area: {area1}");
}

#[test]
fn unreadable_file() {
    let dir = TempDir::new().unwrap();
    let e = load(&dir.path().join("nothere.obj")).unwrap_err();
    assert!(matches!(e, SceneError::Io { .. }));
    assert_contains(&e.to_string(), &["cannot read", "nothere.obj"]);
}

#[test]
fn missing_mtl() {
    let obj = box_obj().replace("mtllib box.mtl", "mtllib gone.mtl");
    let (m, e) = load_err(&obj, MTL);
    assert!(matches!(e, SceneError::MissingMtl { line: 2, .. }), "{e:?}");
    assert_contains(&m, &["box.obj line 2", "gone.mtl", "mtllib"]);
}

#[test]
fn face_index_out_of_range() {
    let obj = box_obj().replace("f 2 6 7 3", "f 2 6 99 3");
    let (m, _) = load_err(&obj, MTL);
    assert_contains(
        &m,
        &["box.obj line 23: face uses vertex 99 but only 12 vertices are defined in total"],
    );
    let obj = box_obj().replace("f 2 6 7 3", "f -1 -2 -13");
    let (m, _) = load_err(&obj, MTL);
    assert_contains(&m, &["box.obj line 23", "vertex -13 (relative)", "only 12"]);
}

#[test]
fn nan_coordinate() {
    let obj = box_obj().replace("v 1 1 1\n", "v 1 NaN 1\n");
    let (m, _) = load_err(&obj, MTL);
    assert_contains(
        &m,
        &["box.obj line 9: vertex 7 has a non-finite coordinate (1, NaN, 1)"],
    );
}

#[test]
fn infinite_coordinate() {
    let obj = box_obj().replace("v 0 0 1\n", "v 0 0 1e39\n");
    let (m, _) = load_err(&obj, MTL);
    assert_contains(&m, &["box.obj line 7", "vertex 5", "(0, 0, inf)"]);
}

#[test]
fn reflectance_of_one_or_more() {
    let (m, e) = load_err(
        &box_obj(),
        &MTL.replace("Kd 0.6 0.05 0.05", "Kd 1 0.05 0.05"),
    );
    assert!(matches!(e.innermost(), SceneError::BadReflectance { .. }));
    assert_contains(
        &m,
        &[
            "box.mtl line 4: material 'red' has reflectance (1, 0.05, 0.05)",
            "[0, 1)",
        ],
    );
}

#[test]
fn negative_emission() {
    let (m, _) = load_err(&box_obj(), &MTL.replace("Ke 17 12 4", "Ke -1 0 0"));
    assert_contains(
        &m,
        &["box.mtl line 8: material 'light' has negative emission (-1, 0, 0)"],
    );
}

#[test]
fn no_emitter() {
    let (m, e) = load_err(&box_obj(), &MTL.replace("Ke 17 12 4", ""));
    assert!(matches!(e.innermost(), SceneError::NoEmitter { .. }));
    assert_contains(&m, &["box.obj", "no emitting face"]);
}

#[test]
fn empty_scene() {
    let (m, e) = load_err(&format!("mtllib box.mtl\n{VERTICES}"), MTL);
    assert!(matches!(e.innermost(), SceneError::NoFaces { dropped: 0 }));
    assert_contains(&m, &["box.obj: the scene has no faces"]);
}

#[test]
fn malformed_statements_name_their_line() {
    let (m, _) = load_err(&box_obj().replace("f 1 2 3 4", "f 1 2"), MTL);
    assert_contains(&m, &["box.obj line 19", "at least 3 vertices, found 2"]);
    let (m, _) = load_err(&box_obj(), &MTL.replace("Kd 0.1 0.5 0.1", "Kd 0.1 0.5"));
    assert_contains(&m, &["box.mtl line 7", "Kd needs 3 numbers"]);
    let (m, _) = load_err(&box_obj(), &MTL.replace("Kd 0.1 0.5 0.1", "Kd 0.1 x 0.1"));
    assert_contains(&m, &["box.mtl line 7", "cannot parse 'Kd 0.1 x 0.1'"]);
}

#[test]
fn unknown_extension() {
    let e = load(Path::new("scene.ply")).unwrap_err();
    assert_contains(&e.to_string(), &["scene.ply", "unsupported scene format"]);
    let e = load(&PathBuf::from("no_extension")).unwrap_err();
    assert!(matches!(e, SceneError::UnsupportedFormat { .. }));
}

/// Must not panic: every prefix of a valid OBJ and MTL, and lines of odd statements.
#[test]
fn corrupted_files_error_without_panicking() {
    let obj = box_obj();
    let odd = [
        "f",
        "f 1//",
        "f 1/2/3/4 2 3",
        "f 999999999999999999999 1 2",
        "f -9223372036854775808 1 2",
        "v",
        "v 1 2 3 4 5",
        "v 1 2 3 0",
        "vt",
        "vt 1 2 3 4",
        "vn x",
        "usemtl",
        "mtllib",
        "o",
        "g",
        "l 1 2 99",
        "p -100",
        "s off",
        "\u{feff}v 1 2 3",
        "f 1 2 3 \\",
    ];
    let mtl_odd = [
        "Kd",
        "Ke 1",
        "Ks 1 2",
        "newmtl",
        "Ns",
        "d",
        "illum x",
        "map_Kd",
        "Kd xyz 1 2 3",
    ];
    let dir = TempDir::new().unwrap();
    let run = |obj: &str, mtl: &str| {
        fs::write(dir.path().join("box.obj"), obj).unwrap();
        fs::write(dir.path().join("box.mtl"), mtl).unwrap();
        let _ = load(&dir.path().join("box.obj"));
    };
    for n in 0..obj.len() {
        run(&obj[..n], MTL);
    }
    for n in 0..MTL.len() {
        run(&obj, &MTL[..n]);
    }
    for line in odd {
        run(&format!("{obj}{line}\n"), MTL);
    }
    for line in mtl_odd {
        run(&obj, &format!("{MTL}{line}\n"));
    }
}

#[test]
fn hostile_input_is_refused_at_its_line_with_short_escaped_quotes() {
    // a face of more corners than supported, refused before any work
    let corners = " 1 2 3".repeat(20_000);
    let (m, e) = load_err(&format!("{}f{corners}\n", box_obj()), MTL);
    assert!(
        matches!(
            e.innermost(),
            SceneError::TooManyFaceVertices { count: 60_000 }
        ),
        "{e:?}"
    );
    assert_contains(
        &m,
        &["box.obj line 27:", "60000 vertices", "triangulate it"],
    );
    // the message is complete, so the wrapped error is not also the source (said once)
    assert!(std::error::Error::source(&e).is_none());
    // coordinates beyond the limit (areas would overflow f32)
    let (m, e) = load_err(&format!("{}v 1e38 0 0\n", box_obj()), MTL);
    assert!(matches!(
        e.innermost(),
        SceneError::CoordinateTooLarge { vertex: 13, .. }
    ));
    assert_contains(&m, &["box.obj line 27: vertex 13", "(1e38, 0, 0)"]);
    // a CR and a 400 KB line are escaped and cut
    let long = "x".repeat(400_000);
    let (m, _) = load_err(&format!("{}v 1 2 {long}\r\n", box_obj()), MTL);
    assert!(m.len() < 300, "{} bytes: {m:.300}", m.len());
    assert!(!m.contains('\r') && m.contains("bytes)"), "{m}");
    let (m, _) = load_err(&format!("{}v 1 2\r\n", box_obj()), MTL);
    assert!(m.contains("'v 1 2'") && !m.contains('\r'), "{m}");
    let (m, _) = load_err(&format!("{}f 1 2 x\u{1b}[2J\n", box_obj()), MTL);
    assert!(m.contains("\\u{1b}[2J") && !m.contains('\u{1b}'), "{m}");
}

#[test]
fn a_light_dropped_as_degenerate_is_named_as_the_reason() {
    // the only light is 1e-6 across: 5e-13 m², below 1e-12 of the diagonal squared
    let obj = format!(
        "mtllib box.mtl\n{VERTICES}usemtl white\nf 1 2 3 4\nusemtl light\n\
         v 0 0.5 0\nv 1e-6 0.5 0\nv 0 0.5 1e-6\nf 13 14 15\n"
    );
    let (m, e) = load_err(&obj, MTL);
    assert!(
        matches!(
            e.innermost(),
            SceneError::NoEmitter {
                dropped_emitters: Some((1, 1)),
                ..
            }
        ),
        "{e:?}"
    );
    assert_contains(
        &m,
        &[
            "emitting face was dropped as degenerate",
            "area 5.0e-13",
            "the first is face 1",
        ],
    );
    // with another light left, the warning says light was lost
    let obj = format!("{obj}f 9 10 11 12\n");
    let dir = write(&[("box.obj", &obj), ("box.mtl", MTL)]);
    let warnings = load_ok(&dir, "box.obj").warnings;
    assert_eq!(warnings.len(), 1);
    assert!(
        warnings[0]
            .to_string()
            .contains("1 of them emitted light, which is lost")
    );
}

#[test]
fn duplicate_faces_are_dropped_once_each_and_two_sided_faces_kept() {
    let mut obj = box_obj();
    for _ in 0..1000 {
        obj.push_str("f 10 11 12 9\n"); // the light again, rotated
    }
    obj.push_str("f 12 11 10 9\n"); // its back: a two-sided light is no duplicate
    let dir = write(&[("box.obj", &obj), ("box.mtl", MTL)]);
    let Loaded {
        scene, warnings, ..
    } = load_ok(&dir, "box.obj");
    assert_eq!(scene.faces().len(), 7);
    assert_eq!(
        warnings,
        vec![Warning::DuplicateFacesDropped {
            count: 1000,
            first_source: 6
        }]
    );
    // a self-overlapping outline splits into copies of one triangle: one is kept
    let obj = format!("{}f{}\n", box_obj(), " 1 2 3".repeat(300));
    let dir = write(&[("box.obj", &obj), ("box.mtl", MTL)]);
    let loaded = load_ok(&dir, "box.obj");
    let parts = loaded
        .scene
        .faces()
        .iter()
        .filter(|f| f.source == 6)
        .count();
    assert_eq!(parts, 1, "{:?}", loaded.warnings);
}

#[test]
fn material_libraries_outside_the_folder_and_device_files_are_refused() {
    let inner = TempDir::new().unwrap();
    let scene_dir = inner.path().join("scene");
    fs::create_dir(&scene_dir).unwrap();
    fs::write(inner.path().join("box.mtl"), MTL).unwrap();
    let obj = box_obj().replace("mtllib box.mtl", "mtllib ../box.mtl");
    fs::write(scene_dir.join("box.obj"), &obj).unwrap();
    let path = scene_dir.join("box.obj");
    let e = load(&path).unwrap_err();
    assert!(
        matches!(e.innermost(), SceneError::OutsideScene { .. }),
        "{e:?}"
    );
    assert_contains(
        &e.to_string(),
        &[
            "box.obj line 2: '../box.mtl' is outside the scene's folder",
            "--allow-outside-paths",
        ],
    );
    let open = mcrad_scene_io::LoadOptions {
        allow_outside_paths: true,
        ..Default::default()
    };
    assert!(mcrad_scene_io::load_with(&path, &open).is_ok());
    for (name, why) in [
        ("/etc/passwd", "absolute path"),
        ("/dev/zero", "absolute path"),
    ] {
        let (m, _) = load_err(&box_obj().replace("box.mtl", name), MTL);
        assert_contains(&m, &["line 2", name, why]);
    }
    #[cfg(unix)]
    {
        let dir = write(&[("box.obj", &box_obj().replace("box.mtl", "/dev/zero"))]);
        let e = mcrad_scene_io::load_with(&dir.path().join("box.obj"), &open).unwrap_err();
        assert!(
            matches!(e.innermost(), SceneError::NotAFile { .. }),
            "{e:?}"
        );
        assert_contains(
            &e.to_string(),
            &["box.obj line 2: /dev/zero is not a regular file"],
        );
    }
}
