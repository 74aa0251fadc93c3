//! Where the files a scene names (its meshes) come from, and the record of which it read.
//!
//! A scene's identity must cover these files, not only its text: the same text with another
//! mesh is another image. So every file read is recorded with its SHA-256, and
//! [`crate::scene::Scene::hash`] covers the list.

use std::path::PathBuf;

use sha2::{Digest, Sha256};

/// Why `name`, a file a scene names, may not be read: a name must be a relative path that stays
/// inside the scene file's folder (no `..` part, not absolute, no scheme or drive, `/` as the
/// only separator), or a scene file could read any file its renderer can (`../.ssh/id_rsa`)
/// and `tessera submit` would upload it to the farm for others to fetch. Every reader checks
/// it: `tessera render` and `submit` before any byte is read, the coordinator on submission
/// and the worker on loading, so a client that skips it is refused anyway. A glTF URI is
/// checked after its percent-decoding (`..%2Fsecret` is `../secret`).
pub fn check_file_name(name: &str) -> Result<(), String> {
    let refuse = |why: &str| {
        Err(format!(
            "`{name}` {why}: a scene reads only files inside its own folder"
        ))
    };
    if name.is_empty() {
        return refuse("is empty");
    }
    if name.contains('\\') {
        return refuse("has a backslash (use `/` between folders)");
    }
    if name.chars().any(char::is_control) {
        return refuse("has a control character");
    }
    if name.starts_with('/') {
        return refuse("is an absolute path");
    }
    if name
        .split('/')
        .next()
        .is_some_and(|first| first.contains(':'))
    {
        return refuse("names a scheme or drive");
    }
    if name.split('/').any(|part| part == "..") {
        return refuse("climbs out of its folder with `..`");
    }
    if name.ends_with('/') {
        return refuse("names a folder");
    }
    Ok(())
}

/// A source of the files a scene names, by the name the scene gives (`file = "..."`).
pub trait Assets {
    /// The bytes of `name`, at most `max_bytes` of them, or a one-line reason why not.
    fn read(&self, name: &str, max_bytes: u64) -> Result<Vec<u8>, String>;
}

/// Files relative to a directory: the scene file's own, for a scene loaded from disk.
#[derive(Clone, Debug)]
pub struct DirAssets(pub PathBuf);

impl Assets for DirAssets {
    fn read(&self, name: &str, max_bytes: u64) -> Result<Vec<u8>, String> {
        check_file_name(name)?;
        let path = self.0.join(name);
        // The path as resolved, for a user looking for the file.
        let meta = std::fs::metadata(&path)
            .map_err(|e| format!("cannot read `{name}` ({}): {e}", path.display()))?;
        if !meta.is_file() {
            return Err(format!("`{name}` is not a file"));
        }
        if meta.len() > max_bytes {
            return Err(format!(
                "`{name}` is {} bytes, above the limit of {max_bytes}",
                meta.len()
            ));
        }
        std::fs::read(&path).map_err(|e| format!("cannot read `{name}`: {e}"))
    }
}

/// No files at all: a scene given as text alone, with nothing beside it.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoAssets;

impl Assets for NoAssets {
    fn read(&self, name: &str, _: u64) -> Result<Vec<u8>, String> {
        Err(format!(
            "`{name}` cannot be read: this scene was given as text, with no files beside it"
        ))
    }
}

/// SHA-256, lower-case hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    super::hex(&Sha256::digest(bytes))
}

/// The hash of a scene's text and the files it read (name and content hash, in the order
/// first read): the text's own hash when it reads none, so that scenes without files keep
/// the identity they always had.
pub fn scene_hash(text: &str, files: &[(String, String)]) -> String {
    if files.is_empty() {
        return sha256_hex(text.as_bytes());
    }
    let mut h = Sha256::new();
    h.update(text.as_bytes());
    for (name, hash) in files {
        h.update(b"\0file\0");
        h.update(name.as_bytes());
        h.update(b"\0");
        h.update(hash.as_bytes());
    }
    super::hex(&h.finalize())
}

/// Files held in memory, by name: a scene's files as they arrive over the network, or a
/// test's.
#[derive(Clone, Debug, Default)]
pub struct MemAssets(pub std::collections::BTreeMap<String, Vec<u8>>);

impl Assets for MemAssets {
    fn read(&self, name: &str, max_bytes: u64) -> Result<Vec<u8>, String> {
        let bytes = self
            .0
            .get(name)
            .ok_or_else(|| format!("`{name}` is not among the scene's files"))?;
        if bytes.len() as u64 > max_bytes {
            return Err(format!(
                "`{name}` is {} bytes, above the limit of {max_bytes}",
                bytes.len()
            ));
        }
        Ok(bytes.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_stay_inside_the_scene_folder() {
        for ok in [
            "a.obj",
            "meshes/a.obj",
            "./a.png",
            "my car.bin",
            "a..b.png",
            "x/.../y",
        ] {
            assert_eq!(check_file_name(ok), Ok(()), "{ok}");
        }
        for (bad, why) in [
            ("", "is empty"),
            ("../secret/id_rsa", "climbs out"),
            ("meshes/../../x", "climbs out"),
            ("..", "climbs out"),
            ("/etc/passwd", "absolute"),
            ("file:///etc/passwd", "scheme"),
            ("https://example.com/a.bin", "scheme"),
            ("C:/Windows/win.ini", "drive"),
            ("..\\secret", "backslash"),
            ("a\nb", "control"),
            ("meshes/", "folder"),
        ] {
            let e = check_file_name(bad).expect_err(bad);
            assert!(e.contains(why), "{bad}: {e}");
        }
        assert!(DirAssets(".".into())
            .read("../x", 10)
            .expect_err("refused")
            .contains("climbs out"));
    }
}
