//! Durable coordinator state in redb: scenes by hash, job records, each tile's merged sums and
//! the results that arrived ahead of their turn. Each commit (fsync) is one transaction of
//! changes queued in order ([`Coalesced`]), so the store always holds the state after some
//! prefix of the coordinator's changes, which a restart resumes from; when commits happen
//! (checkpoints, and changes a reply waits on) is the writer's business (`shared.rs`).
//!
//! Every stored value carries a CRC-32 of its key and bytes, checked whenever it is read: a
//! damaged file (a bad disk, a stray write) makes the coordinator refuse to start with the
//! record it found damaged, instead of writing an image from flipped bits. redb's own
//! structures are checked by redb; a panic inside it on a badly damaged file is caught and
//! reported the same way.

use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use redb::{Database, ReadableDatabase, ReadableTable, TableDefinition};
use tessera_render::{PixelRect, TileSums};

mod apply;
mod coalesce;
mod keys;
mod migrate;
mod records;
mod sums;

use keys::{audit_key, guide_key, job_key, log_key, pending_key, tile_key, unit_key};

pub use coalesce::Coalesced;
pub use records::{
    AuditRecord, DenoiseRecord, GuidingRecord, JobPhase, JobRecord, LoadedJob, Op, RangeRef,
    StoredScene, UnitFailure,
};
pub use sums::{decode_sums, encode_sums, AOV_BYTES, PIXEL_BYTES};

/// Scene hash → [`StoredScene`] (JSON).
const SCENES: TableDefinition<&str, &[u8]> = TableDefinition::new("scenes");
/// Job id → [`JobRecord`] (JSON).
const JOBS: TableDefinition<u64, &[u8]> = TableDefinition::new("jobs");
/// (job, tile) → merged sums of batches `0..next` ([`encode_sums`]).
const TILES: TableDefinition<(u64, u32), &[u8]> = TableDefinition::new("tiles");
/// (job, tile, batch) → a result that arrived before its predecessors were merged.
const PENDING: TableDefinition<(u64, u32, u32), &[u8]> = TableDefinition::new("pending");
/// (job, tile, batch) → one unit's result as merged, kept for audited jobs only, so that a
/// tile can be folded again without the units of a worker an audit convicted.
const UNITS: TableDefinition<(u64, u32, u32), &[u8]> = TableDefinition::new("units");
/// (boot, number) → an [`AuditRecord`] (JSON): a worker convicted by an audit.
const AUDITS: TableDefinition<(u64, u64), &[u8]> = TableDefinition::new("audits");
/// Counters.
const META: TableDefinition<&str, u64> = TableDefinition::new("meta");
/// job id → its workers' log lines (`tessera logs`), JSON, bounded.
const LOGS: TableDefinition<u64, &[u8]> = TableDefinition::new("logs");
/// (job, epoch) → a guided job's tree of that epoch ([`tessera_render::guide::SdTree`]'s
/// encoding): the guide it trained, or the training tree as merged so far.
const GUIDES: TableDefinition<(u64, u32), &[u8]> = TableDefinition::new("guides");

/// The layout of stored values: 2 = each value followed by the CRC-32 of its key and bytes.
/// Stores of layout 1 (no checksums) are sealed in place when first opened.
const FORMAT: u64 = 2;

/// redb's page cache. A checkpoint writes each dirty tile once and nothing reads sums back
/// but a restart, so a small cache costs nothing measurable.
const CACHE_BYTES: usize = 64 << 20;

/// The database file's name under the data directory.
pub const FILE_NAME: &str = "coordinator.redb";

