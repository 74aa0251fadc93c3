//! The files scenes name (meshes), stored once each by SHA-256 under `DATA_DIR/assets`.
//!
//! An upload appends chunks to `partial/HASH` in order; when the declared size is reached the
//! content is hashed, and only a match is moved (atomically, after an fsync) to `HASH`. So a
//! complete file's name is always its content's hash, an interrupted upload resumes from the
//! bytes held, and a client that sends the wrong bytes wastes only its own upload.
//!
//! Writes are serialised by one lock: uploads are rare and large, and a lock per hash would
//! buy nothing but code. Files are plain files rather than database values, as the EXRs are:
//! they can be gigabytes, and redb would copy them through its pages.
//!
//! The store has a budget of bytes (complete files plus the declared sizes of unfinished
//! uploads), and [`AssetStore::collect`] deletes what no active job has used for the retention
//! time, so a long-running farm's disk does not fill with last month's meshes, and a client
//! cannot fill it with files no job names.

use std::collections::{BTreeMap, BTreeSet};
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, SystemTime};

use sha2::{Digest, Sha256};
use tessera_render::files;

/// Most uploads that may be unfinished at once: each holds disk until it completes, so a
/// client that starts many and finishes none is refused rather than left to fill the disk.
pub const MAX_PENDING_UPLOADS: usize = 64;

/// Largest chunk accepted (and sent), in bytes.
pub const CHUNK_BYTES: usize = 1 << 20;

/// Why an asset operation failed.
#[derive(Debug, thiserror::Error)]
pub enum AssetError {
    /// The request is wrong (a malformed hash, an offset other than the bytes held, content
    /// that does not match its hash).
    #[error("{0}")]
    Invalid(String),
    /// A limit would be exceeded.
    #[error("{0}")]
    Limit(String),
    /// The file is not held (or not all of it).
    #[error("{0}")]
    Missing(String),
    /// The disk failed.
    #[error("asset store {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What failed.
        source: std::io::Error,
    },
}

/// How much of a file is held.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Held {
    /// Bytes held.
    pub received: u64,
    /// Whether all of it is, with its hash checked.
    pub complete: bool,
}

/// What [`AssetStore::collect`] deleted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Collected {
    /// Complete files deleted.
    pub files: usize,
    /// Unfinished uploads abandoned.
    pub uploads: usize,
    /// Bytes freed.
    pub bytes: u64,
}

/// The asset store.
#[derive(Debug)]
pub struct AssetStore {
    dir: PathBuf,
    max_bytes: u64,
    budget: u64,
    /// Declared sizes of the uploads in progress, by hash.
    pending: Mutex<BTreeMap<String, u64>>,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> AssetError + '_ {
    move |source| AssetError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Checks that `hash` is a SHA-256 in lower-case hex (it becomes a file name).
pub fn check_hash(hash: &str) -> Result<(), AssetError> {
    if hash.len() == 64
        && hash
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
    {
        Ok(())
    } else {
        let shown: String = hash.chars().take(80).collect();
        Err(AssetError::Invalid(format!(
            "{shown:?} is not a SHA-256 (64 lower-case hex digits)"
        )))
    }
}

/// Opens an upload's partial file to append to, creating it owner-only, and never through a
/// link: the data directory is private, so a link there is damage or an intruder's, and
/// appending through one would write a client's bytes into whatever it names.
fn append_only_here(path: &Path) -> std::io::Result<File> {
    let mut o = OpenOptions::new();
    o.create(true).append(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.mode(0o600).custom_flags(libc::O_NOFOLLOW);
    }
    o.open(path)
}

impl AssetStore {
    /// Opens (creating) the store under `data_dir`, accepting files of up to `max_bytes` and
    /// holding at most `budget` bytes in all. Unfinished uploads from before a restart stay
    /// resumable.
    pub fn open(data_dir: &Path, max_bytes: u64, budget: u64) -> Result<Self, AssetError> {
        let dir = data_dir.join("assets");
        let partial = dir.join("partial");
        files::private_dir(&partial).map_err(io(&partial))?;
        let mut pending = BTreeMap::new();
        for e in std::fs::read_dir(&partial).map_err(io(&partial))?.flatten() {
            let name = e.file_name().to_string_lossy().to_string();
            // HASH.size holds the declared size next to the partial HASH.
            if let Some(hash) = name.strip_suffix(".size") {
                if let Ok(size) = std::fs::read_to_string(e.path()) {
                    if let Ok(size) = size.trim().parse::<u64>() {
                        pending.insert(hash.to_string(), size);
                    }
                }
            }
        }
        Ok(Self {
            dir,
            max_bytes,
            budget,
            pending: Mutex::new(pending),
        })
    }

