//! Durable coordinator state in redb: scenes by hash, job records, each tile's merged sums and
//! the results that arrived ahead of their turn. Every change a reply depends on is committed
//! (fsync) before the reply is sent, so a restart resumes exactly where the last
//! acknowledged result left it.

use std::ops::Range;
use std::path::Path;

use redb::{Database, ReadableDatabase, ReadableTable, TableDefinition};
use serde::{Deserialize, Serialize};
use tessera_render::{PixelRect, TileSums};

/// Scene hash → [`StoredScene`] (JSON).
const SCENES: TableDefinition<&str, &[u8]> = TableDefinition::new("scenes");
/// Job id → [`JobRecord`] (JSON).
const JOBS: TableDefinition<u64, &[u8]> = TableDefinition::new("jobs");
/// (job, tile) → merged sums of batches `0..next` ([`encode_sums`]).
const TILES: TableDefinition<(u64, u32), &[u8]> = TableDefinition::new("tiles");
/// (job, tile, batch) → a result that arrived before its predecessors were merged.
const PENDING: TableDefinition<(u64, u32, u32), &[u8]> = TableDefinition::new("pending");
/// Counters.
const META: TableDefinition<&str, u64> = TableDefinition::new("meta");

/// Why the store failed.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// redb reported an error.
    #[error("state store: {0}")]
    Db(#[from] redb::Error),
    /// A stored record does not decode (a corrupt or foreign file).
    #[error("state store: corrupt record {what}: {why}")]
    Corrupt {
        /// Which record.
        what: String,
        /// What is wrong with it.
        why: String,
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

fn dberr<E: Into<redb::Error>>(e: E) -> StoreError {
    StoreError::Db(e.into())
}

/// A scene as stored: its text, format and the name it was first submitted under.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StoredScene {
    /// Scene text.
    pub text: String,
    /// True for JSON, false for TOML.
    pub json: bool,
    /// Name for error messages.
    pub name: String,
}

/// Lifecycle state of a job, as stored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum JobPhase {
    /// Accepted; units not all merged yet.
    #[default]
    Active,
    /// Finished; the EXR is written.
    Done,
    /// Cancelled by a client.
    Cancelled,
    /// Stopped by an error.
    Failed,
}

/// Everything about a job that must survive a restart, besides its sums. The default is an
/// active, empty job, for building records field by field.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct JobRecord {
    /// Numeric id (shown as `job-NNNNNN`).
    pub id: u64,
    /// Scene content hash.
    pub scene_hash: String,
    /// Scene name as submitted.
    pub scene_name: String,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Seed.
    pub seed: u64,
    /// Samples per batch.
    pub batch: u32,
    /// Strategy name (`mis`, `bsdf`, `nee`).
    pub strategy: String,
    /// Tile edge.
    pub tile_size: u32,
    /// Output file name.
    pub output_name: String,
    /// Priority (higher first).
    pub priority: i32,
    /// Write variance channels.
    pub variance: bool,
    /// Write the sample-count channel.
    pub sample_count: bool,
    /// State.
    pub phase: JobPhase,
    /// Why it failed.
    pub error: String,
    /// Submission time, Unix ms.
    pub submitted_ms: i64,
    /// End time, Unix ms (0 while active).
    pub finished_ms: i64,
    /// Final noise estimate (RMS standard error, relative), kept once the sums are dropped.
    #[serde(default)]
    pub final_noise: (f64, f64),
    /// The renderer image revision whose results the job's sums hold
    /// ([`tessera_render::IMAGE_REVISION`] of the coordinator that accepted it; 0 in records
    /// written before revisions were recorded).
    #[serde(default)]
    pub image_revision: u32,
}

/// One change to the store; a list of them is committed as one transaction.
#[derive(Debug)]
pub enum Op {
    /// Store a scene if its hash is new.
    PutScene(String, StoredScene),
    /// Write a job record.
    PutJob(JobRecord),
    /// Write a tile's merged sums.
    PutTile(u64, u32, Vec<u8>),
    /// Keep an early result.
    PutPending(u64, u32, u32, Vec<u8>),
    /// Forget an early result (it has been merged).
    DelPending(u64, u32, u32),
    /// Forget every sum of a job (it has ended).
    DropSums(u64),
}