/// Why the store failed.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// redb reported an error. Its message is in this one's, so it is not also given as the
    /// source: a report of the chain (`{:#}`) would say it twice.
    #[error("state store: {0}")]
    Db(redb::Error),
    /// A stored record does not decode (a corrupt or foreign file).
    #[error("state store: corrupt record {what}: {why}; refusing to start on it (move {FILE_NAME} out of the data directory to start a new, empty farm)")]
    Corrupt {
        /// Which record.
        what: String,
        /// What is wrong with it.
        why: String,
    },
    /// redb panicked on the file: it is damaged beyond what redb checks for.
    #[error("state store {path}: damaged ({why}); refusing to start on it (move it away to start a new, empty farm)")]
    Damaged {
        /// The file.
        path: String,
        /// What redb said.
        why: String,
    },
    /// Another process has the store open: a second coordinator on the same data directory.
    #[error("state store {path}: another coordinator holds it (one data directory serves one coordinator: stop that one, or give this one its own --data-dir)")]
    Held {
        /// The file.
        path: String,
    },
    /// The data directory cannot be used.
    #[error("state store: {path}: {source}")]
    Io {
        /// The path.
        path: String,
        /// The error.
        source: std::io::Error,
    },
}

impl From<redb::Error> for StoreError {
    fn from(e: redb::Error) -> Self {
        Self::Db(e)
    }
}

fn dberr<E: Into<redb::Error>>(e: E) -> StoreError {
    StoreError::Db(e.into())
}

/// `bytes` followed by the CRC-32 of `key` and `bytes`. The key is in the sum so that a value
/// moved under another key by damage to the tree is caught too.
fn seal(key: &[u8], bytes: &[u8]) -> Vec<u8> {
    let mut h = crc32fast::Hasher::new();
    h.update(key);
    h.update(bytes);
    let mut out = Vec::with_capacity(bytes.len() + 4);
    out.extend_from_slice(bytes);
    out.extend_from_slice(&h.finalize().to_le_bytes());
    out
}

/// The bytes of a sealed value, if its checksum holds.
fn unseal<'a>(
    what: impl Fn() -> String,
    key: &[u8],
    sealed: &'a [u8],
) -> Result<&'a [u8], StoreError> {
    let corrupt = |why: &str| StoreError::Corrupt {
        what: what(),
        why: why.to_string(),
    };
    let split = sealed
        .len()
        .checked_sub(4)
        .ok_or_else(|| corrupt("shorter than its checksum"))?;
    let (bytes, sum) = sealed.split_at(split);
    let mut h = crc32fast::Hasher::new();
    h.update(key);
    h.update(bytes);
    if h.finalize().to_le_bytes() != sum {
        return Err(corrupt("checksum mismatch: the file is damaged"));
    }
    Ok(bytes)
}

/// A panic inside redb (a badly damaged file) as an error.
fn guarded<T>(path: &Path, f: impl FnOnce() -> Result<T, StoreError>) -> Result<T, StoreError> {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|p| {
        let why = p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "redb panicked".into());
        Err(StoreError::Damaged {
            path: path.display().to_string(),
            why: why.lines().next().unwrap_or_default().to_string(),
        })
    })
}

/// The coordinator's redb database.
pub struct Store {
    /// Always `Some` but in `drop`.
    db: Option<Database>,
}

impl Drop for Store {
    /// redb flushes on close, and on a damaged file that can panic too: caught, so a damaged
    /// store ends in the one error that reported it.
    fn drop(&mut self) {
        let db = self.db.take();
        let _ = catch_unwind(AssertUnwindSafe(move || drop(db)));
    }
}

