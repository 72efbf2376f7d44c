//! The OBJ reader's one pass over the file (in parallel over line-aligned chunks, stitched in
//! order: [`scan_obj_parallel`]), and a check of MTL text before `tobj` reads it.
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
use rayon::prelude::*;
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
#[derive(Debug, PartialEq)]
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

/// The text of a chunk parsed in parallel by [`scan_obj_parallel`]: at least this many bytes
/// (then to the end of the line). Fixed, so the chunks do not depend on the thread count.
const CHUNK_BYTES: usize = 1 << 20;

/// [`scan_obj`] in parallel: the text is cut into line-aligned chunks of about
/// [`CHUNK_BYTES`], parsed in parallel, then stitched in order (vertex numbers, relative
/// indices and line numbers offset by the chunks before). The result is [`scan_obj`]'s, the
/// same for any thread count: where a chunk finds something wrong, or the stitched whole breaks
/// a rule that needs the whole file (a relative index reaching before the first vertex, an
/// index past the last, too many faces), the text is parsed again by [`scan_obj`], which finds
/// the first error with its line and message.
pub(crate) fn scan_obj_parallel(text: &str) -> Result<ObjText, LineError> {
    scan_obj_chunked(text, CHUNK_BYTES)
}

/// [`scan_obj_parallel`] with chunks of at least `chunk_bytes` bytes.
fn scan_obj_chunked(text: &str, chunk_bytes: usize) -> Result<ObjText, LineError> {
    let chunks: Vec<&str> = line_chunks(text, chunk_bytes.max(1));
    let parsed: Option<Vec<Chunk>> = chunks.into_par_iter().map(scan_chunk).collect();
    match parsed.and_then(stitch) {
        Some(obj) => Ok(obj),
        None => scan_obj(text),
    }
}

/// `text` cut into pieces of at least `chunk_bytes` bytes that end just after a newline (the
/// last at the end of the text); at least one piece.
fn line_chunks(text: &str, chunk_bytes: usize) -> Vec<&str> {
    let bytes = text.as_bytes();
    let mut chunks = Vec::with_capacity(text.len() / chunk_bytes + 1);
    let mut start = 0usize;
    loop {
        let at = start.saturating_add(chunk_bytes);
        let end = match bytes
            .get(at..)
            .and_then(|b| b.iter().position(|&c| c == b'\n'))
        {
            Some(newline) => at + newline + 1,
            None => bytes.len(),
        };
        // (after a newline or at the end: a character boundary)
        chunks.push(text.get(start..end).unwrap_or(""));
        if end >= bytes.len() {
            return chunks;
        }
        start = end;
    }
}

/// A chunk of an OBJ file parsed on its own: as [`ObjText`], but with line numbers counted
/// from the chunk's first line and vertices from its first vertex.
struct Chunk {
    /// Its `v` positions.
    positions: Vec<Vec3>,
    /// Its statements; face ranges index [`Chunk::corners`], `mtllib` lines are the chunk's.
    statements: Vec<Statement>,
    /// Its faces' corners as 0-based indices into the file's positions, except those listed in
    /// [`Chunk::relative`].
    corners: Vec<usize>,
    /// The corners with relative (negative) indices: the corner's place in
    /// [`Chunk::corners`] and its 1-based vertex number counted from the chunk's first vertex
    /// (`<= 0` for vertices of earlier chunks).
    relative: Vec<(usize, i64)>,
    /// The chunk's line of each face.
    face_lines: Vec<usize>,
    /// Each `usemtl` name with the chunk's line of its first use in the chunk.
    usemtl: Vec<(String, usize)>,
    /// The largest positive vertex index used (0 if none).
    max_index: i64,
    /// Its lines (all ending in a newline, but the last chunk's last one may not).
    lines: usize,
}