/// A job as loaded at start-up.
pub struct LoadedJob {
    /// Its record.
    pub record: JobRecord,
    /// (tile, merged sums) for the tiles that have any.
    pub tiles: Vec<(u32, Vec<u8>)>,
    /// ((tile, batch), sums) waiting for their turn.
    pub pending: Vec<((u32, u32), Vec<u8>)>,
}

/// The coordinator's redb database.
pub struct Store {
    db: Database,
}

impl Store {
    /// Opens (or creates) `dir/coordinator.redb`.
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        std::fs::create_dir_all(dir).map_err(|source| StoreError::Io {
            path: dir.display().to_string(),
            source,
        })?;
        let db = Database::create(dir.join("coordinator.redb")).map_err(dberr)?;
        let tx = db.begin_write().map_err(dberr)?;
        {
            // Create every table so readers never meet a missing one.
            tx.open_table(SCENES).map_err(dberr)?;
            tx.open_table(JOBS).map_err(dberr)?;
            tx.open_table(TILES).map_err(dberr)?;
            tx.open_table(PENDING).map_err(dberr)?;
            tx.open_table(META).map_err(dberr)?;
        }
        tx.commit().map_err(dberr)?;
        Ok(Self { db })
    }

    /// Increments and returns the boot counter, which makes lease and worker ids unique across
    /// restarts.
    pub fn next_epoch(&self) -> Result<u64, StoreError> {
        let tx = self.db.begin_write().map_err(dberr)?;
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

    /// Every job with its stored sums.
    pub fn load(&self) -> Result<Vec<LoadedJob>, StoreError> {
        let tx = self.db.begin_read().map_err(dberr)?;
        let jobs = tx.open_table(JOBS).map_err(dberr)?;
        let tiles = tx.open_table(TILES).map_err(dberr)?;
        let pending = tx.open_table(PENDING).map_err(dberr)?;
        let mut out = Vec::new();
        for row in jobs.iter().map_err(dberr)? {
            let (k, v) = row.map_err(dberr)?;
            let id = k.value();
            let record: JobRecord =
                serde_json::from_slice(v.value()).map_err(|e| StoreError::Corrupt {
                    what: format!("job {id}"),
                    why: e.to_string(),
                })?;
            let mut job = LoadedJob {
                record,
                tiles: Vec::new(),
                pending: Vec::new(),
            };
            for row in tiles.range((id, 0)..=(id, u32::MAX)).map_err(dberr)? {
                let (k, v) = row.map_err(dberr)?;
                job.tiles.push((k.value().1, v.value().to_vec()));
            }
            for row in pending
                .range((id, 0, 0)..=(id, u32::MAX, u32::MAX))
                .map_err(dberr)?
            {
                let (k, v) = row.map_err(dberr)?;
                let (_, t, b) = k.value();
                job.pending.push(((t, b), v.value().to_vec()));
            }
            out.push(job);
        }
        Ok(out)
    }

    /// A stored scene.
    pub fn scene(&self, hash: &str) -> Result<Option<StoredScene>, StoreError> {
        let tx = self.db.begin_read().map_err(dberr)?;
        let scenes = tx.open_table(SCENES).map_err(dberr)?;
        let Some(v) = scenes.get(hash).map_err(dberr)? else {
            return Ok(None);
        };
        serde_json::from_slice(v.value())
            .map(Some)
            .map_err(|e| StoreError::Corrupt {
                what: format!("scene {hash}"),
                why: e.to_string(),
            })
    }

    /// Applies `ops` in order as one durable transaction.
    pub fn apply(&self, ops: &[Op]) -> Result<(), StoreError> {
        let tx = self.db.begin_write().map_err(dberr)?;
        {
            let mut scenes = tx.open_table(SCENES).map_err(dberr)?;
            let mut jobs = tx.open_table(JOBS).map_err(dberr)?;
            let mut tiles = tx.open_table(TILES).map_err(dberr)?;
            let mut pending = tx.open_table(PENDING).map_err(dberr)?;
            for op in ops {
                match op {
                    Op::PutScene(hash, scene) => {
                        if scenes.get(hash.as_str()).map_err(dberr)?.is_none() {
                            let bytes =
                                serde_json::to_vec(scene).map_err(|e| StoreError::Corrupt {
                                    what: format!("scene {hash}"),
                                    why: e.to_string(),
                                })?;
                            scenes
                                .insert(hash.as_str(), bytes.as_slice())
                                .map_err(dberr)?;
                        }
                    }
                    Op::PutJob(record) => {
                        let bytes =
                            serde_json::to_vec(record).map_err(|e| StoreError::Corrupt {
                                what: format!("job {}", record.id),
                                why: e.to_string(),
                            })?;
                        jobs.insert(record.id, bytes.as_slice()).map_err(dberr)?;
                    }
                    Op::PutTile(job, tile, bytes) => {
                        tiles
                            .insert((*job, *tile), bytes.as_slice())
                            .map_err(dberr)?;
                    }
                    Op::PutPending(job, tile, batch, bytes) => {
                        pending
                            .insert((*job, *tile, *batch), bytes.as_slice())
                            .map_err(dberr)?;
                    }
                    Op::DelPending(job, tile, batch) => {
                        pending.remove((*job, *tile, *batch)).map_err(dberr)?;
                    }
                    Op::DropSums(job) => {
                        tiles
                            .retain_in((*job, 0)..=(*job, u32::MAX), |_, _| false)
                            .map_err(dberr)?;
                        pending
                            .retain_in((*job, 0, 0)..=(*job, u32::MAX, u32::MAX), |_, _| false)
                            .map_err(dberr)?;
                    }
                }
            }
        }
        tx.commit().map_err(dberr)?;
        Ok(())
    }
}