    fn complete_path(&self, hash: &str) -> PathBuf {
        self.dir.join(hash)
    }

    fn partial_path(&self, hash: &str) -> PathBuf {
        self.dir.join("partial").join(hash)
    }

    /// Where an unfinished upload's declared size is kept (it survives a restart).
    fn size_path(&self, hash: &str) -> PathBuf {
        self.dir.join("partial").join(format!("{hash}.size"))
    }

    fn pending(&self) -> std::sync::MutexGuard<'_, BTreeMap<String, u64>> {
        self.pending.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// How much of `hash` is held.
    pub fn status(&self, hash: &str) -> Result<Held, AssetError> {
        check_hash(hash)?;
        if let Ok(m) = std::fs::metadata(self.complete_path(hash)) {
            return Ok(Held {
                received: m.len(),
                complete: true,
            });
        }
        let received = std::fs::metadata(self.partial_path(hash)).map_or(0, |m| m.len());
        Ok(Held {
            received,
            complete: false,
        })
    }

    /// Appends `data` at `offset` to the upload of `hash` (of `total` bytes), and completes it
    /// when the last byte arrives.
    pub fn append(
        &self,
        hash: &str,
        offset: u64,
        total: u64,
        data: &[u8],
    ) -> Result<Held, AssetError> {
        check_hash(hash)?;
        let mut pending = self.pending();
        let held = self.status(hash)?;
        if held.complete {
            // Stored already (another client's upload, or a retry): nothing to do.
            return Ok(held);
        }
        if total > self.max_bytes {
            return Err(AssetError::Limit(format!(
                "asset {hash} is {total} bytes, above this coordinator's limit of {}",
                self.max_bytes
            )));
        }
        if data.len() > CHUNK_BYTES {
            return Err(AssetError::Invalid(format!(
                "a chunk of {} bytes; at most {CHUNK_BYTES}",
                data.len()
            )));
        }
        if offset != held.received {
            return Err(AssetError::Invalid(format!(
                "asset {hash}: a chunk at offset {offset}, but {} bytes are held: resume from there",
                held.received
            )));
        }
        let end = offset.checked_add(data.len() as u64);
        if end.is_none_or(|e| e > total) {
            return Err(AssetError::Invalid(format!(
                "asset {hash}: a chunk past the declared size of {total} bytes"
            )));
        }
        match pending.get(hash) {
            // An upload with bytes held keeps the size it declared; one with none may start
            // over with another.
            Some(&declared) if declared != total && held.received > 0 => {
                return Err(AssetError::Invalid(format!(
                    "asset {hash}: the upload in progress declared {declared} bytes, this chunk {total}"
                )))
            }
            Some(&declared) if declared == total => {}
            _ => {
                if !pending.contains_key(hash) && pending.len() >= MAX_PENDING_UPLOADS {
                    return Err(AssetError::Limit(format!(
                        "{MAX_PENDING_UPLOADS} uploads are unfinished; finish one first"
                    )));
                }
                // An upload reserves its whole declared size when it starts, so that uploads
                // in parallel cannot together pass the budget.
                let used = self.held_bytes(&pending, Some(hash))?;
                if used.saturating_add(total) > self.budget {
                    return Err(AssetError::Limit(format!(
                        "asset {hash} is {total} bytes, and the asset store holds {used} of its \
                         budget of {} (tessera coordinator --asset-store-bytes); files no active \
                         job uses are deleted after --asset-retention",
                        self.budget
                    )));
                }
                let size = self.size_path(hash);
                files::place_bytes(
                    &size,
                    files::Place::Replace,
                    files::Access::Private,
                    total.to_string().as_bytes(),
                )
                .map_err(io(&size))?;
                pending.insert(hash.to_string(), total);
            }
        }
        let path = self.partial_path(hash);
        let mut f = append_only_here(&path).map_err(io(&path))?;
        f.write_all(data).map_err(io(&path))?;
        let received = offset + data.len() as u64;
        if received < total {
            return Ok(Held {
                received,
                complete: false,
            });
        }
        f.sync_all().map_err(io(&path))?;
        drop(f);
        let actual = hash_file(&path)?;
        let size = self.size_path(hash);
        pending.remove(hash);
        if actual != hash {
            let _ = std::fs::remove_file(&path);
            let _ = std::fs::remove_file(&size);
            return Err(AssetError::Invalid(format!(
                "asset {hash}: the {total} bytes received hash to {actual}; the upload is discarded"
            )));
        }
        let done = self.complete_path(hash);
        std::fs::rename(&path, &done).map_err(io(&done))?;
        let _ = std::fs::remove_file(&size);
        if let Ok(d) = File::open(&self.dir) {
            let _ = d.sync_all();
        }
        Ok(Held {
            received: total,
            complete: true,
        })
    }

