//! Placing a file whole, in a directory someone else may also write to.
//!
//! Every file tessera writes for a reader to find later (an EXR, a preview, a cached asset, a
//! size record) goes through [`place`]. Its invariant: **no write ever follows a link, and a
//! reader sees the old file, nothing, or the whole new file.** The argument:
//!
//! - The bytes are written into a new entry made with `O_CREAT | O_EXCL` under a random
//!   name in the target's directory (the `tempfile` crate). `O_EXCL` fails on any existing
//!   entry, a symbolic link included, so nothing planted in the directory is opened; and the
//!   name cannot be guessed ahead, so nobody can plant one there to make it fail on purpose
//!   either. A predictable name (`.out.exr.tmp-<pid>`, as before) was both: an attacker's link
//!   there had its target truncated and overwritten.
//! - The entry is then moved to its name by `rename` ([`Place::Replace`]), which replaces the
//!   directory entry itself, never the file a link there points to; or by `link` then
//!   `unlink` ([`Place::New`]), which fails if the name is taken by anything, a link included.
//!   Both are atomic within one filesystem, which is why the temporary entry lives in the
//!   target's own directory.
//! - The data are synced before the entry is placed, so a crash after the move cannot leave a
//!   named, empty file.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

/// How [`place`] puts the finished file at its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Place {
    /// Replace whatever entry has the name (the entry, not what a link there points to).
    Replace,
    /// Fail with [`io::ErrorKind::AlreadyExists`] if anything has the name: for a server that
    /// must never replace a file someone else may rely on.
    New,
}

/// Who may read the placed file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// As an ordinary new file: 0666 less the process's umask (a user's render output).
    Shared,
    /// The owner only, 0600 (the coordinator's and worker's own state).
    Private,
}

/// Writes a file with `write` and puts it at `path` as `how` says; see the module doc for
/// why nothing at `path`, or in its directory, is ever followed. The temporary entry is
/// removed on every error.
pub fn place<F>(path: &Path, how: Place, access: Access, write: F) -> io::Result<()>
where
    F: FnOnce(&mut BufWriter<&File>) -> io::Result<()>,
{
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let mut builder = tempfile::Builder::new();
    // The name says whose it is, for a person who finds one left by a killed process.
    let prefix = format!(".{name}.");
    builder.prefix(&prefix).suffix(".tmp");
    #[cfg(unix)]
    builder.permissions(permissions(access));
    #[cfg(not(unix))]
    let _ = access;
    let tmp = builder.tempfile_in(dir)?;
    {
        let mut w = BufWriter::new(tmp.as_file());
        write(&mut w)?;
        w.flush()?;
    }
    tmp.as_file().sync_all()?;
    match how {
        Place::Replace => tmp.persist(path).map(drop).map_err(|e| e.error),
        Place::New => tmp.persist_noclobber(path).map(drop).map_err(|e| e.error),
    }
}

/// [`place`] with bytes already in memory.
pub fn place_bytes(path: &Path, how: Place, access: Access, bytes: &[u8]) -> io::Result<()> {
    place(path, how, access, |w| w.write_all(bytes))
}

/// Makes `dir` (and any missing parents) a directory only its owner may enter: created 0700,
/// or, if it exists with group or other bits set, stripped of them. For the directories that
/// hold a farm's scenes and state, which a promise of privacy must cover whoever made them.
pub fn private_dir(dir: &Path) -> io::Result<()> {
    let mut b = std::fs::DirBuilder::new();
    b.recursive(true);
    #[cfg(unix)]
    std::os::unix::fs::DirBuilderExt::mode(&mut b, 0o700);
    b.create(dir)?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(dir)?.permissions().mode();
        if mode & 0o077 != 0 {
            std::fs::set_permissions(dir, std::fs::Permissions::from_mode(mode & 0o700))?;
        }
    }
    Ok(())
}

