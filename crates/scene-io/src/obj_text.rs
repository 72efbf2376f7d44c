//! The OBJ reader's one pass over the file, and a check of MTL text before `tobj` reads it.
//!
//! `tobj` reports errors without a line, silently drops faces with fewer than 3 vertices,
//! rejects valid input (1-component `vt`, mixed vertex colours, faces referring to vertices
//! defined later in another object) and can panic on some malformed input (`Kd 0.5 0.5`). So the
//! OBJ is parsed here, with line numbers, into what the scene uses: every position (`w` divided
//! out, colours dropped) and the statements that make faces, in order (`mtllib`, `usemtl`, `o`
//! and `g`, faces as absolute 0-based position indices; texture and normal indices dropped).
//! `tobj` reads the MTL files (`crate::obj` groups the faces as `tobj` would). MTL colour
//! statements are normalised for it here, keeping the lines.

use crate::error::SceneError;
use glam::Vec3;
use std::ops::Range;

/// An error with the 1-based line it was found on.
pub(crate) type LineError = (usize, SceneError);

/// A statement of an OBJ file that makes or groups faces.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Statement {
    /// `mtllib NAME` (the rest of the line, trimmed) on line `line`.
    Mtllib {
        /// The library's file name.
        name: String,
        /// Its 1-based line.
        line: usize,
    },
    /// `usemtl NAME`.
    Usemtl(String),
    /// `o` or `g`: a new object or group.
    Group,
    /// `f`: these elements of [`ObjText::corners`].
    Face(Range<usize>),
}

/// An OBJ file checked and parsed.
pub(crate) struct ObjText {
    /// Every `v` position, in file order (`w` divided out).
    pub positions: Vec<Vec3>,
    /// The statements that make faces, in file order.
    pub statements: Vec<Statement>,
    /// The faces' corners as 0-based indices into `positions`, face after face.
    pub corners: Vec<usize>,
    /// The line of each face, in file order (index = the face's `source`).
    pub face_lines: Vec<usize>,
    /// Each `usemtl` name with the line of its first use, in file order.
    pub usemtl: Vec<(String, usize)>,
}

/// Checks and parses an OBJ file. Errors: unparsable or non-finite vertices,
/// faces with fewer than 3 vertices, unparsable or out-of-range vertex indices, `usemtl` without
/// a name.
pub(crate) fn scan_obj(text: &str) -> Result<ObjText, LineError> {
    let mut count = 0usize; // vertices defined so far
    let mut forward: Vec<(usize, i64)> = Vec::new(); // positive indices past `count`, to check
    let mut out = ObjText {
        positions: Vec::new(),
        statements: Vec::new(),
        corners: Vec::new(),
        face_lines: Vec::new(),
        usemtl: Vec::new(),
    };
    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        let statement = line.split('#').next().unwrap_or("");
        let mut words = statement.split_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        let rest = || rest_after_keyword(line, keyword);
        match keyword {
            "v" => {
                let p = parse_vertex(line, words, count + 1).map_err(|e| (line_no, e))?;
                count += 1;
                out.positions.push(p);
            }
            "f" => {
                // counted first (no list of the words per face)
                let corners = words.clone();
                let found = words.count();
                if found < 3 {
                    let message = format!(
                        "a face needs at least 3 vertices, found {found}: {}",
                        crate::quote(line.trim())
                    );
                    return Err((line_no, SceneError::parse(message)));
                }
                if found > crate::MAX_FACE_VERTICES {
                    let e = SceneError::TooManyFaceVertices { count: found };
                    return Err((line_no, e));
                }
                if out.face_lines.len() >= crate::MAX_FACES {
                    return Err((line_no, SceneError::TooManyFaces));
                }
                let start = out.corners.len();
                for corner in corners {
                    let index = parse_face_index(corner, count).map_err(|e| (line_no, e))?;
                    if index > count as i64 {
                        forward.push((line_no, index));
                    }
                    // 1-based and positive here
                    out.corners.push(index as usize - 1);
                }
                out.statements
                    .push(Statement::Face(start..out.corners.len()));
                out.face_lines.push(line_no);
            }
            "mtllib" => out.statements.push(Statement::Mtllib {
                name: rest().to_string(),
                line: line_no,
            }),
            "usemtl" => {
                let name = rest();
                if name.is_empty() {
                    return Err((line_no, SceneError::parse("usemtl needs a material name")));
                }
                if !out.usemtl.iter().any(|(n, _)| *n == name) {
                    out.usemtl.push((name.to_string(), line_no));
                }
                out.statements.push(Statement::Usemtl(name.to_string()));
            }
            "o" | "g" => out.statements.push(Statement::Group),
            // vt, vn, l, p, s and the rest carry nothing the scene uses.
            _ => {}
        }
    }
    if let Some(&(line_no, index)) = forward.iter().find(|(_, index)| *index > count as i64) {
        let e = SceneError::ObjFaceVertex {
            index,
            available: count,
        };
        return Err((line_no, e));
    }
    Ok(out)
}