    /// The complete files: (hash, path, metadata).
    fn complete_files(&self) -> Result<Vec<(String, PathBuf, std::fs::Metadata)>, AssetError> {
        let mut out = Vec::new();
        for e in std::fs::read_dir(&self.dir)
            .map_err(io(&self.dir))?
            .flatten()
        {
            let name = e.file_name().to_string_lossy().to_string();
            if check_hash(&name).is_ok() {
                if let Ok(m) = e.metadata() {
                    out.push((name, e.path(), m));
                }
            }
        }
        Ok(out)
    }

    /// The bytes of the complete files plus the declared sizes of the unfinished uploads in
    /// `pending`, but for `except`'s.
    fn held_bytes(
        &self,
        pending: &BTreeMap<String, u64>,
        except: Option<&str>,
    ) -> Result<u64, AssetError> {
        let complete: u64 = self.complete_files()?.iter().map(|(_, _, m)| m.len()).sum();
        let reserved: u64 = pending
            .iter()
            .filter(|(h, _)| Some(h.as_str()) != except)
            .map(|(_, &size)| size)
            .sum();
        Ok(complete.saturating_add(reserved))
    }

    /// Bytes held: the complete files, plus the declared sizes of unfinished uploads (which
    /// they reserve).
    pub fn used_bytes(&self) -> Result<u64, AssetError> {
        self.held_bytes(&self.pending(), None)
    }

    /// Deletes the files, complete or not, that are not in `keep` and have not been used for
    /// `retention` before `now`; marks those in `keep` as used at `now`. A file's last use is
    /// its modification time: set when its upload last wrote to it, and at each collection
    /// that finds an active job naming it. So a file lives while a job renders from it, and
    /// for `retention` after, long enough for a client that checked it is held to submit the
    /// job naming it. The caller must make sure that no submission is between that check and
    /// its job's admission while this runs (the coordinator's submissions hold a lock it
    /// takes).
    pub fn collect(
        &self,
        keep: &BTreeSet<String>,
        retention: Duration,
        now: SystemTime,
    ) -> Result<Collected, AssetError> {
        let mut pending = self.pending();
        let mut out = Collected::default();
        let stale = |m: &std::fs::Metadata| {
            m.modified()
                .is_ok_and(|t| t.checked_add(retention).is_none_or(|end| end <= now))
        };
        for (hash, path, m) in self.complete_files()? {
            if keep.contains(&hash) {
                // Best effort: a file whose time cannot be set is kept now and judged by its
                // older time later.
                if let Ok(f) = OpenOptions::new().write(true).open(&path) {
                    let _ = f.set_modified(now);
                }
            } else if stale(&m) {
                std::fs::remove_file(&path).map_err(io(&path))?;
                out.files += 1;
                out.bytes += m.len();
            }
        }
        let abandoned: Vec<String> = pending
            .keys()
            .filter(|h| !keep.contains(*h))
            .filter(|h| {
                // An upload that has written nothing yet is judged by its size file.
                let data = std::fs::metadata(self.partial_path(h));
                let size = std::fs::metadata(self.size_path(h));
                data.or(size).is_ok_and(|m| stale(&m))
            })
            .cloned()
            .collect();
        for h in abandoned {
            let received = std::fs::metadata(self.partial_path(&h)).map_or(0, |m| m.len());
            let _ = std::fs::remove_file(self.partial_path(&h));
            let _ = std::fs::remove_file(self.size_path(&h));
            pending.remove(&h);
            out.uploads += 1;
            out.bytes += received;
        }
        Ok(out)
    }

    /// The whole content of a complete file.
    pub fn read(&self, hash: &str) -> Result<Vec<u8>, AssetError> {
        self.read_from(hash, 0, u64::MAX)
    }

    /// Up to `len` bytes of a complete file from `offset`.
    pub fn read_from(&self, hash: &str, offset: u64, len: u64) -> Result<Vec<u8>, AssetError> {
        check_hash(hash)?;
        let path = self.complete_path(hash);
        let mut f = File::open(&path)
            .map_err(|_| AssetError::Missing(format!("asset {hash} is not uploaded")))?;
        f.seek(SeekFrom::Start(offset)).map_err(io(&path))?;
        let mut out = Vec::new();
        f.take(len).read_to_end(&mut out).map_err(io(&path))?;
        Ok(out)
    }
}

fn hash_file(path: &Path) -> Result<String, AssetError> {
    let mut f = File::open(path).map_err(io(path))?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf).map_err(io(path))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// A scene's files as the store holds them: the names the job lists, each by hash.
pub struct JobAssets<'a> {
    /// The store.
    pub store: &'a AssetStore,
    /// Name → hash, as the job lists them.
    pub names: BTreeMap<String, String>,
}