/// Parses one chunk; `None` if any statement in it is wrong (the serial parse then finds the
/// error).
fn scan_chunk(text: &str) -> Option<Chunk> {
    let mut out = Chunk {
        positions: Vec::new(),
        statements: Vec::new(),
        corners: Vec::new(),
        relative: Vec::new(),
        face_lines: Vec::new(),
        usemtl: Vec::new(),
        max_index: 0,
        lines: 0,
    };
    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        out.lines = line_no;
        let statement = line.split('#').next().unwrap_or("");
        let mut words = statement.split_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        let rest = || rest_after_keyword(line, keyword);
        match keyword {
            "v" => {
                // (the vertex number only shows in an error, which the serial parse reports)
                let p = parse_vertex(line, words, 0).ok()?;
                out.positions.push(p);
            }
            "f" => {
                let corners = words.clone();
                let found = words.count();
                if !(3..=crate::MAX_FACE_VERTICES).contains(&found) {
                    return None;
                }
                let start = out.corners.len();
                for corner in corners {
                    let v = corner.split('/').next().unwrap_or("");
                    let index = v.parse::<i64>().ok()?;
                    match index {
                        0 => return None,
                        i if i < 0 => {
                            let local = out.positions.len() as i64 + i + 1;
                            out.relative.push((out.corners.len(), local));
                            out.corners.push(0);
                        }
                        i => {
                            out.max_index = out.max_index.max(i);
                            out.corners.push(usize::try_from(i - 1).ok()?);
                        }
                    }
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
                    return None;
                }
                if !out.usemtl.iter().any(|(n, _)| *n == name) {
                    out.usemtl.push((name.to_string(), line_no));
                }
                out.statements.push(Statement::Usemtl(name.to_string()));
            }
            "o" | "g" => out.statements.push(Statement::Group),
            _ => {}
        }
    }
    Some(out)
}

