//! A scene file's fields: where a value sits ([`KeyPath`], `materials.glass.ior`), the checks
//! every reader applies to one (finite, positive, a colour, a number in [0, 1], keys that do
//! not apply to a kind), each answering with the path of what is wrong, and the serde helper
//! for three-number vectors. Below the scene readers and the materials, which both read
//! fields.

use std::fmt;

use glam::Vec3A;
use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

use crate::util::math::v3;

/// One step of a key path.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Seg {
    /// A table key.
    Key(String),
    /// An array index.
    Index(usize),
    /// Inside the file the path so far names (a glTF file an object reads): what follows is
    /// a place in that file, not in the scene's text.
    File(String),
}

/// A key path into a scene document.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct KeyPath(pub Vec<Seg>);

impl KeyPath {
    /// The path extended by a key.
    pub fn key(&self, k: &str) -> Self {
        let mut v = self.0.clone();
        v.push(Seg::Key(k.to_string()));
        Self(v)
    }

    /// The path extended by an index.
    pub fn index(&self, i: usize) -> Self {
        let mut v = self.0.clone();
        v.push(Seg::Index(i));
        Self(v)
    }

    /// The path into the file `file` that this key names: an error found inside that file
    /// keeps both places, the key in the scene and the file it names.
    pub fn within(&self, file: &str) -> Self {
        let mut v = self.0.clone();
        v.push(Seg::File(file.to_string()));
        Self(v)
    }

    /// The path extended by every step of `rest` (a place found relative to where this path
    /// points, such as a place in a file found before the file's key was known).
    pub fn join(&self, rest: &KeyPath) -> Self {
        let mut v = self.0.clone();
        v.extend(rest.0.iter().cloned());
        Self(v)
    }

    /// The path as a JSON pointer (RFC 6901: `/meshes/0/primitives/1`; `""` for the whole
    /// document), the form glTF's own validator reports places in: a place inside a JSON
    /// file is said the way tools for that file say it.
    pub fn pointer(&self) -> String {
        let mut out = String::new();
        for s in &self.0 {
            out.push('/');
            match s {
                Seg::Key(k) | Seg::File(k) => {
                    out.push_str(&k.replace('~', "~0").replace('/', "~1"))
                }
                Seg::Index(n) => out.push_str(&n.to_string()),
            }
        }
        out
    }

    /// A path into a file ([`KeyPath::within`]) as its parts: the key in the scene, the file,
    /// and the place in the file (empty: the file as a whole). `None` for a place in the
    /// scene's own text.
    pub fn split_file(&self) -> Option<(KeyPath, &str, KeyPath)> {
        let i = self.0.iter().position(|s| matches!(s, Seg::File(_)))?;
        let Seg::File(file) = &self.0[i] else {
            return None;
        };
        Some((
            KeyPath(self.0[..i].to_vec()),
            file,
            KeyPath(self.0[i + 1..].to_vec()),
        ))
    }
}

impl fmt::Display for KeyPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0.is_empty() {
            return f.write_str("(document)");
        }
        for (i, s) in self.0.iter().enumerate() {
            match s {
                Seg::Key(k) if i == 0 => write!(f, "{k}")?,
                Seg::Key(k) => write!(f, ".{k}")?,
                Seg::Index(n) => write!(f, "[{n}]")?,
                Seg::File(name) => write!(f, " in `{name}`")?,
            }
        }
        Ok(())
    }
}

/// What is wrong, and where in the file.
pub type Invalid = (KeyPath, String);

/// The path of a top-level key (`materials`).
pub fn root(k: &str) -> KeyPath {
    KeyPath(vec![Seg::Key(k.to_string())])
}

/// Three finite numbers.
pub fn finite3(v: [f32; 3], path: &KeyPath) -> Result<Vec3A, Invalid> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v3(v))
    } else {
        Err((path.clone(), format!("must be finite numbers, got {v:?}")))
    }
}