impl Store {
    /// Opens (or creates) `dir/coordinator.redb`. The directory and the file are made the
    /// owner's alone (0700, 0600; an existing directory loses its group and other bits): they
    /// hold every submitted scene.
    ///
    /// An existing file that is empty is refused rather than started afresh: a fresh store
    /// would give out job ids again, and with them the names of finished jobs' outputs.
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        let io = |source| StoreError::Io {
            path: dir.display().to_string(),
            source,
        };
        tessera_render::files::private_dir(dir).map_err(io)?;
        let path = dir.join(FILE_NAME);
        if std::fs::metadata(&path).is_ok_and(|m| m.len() == 0) {
            return Err(StoreError::Damaged {
                path: path.display().to_string(),
                why: "the file is empty (truncated?)".into(),
            });
        }
        guarded(&path, || {
            // redb's default cache is 1 GiB, which a store of large frames' sums fills: it
            // would be most of the coordinator's memory, for pages read once at a restart.
            let db = Database::builder()
                .set_cache_size(CACHE_BYTES)
                .create(&path)
                .map_err(|e| match e {
                    redb::DatabaseError::DatabaseAlreadyOpen => StoreError::Held {
                        path: path.display().to_string(),
                    },
                    e => dberr(e),
                })?;
            // redb creates its file as an ordinary one; it holds every scene submitted.
            #[cfg(unix)]
            {
                use std::os::unix::fs::PermissionsExt;
                std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).map_err(
                    |source| StoreError::Io {
                        path: path.display().to_string(),
                        source,
                    },
                )?;
            }
            let store = Self { db: Some(db) };
            store.prepare()?;
            Ok(store)
        })
    }

    fn db(&self) -> Result<&Database, StoreError> {
        self.db.as_ref().ok_or_else(|| StoreError::Corrupt {
            what: "database".into(),
            why: "used after close".into(),
        })
    }

    /// Creates every table (so readers never meet a missing one) and brings an older layout
    /// up to [`FORMAT`].
    fn prepare(&self) -> Result<(), StoreError> {
        let tx = self.db()?.begin_write().map_err(dberr)?;
        // redb can panic on a damaged file, and its write transaction's drop can panic too: run
        // during the unwinding of the first panic, that would abort the process. So the first
        // panic is caught here, and the transaction is leaked rather than dropped.
        match catch_unwind(AssertUnwindSafe(|| Self::prepare_in(&tx))) {
            Ok(Ok(())) => {
                tx.commit().map_err(dberr)?;
                Ok(())
            }
            Ok(Err(e)) => Err(e),
            Err(p) => {
                std::mem::forget(tx);
                std::panic::resume_unwind(p)
            }
        }
    }

    fn prepare_in(tx: &redb::WriteTransaction) -> Result<(), StoreError> {
        // One table open at a time: a table dropped while a panic unwinds locks a mutex that
        // panic poisoned, which aborts.
        tx.open_table(SCENES).map_err(dberr)?;
        tx.open_table(JOBS).map_err(dberr)?;
        tx.open_table(TILES).map_err(dberr)?;
        tx.open_table(PENDING).map_err(dberr)?;
        tx.open_table(UNITS).map_err(dberr)?;
        tx.open_table(AUDITS).map_err(dberr)?;
        let format = tx
            .open_table(META)
            .map_err(dberr)?
            .get("format")
            .map_err(dberr)?
            .map(|g| g.value());
        match format {
            Some(FORMAT) => Ok(()),
            Some(f) => Err(StoreError::Corrupt {
                what: "format".into(),
                why: format!("layout {f}, and this coordinator reads layout {FORMAT}"),
            }),
            None => {
                // Layout 1: the same values without checksums. Seal each in place.
                migrate::seal_layout_1(
                    &mut tx.open_table(SCENES).map_err(dberr)?,
                    &mut tx.open_table(JOBS).map_err(dberr)?,
                    &mut tx.open_table(TILES).map_err(dberr)?,
                    &mut tx.open_table(PENDING).map_err(dberr)?,
                )?;
                tx.open_table(META)
                    .map_err(dberr)?
                    .insert("format", FORMAT)
                    .map_err(dberr)?;
                Ok(())
            }
        }
    }

    /// Increments and returns the boot counter, which makes lease and worker ids unique across
    /// restarts.
    pub fn next_epoch(&self) -> Result<u64, StoreError> {
        let tx = self.db()?.begin_write().map_err(dberr)?;
        let epoch = {
            let mut meta = tx.open_table(META).map_err(dberr)?;
            let e = meta
                .get("epoch")
                .map_err(dberr)?
                .map(|g| g.value())
                .unwrap_or(0)
                + 1;
            meta.insert("epoch", e).map_err(dberr)?;
            e
        };
        tx.commit().map_err(dberr)?;
        Ok(epoch)
    }

    /// Job `id`'s stored log (JSON), if it has one: an ended job's, which is not kept in memory.
    pub fn log(&self, id: u64) -> Result<Option<Vec<u8>>, StoreError> {
        guarded(Path::new(FILE_NAME), || {
            let tx = self.db()?.begin_read().map_err(dberr)?;
            let logs = match tx.open_table(LOGS) {
                Ok(t) => t,
                Err(redb::TableError::TableDoesNotExist(_)) => return Ok(None),
                Err(e) => return Err(dberr(e)),
            };
            let Some(v) = logs.get(id).map_err(dberr)? else {
                return Ok(None);
            };
            Ok(Some(
                unseal(|| format!("job {id} log"), &log_key(id), v.value())?.to_vec(),
            ))
        })
    }

    /// Every job with its stored sums, each checked against its checksum.
    pub fn load(&self) -> Result<Vec<LoadedJob>, StoreError> {
        guarded(Path::new(FILE_NAME), || self.load_unguarded())
    }

    fn load_unguarded(&self) -> Result<Vec<LoadedJob>, StoreError> {
        let tx = self.db()?.begin_read().map_err(dberr)?;
        let jobs = tx.open_table(JOBS).map_err(dberr)?;
        let tiles = tx.open_table(TILES).map_err(dberr)?;
        let pending = tx.open_table(PENDING).map_err(dberr)?;
        // Made by the first log written (a store with none has the layout it had before logs).
        let logs = match tx.open_table(LOGS) {
            Ok(t) => Some(t),
            Err(redb::TableError::TableDoesNotExist(_)) => None,
            Err(e) => return Err(dberr(e)),
        };
        // Made by the first guided job's checkpoint.
        let guides = match tx.open_table(GUIDES) {
            Ok(t) => Some(t),
            Err(redb::TableError::TableDoesNotExist(_)) => None,
            Err(e) => return Err(dberr(e)),
        };
        let mut out = Vec::new();
        for row in jobs.iter().map_err(dberr)? {
            let (k, v) = row.map_err(dberr)?;
            let id = k.value();
            let what = || format!("job {id}");
            let bytes = unseal(what, &job_key(id), v.value())?;
            let record: JobRecord =
                serde_json::from_slice(bytes).map_err(|e| StoreError::Corrupt {
                    what: what(),
                    why: e.to_string(),
                })?;
            if record.id != id {
                return Err(StoreError::Corrupt {
                    what: what(),
                    why: format!("the record says it is job {}", record.id),
                });
            }
            // A damaged log costs the log alone, not the start: it is only ever read by people.
            // An ended job's log stays in the store (its size noted for retention).
            let stored = match &logs {
                Some(t) => t.get(id).map_err(dberr)?,
                None => None,
            };
            let log_bytes = stored.as_ref().map_or(0, |v| v.value().len() as u64);
            let stored = stored.filter(|_| record.phase == JobPhase::Active);
            let log = stored.and_then(|v| {
                unseal(|| format!("job {id} log"), &log_key(id), v.value())
                    .map_err(|e| tracing::warn!("{e}; its log is left out"))
                    .ok()
                    .map(<[u8]>::to_vec)
            });
            let mut job = LoadedJob {
                record,
                tiles: Vec::new(),
                pending: Vec::new(),
                log,
                log_bytes,
                guides: Vec::new(),
            };
            if let Some(g) = &guides {
                for row in g.range((id, 0)..=(id, u32::MAX)).map_err(dberr)? {
                    let (k, v) = row.map_err(dberr)?;
                    let e = k.value().1;
                    let bytes = unseal(
                        || format!("job {id} guide {e}"),
                        &guide_key(id, e),
                        v.value(),
                    )?;
                    job.guides.push((e, bytes.to_vec()));
                }
            }
            for row in tiles.range((id, 0)..=(id, u32::MAX)).map_err(dberr)? {
                let (k, v) = row.map_err(dberr)?;
                let t = k.value().1;
                let bytes = unseal(|| format!("job {id} tile {t}"), &tile_key(id, t), v.value())?;
                job.tiles.push((t, bytes.to_vec()));
            }
            for row in pending
                .range((id, 0, 0)..=(id, u32::MAX, u32::MAX))
                .map_err(dberr)?
            {
                let (k, v) = row.map_err(dberr)?;
                let (_, t, b) = k.value();
                let bytes = unseal(
                    || format!("job {id} tile {t} batch {b}"),
                    &pending_key(id, t, b),
                    v.value(),
                )?;
                job.pending.push(((t, b), bytes.to_vec()));
            }
            out.push(job);
        }
        Ok(out)
    }

    /// The hashes of every stored scene.
    pub fn scene_hashes(&self) -> Result<Vec<String>, StoreError> {
        let tx = self.db()?.begin_read().map_err(dberr)?;
        let scenes = tx.open_table(SCENES).map_err(dberr)?;
        let mut out = Vec::new();
        for row in scenes.iter().map_err(dberr)? {
            out.push(row.map_err(dberr)?.0.value().to_string());
        }
        Ok(out)
    }

    /// A stored scene.
    pub fn scene(&self, hash: &str) -> Result<Option<StoredScene>, StoreError> {
        let tx = self.db()?.begin_read().map_err(dberr)?;
        let scenes = tx.open_table(SCENES).map_err(dberr)?;
        let Some(v) = scenes.get(hash).map_err(dberr)? else {
            return Ok(None);
        };
        let bytes = unseal(|| format!("scene {hash}"), hash.as_bytes(), v.value())?;
        serde_json::from_slice(bytes)
            .map(Some)
            .map_err(|e| StoreError::Corrupt {
                what: format!("scene {hash}"),
                why: e.to_string(),
            })
    }

    /// One tile's merged sums, checked against its checksum: what a frame is written from for
    /// a tile whose sums left memory once stored. A tile that is not there is an error too.
    pub fn tile(&self, job: u64, tile: u32, rect: PixelRect) -> Result<TileSums, StoreError> {
        guarded(Path::new(FILE_NAME), || {
            let what = || format!("job {job} tile {tile}");
            let tx = self.db()?.begin_read().map_err(dberr)?;
            let tiles = tx.open_table(TILES).map_err(dberr)?;
            let v = tiles
                .get((job, tile))
                .map_err(dberr)?
                .ok_or_else(|| StoreError::Corrupt {
                    what: what(),
                    why: "missing (its sums left memory once stored)".into(),
                })?;
            let bytes = unseal(what, &tile_key(job, tile), v.value())?;
            decode_sums(bytes, rect).map_err(|why| StoreError::Corrupt { what: what(), why })
        })
    }

    /// The kept results of one tile of an audited job: batch → (merge serial, sums). A damaged
    /// one is left out (the caller renders it again), so a rebuild never folds in bits the
    /// store cannot vouch for.
    pub fn kept_units(
        &self,
        job: u64,
        tile: u32,
        rect: PixelRect,
    ) -> Result<BTreeMap<u32, (u64, TileSums)>, StoreError> {
        guarded(Path::new(FILE_NAME), || {
            let tx = self.db()?.begin_read().map_err(dberr)?;
            let units = tx.open_table(UNITS).map_err(dberr)?;
            let mut out = BTreeMap::new();
            for row in units
                .range((job, tile, 0)..=(job, tile, u32::MAX))
                .map_err(dberr)?
            {
                let (k, v) = row.map_err(dberr)?;
                let (_, _, b) = k.value();
                let what = || format!("job {job} tile {tile} kept batch {b}");
                let decoded = unseal(what, &unit_key(job, tile, b), v.value())
                    .map_err(|e| e.to_string())
                    .and_then(|bytes| {
                        let (serial, sums) = bytes
                            .split_first_chunk::<8>()
                            .ok_or("shorter than its serial")?;
                        Ok((u64::from_le_bytes(*serial), decode_sums(sums, rect)?))
                    });
                match decoded {
                    Ok(kept) => {
                        out.insert(b, kept);
                    }
                    Err(e) => tracing::warn!("job {job} tile {tile} kept batch {b}: {e}"),
                }
            }
            Ok(out)
        })
    }

    /// Every recorded conviction, oldest first.
    pub fn audits(&self) -> Result<Vec<AuditRecord>, StoreError> {
        let tx = self.db()?.begin_read().map_err(dberr)?;
        let audits = tx.open_table(AUDITS).map_err(dberr)?;
        let mut out = Vec::new();
        for row in audits.iter().map_err(dberr)? {
            let (k, v) = row.map_err(dberr)?;
            let (e, n) = k.value();
            let what = || format!("audit {e}-{n}");
            let bytes = unseal(what, &audit_key(e, n), v.value())?;
            out.push(
                serde_json::from_slice(bytes).map_err(|err| StoreError::Corrupt {
                    what: what(),
                    why: err.to_string(),
                })?,
            );
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sums_round_trip_bit_exactly() {
        let rect = PixelRect {
            x0: 3,
            y0: 4,
            width: 3,
            height: 2,
        };
        let mut t = TileSums::empty(rect, 16);
        t.samples = 16..32;
        for (i, s) in t.sum.iter_mut().enumerate() {
            *s = [i as f64 * 0.1, -0.0, f64::MIN_POSITIVE];
        }
        t.count[2] = 7;
        t.nonfinite = 9;
        let bytes = encode_sums(&t);
        assert_eq!(decode_sums(&bytes, rect), Ok(t.clone()));
        assert!(decode_sums(&bytes[1..], rect).is_err());
        // With AOV sums, each array distinct so that a swapped one shows.
        let mut a = tessera_render::film::AovSums::zeros(6);
        for i in 0..6 {
            let f = i as f64;
            a.albedo[i] = [f, f + 0.25, f + 0.5];
            a.normal[i] = [-f, 0.125, f * 3.0];
            a.depth[i] = 100.0 + f;
            a.hits[i] = i as u32;
            a.count[i] = 10 + i as u32;
        }
        t.aov = Some(Box::new(a));
        let bytes = encode_sums(&t);
        assert_eq!(decode_sums(&bytes, rect), Ok(t));
        assert!(decode_sums(&bytes[..bytes.len() - 1], rect).is_err());
    }

    #[test]
    fn store_survives_reopen_and_drops_sums() {
        let dir = tempfile::tempdir().expect("tempdir");
        let rec = JobRecord {
            id: 7,
            width: 4,
            height: 4,
            spp: 4,
            seed: 1,
            batch: 2,
            strategy: tessera_render::Strategy::Mis,
            tile_size: 64,
            output_name: "a.exr".into(),
            submitted_ms: 1,
            ..JobRecord::default()
        };
        {
            let store = Store::open(dir.path()).expect("open");
            assert_eq!(store.next_epoch().expect("epoch"), 1);
            store
                .apply(&[
                    Op::PutJob(rec.clone()),
                    Op::PutTile(7, 0, vec![1, 2]),
                    Op::PutPending(7, 0, 3, vec![3]),
                    Op::PutPending(8, 0, 3, vec![4]),
                ])
                .expect("apply");
        }
        let store = Store::open(dir.path()).expect("reopen");
        assert_eq!(store.next_epoch().expect("epoch"), 2);
        let jobs = store.load().expect("load");
        assert_eq!(jobs.len(), 1);
        assert_eq!(jobs[0].tiles, vec![(0, vec![1, 2])]);
        assert_eq!(jobs[0].pending, vec![((0, 3), vec![3])]);
        store.apply(&[Op::DropSums(7)]).expect("drop");
        let jobs = store.load().expect("load");
        assert!(jobs[0].tiles.is_empty() && jobs[0].pending.is_empty());
    }

    fn sample_store(dir: &Path) -> Vec<u8> {
        let store = Store::open(dir).expect("open");
        let rect = PixelRect {
            x0: 0,
            y0: 0,
            width: 8,
            height: 8,
        };
        let mut t = TileSums::empty(rect, 0);
        t.samples = 0..4;
        for (i, s) in t.sum.iter_mut().enumerate() {
            // A recognisable run of bytes to find in the file.
            *s = [1234.5678 + i as f64; 3];
        }
        let bytes = encode_sums(&t);
        store
            .apply(&[
                Op::PutJob(JobRecord {
                    id: 1,
                    ..JobRecord::default()
                }),
                Op::PutTile(1, 0, bytes.clone()),
            ])
            .expect("apply");
        bytes
    }

    #[test]
    fn a_flipped_bit_in_stored_sums_is_refused_on_load() {
        let dir = tempfile::tempdir().expect("tempdir");
        let bytes = sample_store(dir.path());
        let path = dir.path().join(FILE_NAME);
        let mut file = std::fs::read(&path).expect("read");
        let needle = &bytes[20..60];
        let at = file
            .windows(needle.len())
            .position(|w| w == needle)
            .expect("the sums are in the file");
        file[at + 9] ^= 0x10;
        std::fs::write(&path, &file).expect("write");
        let store = Store::open(dir.path()).expect("redb's own structures are intact");
        let err = store.load().err().expect("damaged sums must not load");
        assert!(err.to_string().contains("job 1 tile 0"), "{err}");
        assert!(err.to_string().contains("checksum"), "{err}");
    }

    #[cfg(unix)]
    #[test]
    fn a_new_data_directory_is_private() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().expect("tempdir");
        let data = dir.path().join("a/b");
        Store::open(&data).expect("open");
        let mode = std::fs::metadata(&data).expect("stat").permissions().mode() & 0o777;
        assert_eq!(mode, 0o700);
    }

    #[test]
    fn an_empty_store_file_is_refused_not_started_afresh() {
        let dir = tempfile::tempdir().expect("tempdir");
        sample_store(dir.path());
        std::fs::write(dir.path().join(FILE_NAME), b"").expect("truncate");
        let err = Store::open(dir.path()).err().expect("must refuse");
        assert!(err.to_string().contains("empty"), "{err}");
    }

    #[test]
    fn random_damage_is_an_error_or_the_same_data_never_a_panic_or_wrong_data() {
        let dir = tempfile::tempdir().expect("tempdir");
        sample_store(dir.path());
        let path = dir.path().join(FILE_NAME);
        let clean = std::fs::read(&path).expect("read");
        let want: Vec<(u32, Vec<u8>)> = Store::open(dir.path())
            .and_then(|s| s.load())
            .expect("clean load")
            .remove(0)
            .tiles;
        // A small deterministic generator: the same damage on every run.
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for flips in [1usize, 10, 100, 5000] {
            for _ in 0..8 {
                let mut file = clean.clone();
                for _ in 0..flips {
                    let i = (next() % file.len() as u64) as usize;
                    file[i] ^= 1 << (next() % 8);
                }
                std::fs::write(&path, &file).expect("write");
                let loaded = Store::open(dir.path()).and_then(|s| s.load());
                if let Ok(jobs) = loaded {
                    // Damage in unused space is harmless; anything loaded must be what was
                    // stored.
                    for j in jobs {
                        if j.record.id == 1 {
                            assert_eq!(j.tiles, want, "{flips} flips gave other sums");
                        }
                    }
                }
            }
        }
    }
}