#[cfg(unix)]
fn permissions(access: Access) -> std::fs::Permissions {
    use std::os::unix::fs::PermissionsExt;
    // The mode goes to open(2), which applies the umask.
    std::fs::Permissions::from_mode(match access {
        Access::Shared => 0o666,
        Access::Private => 0o600,
    })
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    fn dir() -> tempfile::TempDir {
        tempfile::tempdir().expect("tempdir")
    }

    #[test]
    fn a_link_at_the_name_is_replaced_not_followed() {
        let d = dir();
        let victim = d.path().join("victim.txt");
        std::fs::write(&victim, b"mine").expect("victim");
        let out = d.path().join("out.exr");
        std::os::unix::fs::symlink(&victim, &out).expect("link");
        place_bytes(&out, Place::Replace, Access::Shared, b"exr").expect("place");
        assert_eq!(std::fs::read(&victim).expect("read"), b"mine");
        assert!(!std::fs::symlink_metadata(&out).expect("stat").is_symlink());
        assert_eq!(std::fs::read(&out).expect("read"), b"exr");
    }

    #[test]
    fn a_new_file_is_never_placed_over_anything_a_link_included() {
        let d = dir();
        let victim = d.path().join("victim.txt");
        std::fs::write(&victim, b"mine").expect("victim");
        let out = d.path().join("sq.exr");
        std::os::unix::fs::symlink(&victim, &out).expect("link");
        let e = place_bytes(&out, Place::New, Access::Shared, b"exr").expect_err("taken");
        assert_eq!(e.kind(), io::ErrorKind::AlreadyExists);
        assert_eq!(std::fs::read(&victim).expect("read"), b"mine");
        // Nothing is left behind but the two entries that were there.
        assert_eq!(std::fs::read_dir(d.path()).expect("ls").count(), 2);
    }

    /// The old scheme's attack: a link planted at every name the old code would have used
    /// for its temporary file. None is touched, because no name is predictable.
    #[test]
    fn links_planted_at_the_old_temporary_names_are_not_followed() {
        let d = dir();
        let victim = d.path().join("victim.txt");
        std::fs::write(&victim, b"mine").expect("victim");
        let out = d.path().join("sq.exr");
        let planted = d.path().join(format!(".sq.exr.tmp-{}", std::process::id()));
        std::os::unix::fs::symlink(&victim, &planted).expect("link");
        place_bytes(&out, Place::New, Access::Shared, b"exr").expect("place");
        assert_eq!(std::fs::read(&victim).expect("read"), b"mine");
        assert_eq!(std::fs::read(&out).expect("read"), b"exr");
        assert!(!std::fs::symlink_metadata(&out).expect("stat").is_symlink());
    }

    #[test]
    fn private_files_are_the_owners_alone() {
        let d = dir();
        let out = d.path().join("asset");
        place_bytes(&out, Place::Replace, Access::Private, b"x").expect("place");
        let mode = std::fs::metadata(&out).expect("stat").permissions().mode() & 0o777;
        assert_eq!(mode, 0o600);
    }

    #[test]
    fn private_dirs_are_made_or_made_private() {
        let d = dir();
        let new = d.path().join("a/b");
        private_dir(&new).expect("made");
        let mode = |p: &Path| std::fs::metadata(p).expect("stat").permissions().mode() & 0o777;
        assert_eq!(mode(&new), 0o700);
        let open = d.path().join("open");
        std::fs::create_dir(&open).expect("mkdir");
        std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o755)).expect("chmod");
        private_dir(&open).expect("tightened");
        assert_eq!(mode(&open), 0o700);
    }

    #[test]
    fn a_failed_write_leaves_nothing() {
        let d = dir();
        let out = d.path().join("out.exr");
        let e = place(&out, Place::Replace, Access::Shared, |_| {
            Err(io::Error::other("encoder failed"))
        })
        .expect_err("fails");
        assert_eq!(e.to_string(), "encoder failed");
        assert_eq!(std::fs::read_dir(d.path()).expect("ls").count(), 0);
    }
}