impl tessera_render::scene::assets::Assets for JobAssets<'_> {
    fn read(&self, name: &str, max_bytes: u64) -> Result<Vec<u8>, String> {
        let hash = self.names.get(name).ok_or_else(|| {
            format!(
                "`{name}` is not among the files sent with the job (tessera submit uploads them)"
            )
        })?;
        let held = self.store.status(hash).map_err(|e| e.to_string())?;
        if !held.complete {
            return Err(format!("`{name}` (sha256 {hash}) has not been uploaded"));
        }
        if held.received > max_bytes {
            return Err(format!(
                "`{name}` is {} bytes, above the limit of {max_bytes}",
                held.received
            ));
        }
        self.store.read(hash).map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hash_of(data: &[u8]) -> String {
        Sha256::digest(data)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }

    fn upload(store: &AssetStore, data: &[u8]) -> String {
        let hash = hash_of(data);
        let held = store
            .append(&hash, 0, data.len() as u64, data)
            .expect("upload");
        assert!(held.complete);
        hash
    }

    const HOUR: Duration = Duration::from_secs(3600);

    /// A file a stored scene names is kept however old, and its use restarts its retention;
    /// a file none names is kept for the retention and deleted after it; so is an upload
    /// left unfinished.
    #[test]
    fn collection_keeps_what_jobs_use_and_what_is_young() {
        let dir = tempfile::tempdir().expect("tmp");
        let store = AssetStore::open(dir.path(), 1 << 20, 1 << 20).expect("open");
        let used = upload(&store, b"used by a job");
        let unused = upload(&store, b"named by nothing");
        let partial = hash_of(b"half of a file");
        store.append(&partial, 0, 14, b"half o").expect("part");
        let keep = BTreeSet::from([used.clone()]);
        let now = SystemTime::now();
        // Within the retention: nothing goes.
        let c = store.collect(&keep, HOUR, now).expect("collect");
        assert_eq!(c, Collected::default());
        // Two hours on: the unused file and the unfinished upload go.
        let later = now + 2 * HOUR;
        let c = store.collect(&keep, HOUR, later).expect("collect");
        assert_eq!((c.files, c.uploads), (1, 1), "{c:?}");
        assert_eq!(c.bytes, 16 + 6);
        assert!(store.status(&used).expect("status").complete);
        let gone = store.status(&unused).expect("status");
        assert_eq!((gone.received, gone.complete), (0, false));
        assert_eq!(store.status(&partial).expect("status").received, 0);
        assert_eq!(store.used_bytes().expect("used"), 13);
        // The job ends: the file was last used at `later`, so it stays an hour more.
        let none = BTreeSet::new();
        let c = store
            .collect(&none, HOUR, later + HOUR / 2)
            .expect("collect");
        assert_eq!(c, Collected::default());
        let c = store
            .collect(&none, HOUR, later + 2 * HOUR)
            .expect("collect");
        assert_eq!(c.files, 1);
        assert!(!store.status(&used).expect("status").complete);
        // An upload started again after its partial was dropped resumes from nothing.
        store.append(&partial, 0, 14, b"half o").expect("again");
    }

    /// An upload that would pass the store's budget is refused with a message naming the
    /// budget and the flag; unfinished uploads count at their declared size.
    #[test]
    fn the_budget_refuses_uploads_and_counts_unfinished_ones() {
        let dir = tempfile::tempdir().expect("tmp");
        let store = AssetStore::open(dir.path(), 100, 100).expect("open");
        upload(&store, &[7u8; 60]);
        let big = [8u8; 50];
        let e = store
            .append(&hash_of(&big), 0, 50, &big)
            .expect_err("over budget");
        let msg = e.to_string();
        assert!(matches!(e, AssetError::Limit(_)), "{msg}");
        assert!(
            msg.contains("budget of 100") && msg.contains("--asset-store-bytes"),
            "{msg}"
        );
        // 30 declared bytes reserve their space: another 20 fits, 11 more would not.
        let a = [1u8; 30];
        store.append(&hash_of(&a), 0, 30, &a[..5]).expect("start");
        store
            .append(&hash_of(&[2u8; 10]), 0, 10, &[2u8; 10])
            .expect("fits");
        let b = [3u8; 11];
        assert!(store.append(&hash_of(&b), 0, 11, &b).is_err());
        // Finishing the reserved upload takes no more room than it declared.
        store.append(&hash_of(&a), 5, 30, &a[5..]).expect("finish");
        assert_eq!(store.used_bytes().expect("used"), 100);
    }
}
