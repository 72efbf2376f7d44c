//! Which files a scene may read and how much of them: the [`LoadOptions`] policy.
//!
//! A scene file names other files (OBJ `mtllib`, glTF buffer URIs). Read blindly, a hostile or
//! broken scene could make the loader read `/etc/passwd`, `/proc/self/status` or `/dev/zero`
//! (forever). So every file is opened here: it must be a regular file (no device, pipe or
//! directory), at most [`LoadOptions::max_file_bytes`] long (checked before and while reading:
//! `/proc` files claim a size of 0), and a file the scene names must lie inside the scene file's
//! folder unless [`LoadOptions::allow_outside_paths`] is set.

use crate::error::SceneError;
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// The default of [`LoadOptions::max_file_bytes`]: 1 GiB, per file.
pub const DEFAULT_MAX_FILE_BYTES: u64 = 1 << 30;

/// How [`load_with`](crate::load_with) reads a scene. The default is the safe policy:
/// named files inside the scene's folder only, at most [`DEFAULT_MAX_FILE_BYTES`] each.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadOptions {
    /// Read files the scene names (OBJ `mtllib`, glTF buffer URIs) even when they lie outside
    /// the folder of the scene file: absolute paths, `file:` URIs, `..` that climbs out of
    /// it, or a symbolic link that leads out of it. Off by default: such a name is refused
    /// with [`SceneError::OutsideScene`].
    pub allow_outside_paths: bool,
    /// The largest file read, in bytes: the scene file, each MTL file and each glTF buffer
    /// ([`SceneError::FileTooLarge`] beyond).
    pub max_file_bytes: u64,
    /// Lights added to the scene's own (a sun the caller sets), in the scene's frame and
    /// radiometric units; none by default.
    pub lights: Vec<crate::Light>,
    /// The sky ([`Sky`](crate::Sky): radiance from the directions in which rays leave the
    /// scene); none by default.
    pub sky: Option<crate::Sky>,
    /// The luminous efficacy `K` (lm/W) that converts glTF lights' photometric intensities
    /// to radiometric ones: a point or spot light of `I` cd radiates `I / K` W/sr, a
    /// directional light of `E_v` lux gives `E_v / K` W/m². Default
    /// [`DEFAULT_LIGHT_EFFICACY`](crate::DEFAULT_LIGHT_EFFICACY) (683, Blender's exporter's
    /// factor); 1 reads the intensities as radiometric. Must be positive and finite.
    pub light_efficacy: f64,
    /// Make every face of an OBJ scene two-sided ([`Scene::with_two_sided`](crate::Scene::with_two_sided)).
    /// Off by default. glTF scenes ignore it: each material's `doubleSided` decides.
    pub two_sided: bool,
}

impl Default for LoadOptions {
    fn default() -> LoadOptions {
        LoadOptions {
            allow_outside_paths: false,
            max_file_bytes: DEFAULT_MAX_FILE_BYTES,
            lights: Vec::new(),
            sky: None,
            light_efficacy: crate::DEFAULT_LIGHT_EFFICACY,
            two_sided: false,
        }
    }
}

/// Why a name leads outside the scene's folder (the end of [`SceneError::OutsideScene`]'s
/// message).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Outside {
    /// The name is an absolute path.
    Absolute,
    /// The name is a `file:` URI.
    FileUri,
    /// The name's `..` components climb out of the folder.
    ParentDir,
    /// The name resolves, through a symbolic link, to a file outside the folder.
    Link,
}

impl std::fmt::Display for Outside {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Outside::Absolute => "it is an absolute path",
            Outside::FileUri => "it is a file: URI",
            Outside::ParentDir => "its '..' climbs out of it",
            Outside::Link => "it is a symbolic link to a file outside it",
        })
    }
}