/// Serialises partial sums: sample range, non-finite count, then the f64 and u32 arrays,
/// little-endian. The rectangle is the job's business and is not stored.
pub fn encode_sums(t: &TileSums) -> Vec<u8> {
    let n = t.sum.len();
    let mut out = Vec::with_capacity(20 + n * 52);
    out.extend_from_slice(&t.samples.start.to_le_bytes());
    out.extend_from_slice(&t.samples.end.to_le_bytes());
    out.extend_from_slice(&t.nonfinite.to_le_bytes());
    out.extend_from_slice(&(n as u32).to_le_bytes());
    for v in t.sum.iter().chain(&t.sum_sq) {
        for c in v {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for c in &t.count {
        out.extend_from_slice(&c.to_le_bytes());
    }
    out
}

/// Inverse of [`encode_sums`] for a tile of rectangle `rect`.
pub fn decode_sums(bytes: &[u8], rect: PixelRect) -> Result<TileSums, String> {
    let n = rect.area();
    if bytes.len() != 20 + n * 52 {
        return Err(format!(
            "{} bytes where a {}×{} tile needs {}",
            bytes.len(),
            rect.width,
            rect.height,
            20 + n * 52
        ));
    }
    let u32_at =
        |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let u64_at = |o: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&bytes[o..o + 8]);
        u64::from_le_bytes(b)
    };
    if u32_at(16) as usize != n {
        return Err(format!("pixel count {} where the tile has {n}", u32_at(16)));
    }
    let samples: Range<u32> = u32_at(0)..u32_at(4);
    let f = |i: usize| f64::from_bits(u64_at(20 + 8 * i));
    let sum = (0..n)
        .map(|p| [f(3 * p), f(3 * p + 1), f(3 * p + 2)])
        .collect();
    let sum_sq = (0..n)
        .map(|p| [f(3 * (n + p)), f(3 * (n + p) + 1), f(3 * (n + p) + 2)])
        .collect();
    let count = (0..n).map(|p| u32_at(20 + 48 * n + 4 * p)).collect();
    Ok(TileSums {
        rect,
        samples,
        sum,
        sum_sq,
        count,
        nonfinite: u64_at(8),
    })
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
        assert_eq!(decode_sums(&bytes, rect), Ok(t));
        assert!(decode_sums(&bytes[1..], rect).is_err());
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
            strategy: "mis".into(),
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
}