/// The text after a statement's keyword, trimmed (names may contain spaces).
fn rest_after_keyword<'a>(line: &'a str, keyword: &str) -> &'a str {
    let start = line.trim_start();
    start.get(keyword.len()..).unwrap_or("").trim()
}

/// Parses the numbers of a `v` line (`number` is its 1-based OBJ vertex number): `x y z`,
/// `x y z w` or `x y z r g b`. The position must be finite.
fn parse_vertex<'a>(
    line: &str,
    numbers: impl Iterator<Item = &'a str>,
    number: usize,
) -> Result<Vec3, SceneError> {
    // the first 7 numbers on the stack (a longer line is refused by its count alone)
    let mut stack = [0f32; 7];
    let mut found = 0usize;
    for n in numbers {
        match n.parse::<f32>() {
            Ok(x) => {
                if let Some(slot) = stack.get_mut(found) {
                    *slot = x;
                }
                found += 1;
            }
            Err(_) => {
                return Err(SceneError::parse(format!(
                    "cannot parse vertex coordinate {} in {}",
                    crate::quote(n),
                    crate::quote(line.trim())
                )));
            }
        }
    }
    let [x, y, z, w, ..] = stack;
    let p = match found {
        3 | 6 => Vec3::new(x, y, z),
        4 => Vec3::new(x, y, z) / w,
        _ => {
            return Err(SceneError::parse(format!(
                "a vertex needs 3 numbers (4 with w, 6 with a colour), found {found}: {}",
                crate::quote(line.trim())
            )));
        }
    };
    if !p.is_finite() {
        return Err(SceneError::NonFinitePosition {
            vertex: number,
            position: p,
        });
    }
    if p.abs().max_element() > crate::MAX_COORDINATE {
        return Err(SceneError::CoordinateTooLarge {
            vertex: number,
            position: p,
        });
    }
    Ok(p)
}

/// Parses the position index of one face corner (`v`, `v/vt`, `v//vn` or `v/vt/vn`) as an
/// absolute 1-based index; `count` vertices are defined so far. Positive indices past `count`
/// are returned as they are (checked against the total at the end).
fn parse_face_index(corner: &str, count: usize) -> Result<i64, SceneError> {
    let v = corner.split('/').next().unwrap_or("");
    let Ok(index) = v.parse::<i64>() else {
        return Err(SceneError::parse(format!(
            "cannot parse face vertex {}",
            crate::quote(corner)
        )));
    };
    let bad = SceneError::ObjFaceVertex {
        index,
        available: count,
    };
    match index {
        0 => Err(bad),
        i if i < 0 => {
            let absolute = count as i64 + i + 1;
            if absolute < 1 { Err(bad) } else { Ok(absolute) }
        }
        i => Ok(i),
    }
}

/// An MTL file checked and normalised for `tobj`.
pub(crate) struct MtlText {
    /// The normal form (same lines as the input).
    pub text: String,
    /// The line of each `newmtl`, in file order.
    pub newmtl_lines: Vec<usize>,
}