/// Reads a whole file under the policy: a regular file of at most `options.max_file_bytes`.
pub(crate) fn read_file(path: &Path, options: &LoadOptions) -> Result<Vec<u8>, SceneError> {
    let io = |reason| SceneError::Io {
        path: path.to_path_buf(),
        reason,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        return Err(SceneError::NotAFile {
            path: path.to_path_buf(),
        });
    }
    let limit = options.max_file_bytes;
    let too_large = |bytes| SceneError::FileTooLarge {
        path: path.to_path_buf(),
        bytes,
        limit,
    };
    if meta.len() > limit {
        return Err(too_large(meta.len()));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(limit.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(io)?;
    if bytes.len() as u64 > limit {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// The path of a file named `name` by the scene file `scene` (a relative path is relative to
/// the scene's folder; `uri` says whether `name` came from a URI, where `file:` applies), or
/// why it is refused.
pub(crate) fn resolve_named(
    scene: &Path,
    name: &str,
    uri: bool,
    options: &LoadOptions,
) -> Result<PathBuf, SceneError> {
    let dir = scene.parent().unwrap_or(Path::new(""));
    let refuse = |why| SceneError::OutsideScene {
        name: name.to_string(),
        why,
    };
    let file_uri = uri
        .then(|| {
            name.strip_prefix("file://")
                .or_else(|| name.strip_prefix("file:"))
        })
        .flatten();
    if let Some(rest) = file_uri {
        return if options.allow_outside_paths {
            Ok(PathBuf::from(rest))
        } else {
            Err(refuse(Outside::FileUri))
        };
    }
    let named = Path::new(name);
    let path = dir.join(named);
    if options.allow_outside_paths {
        return Ok(path);
    }
    if named.is_absolute() || named.has_root() {
        return Err(refuse(Outside::Absolute));
    }
    // lexically: `..` may not climb above the folder
    let mut depth = 0usize;
    for component in named.components() {
        match component {
            Component::ParentDir if depth == 0 => return Err(refuse(Outside::ParentDir)),
            Component::ParentDir => depth -= 1,
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::RootDir | Component::Prefix(_) => return Err(refuse(Outside::Absolute)),
        }
    }
    // and through links: where it really is (a file that does not exist is an I/O error
    // when it is opened)
    let folder = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    if let (Ok(real_dir), Ok(real)) = (folder.canonicalize(), path.canonicalize())
        && !real.starts_with(&real_dir)
    {
        return Err(refuse(Outside::Link));
    }
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_leaving_the_folder_are_refused_unless_allowed() {
        let safe = LoadOptions::default();
        let open = LoadOptions {
            allow_outside_paths: true,
            ..safe.clone()
        };
        let scene = Path::new("scenes/room/room.obj");
        let why = |name: &str, uri: bool| match resolve_named(scene, name, uri, &safe) {
            Err(SceneError::OutsideScene { why, .. }) => Some(why),
            Err(e) => panic!("{name}: {e}"),
            Ok(_) => None,
        };
        assert_eq!(why("room.mtl", false), None);
        assert_eq!(why("sub/../room.mtl", false), None);
        assert_eq!(why("./a/b/../../room.mtl", false), None);
        assert_eq!(why("../room.mtl", false), Some(Outside::ParentDir));
        assert_eq!(why("a/../../x.mtl", false), Some(Outside::ParentDir));
        assert_eq!(
            why("../../../../etc/passwd", false),
            Some(Outside::ParentDir)
        );
        assert_eq!(why("/etc/passwd", false), Some(Outside::Absolute));
        assert_eq!(why("/dev/zero", true), Some(Outside::Absolute));
        assert_eq!(why("file:///etc/passwd", true), Some(Outside::FileUri));
        assert_eq!(why("file:/etc/passwd", true), Some(Outside::FileUri));
        // outside a URI, "file:x" is just a (strange) relative name
        assert_eq!(why("file:x", false), None);
        assert_eq!(
            resolve_named(scene, "file:///etc/passwd", true, &open).unwrap(),
            Path::new("/etc/passwd")
        );
        assert_eq!(
            resolve_named(scene, "../x.mtl", false, &open).unwrap(),
            Path::new("scenes/room/../x.mtl")
        );
        let e = resolve_named(scene, "../../../../etc/passwd", false, &safe).unwrap_err();
        assert_eq!(
            e.to_string(),
            "'../../../../etc/passwd' is outside the scene's folder: its '..' climbs out of it \
             (files outside it are read only when allowed: mcrad --allow-outside-paths)"
        );
    }

    #[cfg(unix)]
    #[test]
    fn links_out_of_the_folder_and_device_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("s.obj");
        std::os::unix::fs::symlink("/etc/hostname", dir.path().join("l.mtl")).unwrap();
        assert!(matches!(
            resolve_named(&scene, "l.mtl", false, &LoadOptions::default()),
            Err(SceneError::OutsideScene {
                why: Outside::Link,
                ..
            })
        ));
        let e = read_file(Path::new("/dev/zero"), &LoadOptions::default()).unwrap_err();
        assert!(matches!(e, SceneError::NotAFile { .. }), "{e}");
        let small = LoadOptions {
            max_file_bytes: 10,
            ..LoadOptions::default()
        };
        std::fs::write(&scene, "0123456789A").unwrap();
        let e = read_file(&scene, &small).unwrap_err();
        assert!(
            matches!(
                e,
                SceneError::FileTooLarge {
                    bytes: 11,
                    limit: 10,
                    ..
                }
            ),
            "{e}"
        );
        std::fs::write(&scene, "0123456789").unwrap();
        assert_eq!(read_file(&scene, &small).unwrap().len(), 10);
    }
}