/// The chunks joined in order into the file's [`ObjText`]; `None` if the whole breaks a rule
/// the chunks alone could not check.
fn stitch(chunks: Vec<Chunk>) -> Option<ObjText> {
    let total = |f: fn(&Chunk) -> usize| chunks.iter().map(f).sum::<usize>();
    let vertices = total(|c| c.positions.len());
    let faces = total(|c| c.face_lines.len());
    if faces > crate::MAX_FACES {
        return None;
    }
    if chunks.iter().any(|c| c.max_index > vertices as i64) {
        return None;
    }
    let mut out = ObjText {
        positions: Vec::with_capacity(vertices),
        statements: Vec::with_capacity(total(|c| c.statements.len())),
        corners: Vec::with_capacity(total(|c| c.corners.len())),
        face_lines: Vec::with_capacity(faces),
        usemtl: Vec::new(),
    };
    let mut lines = 0usize;
    for chunk in chunks {
        let first_vertex = out.positions.len();
        let first_corner = out.corners.len();
        out.positions.extend_from_slice(&chunk.positions);
        out.corners.extend_from_slice(&chunk.corners);
        for &(at, local) in &chunk.relative {
            let absolute = first_vertex as i64 + local;
            if absolute < 1 {
                return None;
            }
            out.corners[first_corner + at] = absolute as usize - 1;
        }
        out.statements
            .extend(chunk.statements.into_iter().map(|s| match s {
                Statement::Face(r) => Statement::Face(r.start + first_corner..r.end + first_corner),
                Statement::Mtllib { name, line } => Statement::Mtllib {
                    name,
                    line: line + lines,
                },
                other => other,
            }));
        out.face_lines
            .extend(chunk.face_lines.iter().map(|l| l + lines));
        for (name, line) in chunk.usemtl {
            if !out.usemtl.iter().any(|(n, _)| *n == name) {
                out.usemtl.push((name, line + lines));
            }
        }
        lines += chunk.lines;
    }
    Some(out)
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

    /// A random OBJ text of `lines` lines (seeded): vertices (with `w`, with colours), faces
    /// of 3 to 5 corners in every index form (absolute, relative, forward, some past the end),
    /// names, comments, blank lines, CRLF endings; with `error`, one line replaced by a
    /// malformed statement.
    fn random_obj(seed: u64, lines: usize, error: bool) -> String {
        use rand_core::Rng as _;
        let mut stream = rand_pcg::Pcg32::new(seed, 0x0a02_bdbf_7bb3_c0a7);
        let mut pick = |n: u64| stream.next_u64() % n.max(1);
        let bad = [
            "f 1 2",
            "f 1 x 2",
            "f 0 1 2",
            "f -100000 1 2",
            "f 1 2 100000",
            "v 1 nan 0",
            "v 1 1",
            "v 1 a 1",
            "v 1 1 1 0",
            "v 2e38 2e38 2e38 0.5",
            "usemtl",
            "usemtl   # nothing",
        ];
        let error_line = error.then(|| pick(lines as u64) as usize);
        let mut count = 0u64;
        let mut text = String::new();
        for l in 0..lines {
            let line = if Some(l) == error_line {
                bad[pick(bad.len() as u64) as usize].to_string()
            } else {
                match pick(20) {
                    0..=6 => {
                        count += 1;
                        let (x, y, z) = (pick(9), pick(9) as f64 / 4.0, pick(9));
                        match pick(4) {
                            0 => format!("v {x} {y} {z} 2"),
                            1 => format!("v {x} {y} {z} 0.1 0.2 0.3"),
                            _ => format!("v  {x}\t{y} {z}"),
                        }
                    }
                    7..=12 => {
                        let corners = (0..3 + pick(3))
                            .map(|_| {
                                // relative; absolute; forward (rarely past the end)
                                let i = match pick(6) {
                                    0 | 1 if count > 0 => -(1 + pick(count) as i64),
                                    0 => 1 + pick(count + 3) as i64,
                                    _ => 1 + pick(count.max(1)) as i64,
                                };
                                match pick(4) {
                                    0 => format!("{i}/1"),
                                    1 => format!("{i}//2"),
                                    2 => format!("{i}/3/4"),
                                    _ => format!("{i}"),
                                }
                            })
                            .collect::<Vec<_>>();
                        format!("f {}", corners.join(" "))
                    }
                    13 => "vt 0.5 0.5".into(),
                    14 => "# f 1 2".into(),
                    15 => String::new(),
                    16 => format!("usemtl m{} # x", pick(4)),
                    17 => format!("{} part {}", ["g", "o"][pick(2) as usize], pick(5)),
                    18 => format!("mtllib lib{}.mtl", pick(3)),
                    _ => "s 1".into(),
                }
            };
            text.push_str(&line);
            text.push_str(if pick(5) == 0 { "\r\n" } else { "\n" });
        }
        if pick(2) == 0 {
            text.pop(); // no newline at the end
        }
        text
    }

    fn outcome(r: Result<ObjText, LineError>) -> Result<ObjText, (usize, String)> {
        r.map_err(|(line, e)| (line, e.to_string()))
    }

    #[test]
    fn chunks_are_line_aligned_and_cover_the_text() {
        for text in ["", "v 1 2 3", "v 1 2 3\n", "a\r\nbb\n\nccc\n d"] {
            for size in [1, 2, 3, 100] {
                let chunks = line_chunks(text, size);
                assert_eq!(chunks.concat(), text);
                let (last, rest) = chunks.split_last().unwrap();
                assert!(rest.iter().all(|c| c.ends_with('\n') && c.len() >= size));
                assert!(!last.is_empty() || text.is_empty());
            }
        }
        assert_eq!(line_chunks("ab\ncd\nef\n", 1), ["ab\n", "cd\n", "ef\n"]);
        assert_eq!(line_chunks("ab\ncd\nef", 4), ["ab\ncd\n", "ef"]);
    }

    #[test]
    fn parallel_parse_is_the_serial_one() {
        let (mut parsed, mut failed) = (0, 0);
        for seed in 0..300 {
            let text = random_obj(seed, 60 + seed as usize % 200, seed % 3 == 2);
            let serial = outcome(scan_obj(&text));
            for size in [1, 7, 40, 256, CHUNK_BYTES] {
                let chunked = outcome(scan_obj_chunked(&text, size));
                assert_eq!(chunked, serial, "seed {seed}, chunks of {size}:\n{text}");
            }
            // the chunks' own path (no fallback) where the serial parse succeeds
            let own = line_chunks(&text, 7)
                .into_iter()
                .map(scan_chunk)
                .collect::<Option<Vec<_>>>()
                .and_then(stitch);
            match &serial {
                Ok(obj) => {
                    assert_eq!(own.as_ref(), Some(obj), "seed {seed}");
                    parsed += 1;
                }
                Err(_) => {
                    assert!(
                        own.is_none(),
                        "seed {seed}: parallel parse missed the error"
                    );
                    failed += 1;
                }
            }
        }
        // both paths are exercised, with many chunks
        assert!(
            parsed > 50 && failed > 50,
            "{parsed} parsed, {failed} failed"
        );
    }

    #[test]
    fn errors_in_later_chunks_keep_their_line_and_vertex_number() {
        let mut text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".repeat(50);
        text.push_str("f -1 -2 -201\n");
        let (line, e) = scan_obj_chunked(&text, 10).err().unwrap();
        assert_eq!(line, 201);
        assert_eq!(
            e.to_string(),
            "face uses vertex -201 (relative) but only 150 vertices are defined so far"
        );
        // a relative index reaching back over many chunks is fine
        let ok = format!("{}f -150 -1 -75\n", text.trim_end_matches("f -1 -2 -201\n"));
        let obj = scan_obj_chunked(&ok, 10).unwrap();
        assert_eq!(obj.corners[obj.corners.len() - 3..], [0, 149, 75]);
        assert_eq!(*obj.face_lines.last().unwrap(), 201);
        let (line, e) = scan_obj_chunked(&format!("{ok}v 1 inf 0\n"), 10)
            .err()
            .unwrap();
        assert_eq!(
            (line, e.to_string()),
            (
                202,
                "vertex 151 has a non-finite coordinate (1, inf, 0)".into()
            )
        );
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