/// A colour: finite, not negative, and at most 1 where `max_one` (a reflectance).
pub fn color(v: [f32; 3], path: &KeyPath, max_one: bool) -> Result<Vec3A, Invalid> {
    let c = finite3(v, path)?;
    if c.min_element() < 0.0 {
        return Err((path.clone(), format!("must not be negative, got {v:?}")));
    }
    if max_one && c.max_element() > 1.0 {
        return Err((
            path.clone(),
            format!(
                "must be at most 1 (a surface cannot reflect more than it receives), got {v:?}"
            ),
        ));
    }
    Ok(c)
}

/// A finite number greater than 0.
pub fn positive(x: f32, path: &KeyPath) -> Result<f32, Invalid> {
    if x.is_finite() && x > 0.0 {
        Ok(x)
    } else {
        Err((
            path.clone(),
            format!("must be a finite number greater than 0, got {x}"),
        ))
    }
}

/// A finite number.
pub fn finite(x: f32, path: &KeyPath) -> Result<f32, Invalid> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err((path.clone(), format!("must be a finite number, got {x}")))
    }
}

/// Rejects fields that do not belong to the chosen kind, so a typo'd or misplaced key is an
/// error rather than silently ignored.
pub fn only(
    path: &KeyPath,
    kind: &str,
    present: &[(&str, bool)],
    allowed: &[&str],
) -> Result<(), Invalid> {
    for (name, is) in present {
        if *is && !allowed.contains(name) {
            return Err((path.key(name), format!("`{name}` does not apply to {kind}")));
        }
    }
    Ok(())
}

/// The value of a key that `kind` cannot do without, or an error at that key saying so.
pub fn required<T>(value: Option<T>, path: &KeyPath, kind: &str, name: &str) -> Result<T, Invalid> {
    value.ok_or_else(|| (path.key(name), format!("{kind} needs `{name}`")))
}

/// A number in [0, 1].
pub fn unit(x: f32, path: &KeyPath) -> Result<f32, Invalid> {
    if (0.0..=1.0).contains(&x) {
        Ok(x)
    } else {
        Err((path.clone(), format!("must be between 0 and 1, got {x}")))
    }
}

/// A vector of exactly three numbers. serde's own `[f32; 3]` stops reading after the third
/// element, so TOML's `[0, 0, 3.9, 42, "junk"]` would load as `[0, 0, 3.9]`: a typo that
/// silently changes the scene.
pub fn exactly_three<'de, D: Deserializer<'de>>(d: D) -> Result<[f32; 3], D::Error> {
    let v = Vec::<f32>::deserialize(d)?;
    <[f32; 3]>::try_from(v).map_err(|v| D::Error::invalid_length(v.len(), &"a vector of 3 numbers"))
}

/// [`exactly_three`] for a key that may be left out.
pub fn maybe_three<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f32; 3]>, D::Error> {
    exactly_three(d).map(Some)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_into_a_file_splits_into_the_key_the_file_and_the_place() {
        let key = root("objects").index(0).key("file");
        assert_eq!(key.split_file(), None);
        let inside = key.within("m.gltf").key("materials").index(2);
        let (k, file, place) = inside.split_file().expect("a file");
        assert_eq!((k.to_string(), file), ("objects[0].file".into(), "m.gltf"));
        assert_eq!(place.to_string(), "materials[2]");
        assert_eq!(place.pointer(), "/materials/2");
        let whole = key.within("m.gltf");
        assert!(whole.split_file().expect("a file").2 .0.is_empty());
    }

    #[test]
    fn a_pointer_escapes_tilde_and_slash_and_is_empty_for_the_document() {
        assert_eq!(KeyPath::default().pointer(), "");
        let p = root("a/b").key("c~d").index(3).key("");
        assert_eq!(p.pointer(), "/a~1b/c~0d/3/");
        assert_eq!(root("x").join(&root("y").index(1)).pointer(), "/x/y/1");
    }
}