/// Normalises the colour statements `Ka`, `Kd`, `Ks`, `Ke` of an MTL file: a single number `r`
/// means `r r r` (MTL specification); 2 numbers, none, or the `spectral` and `xyz` forms are
/// errors. Line numbers are kept.
pub(crate) fn scan_mtl(text: &str) -> Result<MtlText, LineError> {
    let mut out = MtlText {
        text: String::with_capacity(text.len()),
        newmtl_lines: Vec::new(),
    };
    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        let mut words = line.split('#').next().unwrap_or("").split_whitespace();
        match words.next() {
            Some(k @ ("Ka" | "Kd" | "Ks" | "Ke")) => {
                let numbers: Vec<&str> = words.collect();
                match numbers[..] {
                    [r] if r.parse::<f32>().is_ok() => {
                        out.text.push_str(&format!("{k} {r} {r} {r}"));
                    }
                    [form, ..] if form == "spectral" || form == "xyz" => {
                        let what = format!(
                            "{} colours (use '{k} r g b')",
                            crate::quote(&format!("{k} {form}"))
                        );
                        return Err((line_no, SceneError::Unsupported { what }));
                    }
                    [_, _, _] => out.text.push_str(line),
                    _ => {
                        let message = format!(
                            "{k} needs 3 numbers (or 1 for grey), found {}: {}",
                            numbers.len(),
                            crate::quote(line.trim())
                        );
                        return Err((line_no, SceneError::parse(message)));
                    }
                }
            }
            Some("newmtl") => {
                out.newmtl_lines.push(line_no);
                out.text.push_str(line);
            }
            _ => out.text.push_str(line),
        }
        out.text.push('\n');
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_vertices_are_all_known_and_indices_resolved() {
        let text = "# c\nmtllib a b.mtl\no x\nv 0 0 0\nv 2 0 0 2\nvt 0.5\nusemtl red\n\
                    f 1/1 2//3 -1 4\nv 0 1 0 1 0 0\nv 9 9 9\n  g  y \nf 1 2 3\n";
        let t = scan_obj(text).unwrap();
        let v = |x, y, z| Vec3::new(x, y, z);
        // `w` divided out, the colour dropped, the vertex defined after its face known
        assert_eq!(
            t.positions,
            vec![v(0., 0., 0.), v(1., 0., 0.), v(0., 1., 0.), v(9., 9., 9.)]
        );
        assert_eq!(
            t.statements,
            vec![
                Statement::Mtllib {
                    name: "a b.mtl".into(),
                    line: 2
                },
                Statement::Group,
                Statement::Usemtl("red".into()),
                Statement::Face(0..4),
                Statement::Group,
                Statement::Face(4..7),
            ]
        );
        // relative -1 is the latest vertex (2, 0-based 1); 4 is defined later
        assert_eq!(t.corners, vec![0, 1, 1, 3, 0, 1, 2]);
        assert_eq!(t.face_lines, vec![8, 12]);
        assert_eq!(t.usemtl, vec![("red".to_string(), 7)]);
    }

    fn obj_err(text: &str) -> (usize, String) {
        let (line, e) = scan_obj(text).err().unwrap();
        (line, e.to_string())
    }

    #[test]
    fn obj_errors_name_line_and_value() {
        let v3 = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        assert_eq!(
            obj_err(&format!("{v3}f 1 2 99\n")),
            (
                4,
                "face uses vertex 99 but only 3 vertices are defined in total".into()
            )
        );
        assert_eq!(
            obj_err(&format!("{v3}f -1 -2 -4\n")),
            (
                4,
                "face uses vertex -4 (relative) but only 3 vertices are defined so far".into()
            )
        );
        assert_eq!(
            obj_err(&format!("{v3}f 0 1 2\n")).1,
            "face uses vertex 0, but OBJ vertex numbers start at 1"
        );
        assert_eq!(
            obj_err(&format!("{v3}f 1 2\n")).1,
            "a face needs at least 3 vertices, found 2: 'f 1 2'"
        );
        assert_eq!(
            obj_err(&format!("{v3}f 1 x 2\n")).1,
            "cannot parse face vertex 'x'"
        );
        assert_eq!(
            obj_err("v 0 0 0\nv 1 nan 0\n"),
            (2, "vertex 2 has a non-finite coordinate (1, NaN, 0)".into())
        );
        assert_eq!(
            obj_err("v 1 1 1 0\n").1,
            "vertex 1 has a non-finite coordinate (inf, inf, inf)"
        );
        assert_eq!(
            obj_err("v 1 1\n").1,
            "a vertex needs 3 numbers (4 with w, 6 with a colour), found 2: 'v 1 1'"
        );
        assert_eq!(
            obj_err("v 1 a 1\n").1,
            "cannot parse vertex coordinate 'a' in 'v 1 a 1'"
        );
        assert_eq!(obj_err("usemtl\n").1, "usemtl needs a material name");
    }

    #[test]
    fn mtl_colours_are_normalised() {
        let t = scan_mtl("newmtl a\nKd 0.5\nKe 1 2 3 # hot\n").unwrap();
        assert_eq!(t.text, "newmtl a\nKd 0.5 0.5 0.5\nKe 1 2 3 # hot\n");
        assert_eq!(t.newmtl_lines, vec![1]);
        let (line, e) = scan_mtl("newmtl a\n\nKd 0.5 0.5\n").err().unwrap();
        assert_eq!(line, 3);
        assert_eq!(
            e.to_string(),
            "Kd needs 3 numbers (or 1 for grey), found 2: 'Kd 0.5 0.5'"
        );
        let (_, e) = scan_mtl("Kd spectral x.rfl\n").err().unwrap();
        assert!(e.to_string().contains("unsupported: 'Kd spectral' colours"));
    }
}
