//! What the store holds, as the rest of the coordinator sees it: scenes, job records and their
//! phases, audit records, the changes a commit applies ([`Op`]), and a job as loaded at
//! start-up. Serialised with serde (the store seals every value with its checksum).

use serde::{Deserialize, Serialize};

/// A scene as stored: its text, format and the name it was first submitted under.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StoredScene {
    /// Scene text.
    pub text: String,
    /// True for JSON, false for TOML.
    pub json: bool,
    /// Name for error messages.
    pub name: String,
    /// The files the scene read (name, SHA-256), which its hash covers; none for scenes
    /// stored before files existed.
    #[serde(default)]
    pub assets: Vec<(String, String)>,
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
    /// Direct-lighting strategy (stored by name: `mis`, `bsdf`, `nee`).
    pub strategy: tessera_render::Strategy,
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
    /// JSON has no infinity or NaN: such a value would be written as `null` and then refuse to
    /// load, so a non-finite one is stored as 0, and a `null` read as 0.
    #[serde(
        default,
        serialize_with = "finite_pair",
        deserialize_with = "lenient_pair"
    )]
    pub final_noise: (f64, f64),
    /// The renderer image revision whose results the job's sums hold
    /// ([`tessera_render::IMAGE_REVISION`] of the coordinator that accepted it; 0 in records
    /// written before revisions were recorded).
    #[serde(default)]
    pub image_revision: u32,
    /// Noise target of an adaptive job (0: every pixel takes `spp` samples; absent in records
    /// written before adaptive sampling, which had none).
    #[serde(default)]
    pub noise_target: f64,
    /// Units and samples merged, kept once the job is done (an adaptive job's tiles stop at
    /// different counts; (0, 0) in records written before adaptive sampling).
    #[serde(default)]
    pub final_counts: (u64, u64),
    /// The frame of the scene's `[animation]` the job renders (`None`: none named, and no
    /// frame in the EXR's header).
    #[serde(default)]
    pub frame: Option<u32>,
    /// The film's size when it is not the scene file's (`--resolution`): the scene is built at
    /// it (none in records written before the flag).
    #[serde(default)]
    pub resolution: Option<(u32, u32)>,
    /// Audited: every unit's result is kept until the job ends ([`Op::PutUnit`]), and a
    /// fraction of its units is rendered twice (false in records written before audits).
    #[serde(default)]
    pub audited: bool,
    /// The frame-range job this frame belongs to, if any: its id (taken from the job ids, but
    /// no job of its own: the range is its frames) and the frames it renders. Every frame
    /// keeps it, so a restart rebuilds the range from its frames' records alone.
    #[serde(default)]
    pub range: Option<RangeRef>,
    /// An adaptive job's Neyman scale ([`tessera_render::adaptive::neyman_scale`]), set once
    /// every tile's pilot is merged. Kept because it cannot be computed again once tiles have
    /// gone past their pilots; JSON writes an f64 so that it reads back to the same bits.
    #[serde(default)]
    pub adaptive_scale: Option<f64>,
    /// The AOVs the job renders beside the beauty, as [`tessera_render::Aovs::list`] writes
    /// them (empty: none, as in records written before AOVs).
    #[serde(default)]
    pub aovs: String,
    /// What the finished image was flagged for, set when its EXR is written (none in records
    /// written before the checks, and while the job is active).
    #[serde(default)]
    pub checks: tessera_render::OutputChecks,
    /// The job (or frame-range job) this one starts after (`submit --after`); `None` for none,
    /// as in records written before dependencies.
    #[serde(default)]
    pub after: Option<u64>,
    /// Tags a worker must have to take its units (`submit --require`; see
    /// [`tessera_proto::tags`]); empty for none, as in records written before requirements.
    #[serde(default)]
    pub require: Vec<String>,
    /// Least memory, in bytes, a worker must report to take its units (0: any).
    #[serde(default)]
    pub min_memory: u64,
    /// Units that failed on workers (`ReleaseLeases.cannot_render`), at most the frame's limit.
    #[serde(default)]
    pub failures: Vec<UnitFailure>,
    /// Names of the workers blocklisted for it after failing its units.
    #[serde(default)]
    pub blocklist: Vec<String>,
    /// A frame of a range leased progressively (`submit --progressive`): it hands out a batch
    /// only once every frame of its range has handed out the batches before it.
    #[serde(default)]
    pub progressive: bool,
    /// Paused (`tessera pause`): leased nothing new until resumed (false in records written
    /// before pausing).
    #[serde(default)]
    pub paused: bool,
    /// Times `tessera retry` put it back after it failed (0 in records written before retries).
    #[serde(default)]
    pub retries: u32,
    /// Path guiding (`submit --guiding`): the box its guides start from (the scene's, at
    /// admission), and the hashes of the guides its finished epochs trained, in order (none
    /// for an unguided job, as in records written before guiding).
    #[serde(default)]
    pub guiding: Option<GuidingRecord>,
    /// The user whose token submitted it (empty: no named tokens, as in records written
    /// before them): fair share and the per-user cap count by it, and only that user or an
    /// admin may change the job.
    #[serde(default)]
    pub submitter: String,
    /// Denoised after its last merge (`submit --denoise`): the filter's quality and whether
    /// it filters as HDR (none for a job without, as in records written before denoising).
    #[serde(default)]
    pub denoise: Option<DenoiseRecord>,
}

/// How a job's frame is denoised, as its record keeps it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DenoiseRecord {
    /// `fast`, `balanced` or `high`.
    pub quality: String,
    /// Filtered as HDR (linear radiance).
    pub hdr: bool,
}

/// A guided job's epochs, as its record keeps them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GuidingRecord {
    /// The box epoch 0's structure spans (JSON writes f32s that read back to the same bits).
    pub bounds: [[f32; 3]; 2],
    /// SHA-256 of each finished epoch's guide, epoch by epoch.
    pub guides: Vec<String>,
}

/// One unit that failed on one worker (`scheduler/failures.rs`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UnitFailure {
    /// The worker's name (what a blocklist holds).
    pub worker: String,
    /// Its public id at the time.
    pub worker_id: String,
    /// The unit's tile.
    pub tile: u32,
    /// The unit's batch.
    pub batch: u32,
    /// Why, as the worker said it.
    pub reason: String,
    /// When, Unix milliseconds.
    pub unix_ms: i64,
    /// The machine it failed on: the worker's registration address, or its name where that
    /// is unknown (empty in records written before machines were kept: the name stands in).
    #[serde(default)]
    pub machine: String,
}

impl UnitFailure {
    /// The machine the frame's failure limit counts it against.
    pub fn machine(&self) -> &str {
        if self.machine.is_empty() {
            &self.worker
        } else {
            &self.machine
        }
    }
}

/// A frame-range job, as each of its frames records it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RangeRef {
    /// The range's job id.
    pub id: u64,
    /// Its frames.
    pub frames: tessera_render::scene::FrameRange,
}

fn finite_pair<S: serde::Serializer>(v: &(f64, f64), s: S) -> Result<S::Ok, S::Error> {
    let f = |x: f64| if x.is_finite() { x } else { 0.0 };
    (f(v.0), f(v.1)).serialize(s)
}

fn lenient_pair<'de, D: serde::Deserializer<'de>>(d: D) -> Result<(f64, f64), D::Error> {
    let (a, b) = <(Option<f64>, Option<f64>)>::deserialize(d)?;
    Ok((a.unwrap_or(0.0), b.unwrap_or(0.0)))
}

/// One change to the store; a list of them is committed as one transaction.
#[derive(Debug)]
// A record is a few hundred bytes and the ops live only from a change to its commit; boxing
// would allocate for every record written to save memory on a list that is short-lived.
#[allow(clippy::large_enum_variant)]
pub enum Op {
    /// Store a scene if its hash is new.
    PutScene(String, StoredScene),
    /// Write a job record.
    PutJob(JobRecord),
    /// Write a tile's merged sums.
    PutTile(u64, u32, Vec<u8>),
    /// Keep an early result.
    PutPending(u64, u32, u32, Vec<u8>),
    /// Forget an early result (it has been merged, or it came from a convicted worker).
    DelPending(u64, u32, u32),
    /// Forget a tile's merged sums (an audit took every batch of it back).
    DelTile(u64, u32),
    /// Keep one unit's result of an audited job, with its merge's serial (table `units`).
    PutUnit(u64, u32, u32, u64, Vec<u8>),
    /// Record a conviction.
    PutAudit(AuditRecord),
    /// Forget every sum of a job (it has ended).
    DropSums(u64),
    /// Forget a scene no live job uses (the job that used it has ended).
    DropScene(String),
    /// Write a job's log (its workers' lines, JSON; table `logs`).
    PutLog(u64, Vec<u8>),
    /// Forget a job's log (its retention has passed).
    DropLog(u64),
    /// Forget an ended job's record (its retention has passed; its sums and log are dropped
    /// by their own ops).
    DropJob(u64),
    /// Write a guided job's tree of one epoch (table `guides`): the guide it trained once the
    /// epoch is done, or its training tree as merged so far.
    PutGuide(u64, u32, Vec<u8>),
}

impl Op {
    /// The (job, tile) whose merged sums this op writes, if it writes a tile's: what a
    /// committed checkpoint lets leave memory.
    pub fn written_tile(&self) -> Option<(u64, u32)> {
        match self {
            Op::PutTile(j, t, _) => Some((*j, *t)),
            _ => None,
        }
    }

    /// Bytes of the value this op writes, before sealing (0 for a deletion): what metrics
    /// count as written.
    pub fn payload_len(&self) -> u64 {
        match self {
            Op::PutScene(_, scene) => scene.text.len() as u64,
            Op::PutTile(_, _, b)
            | Op::PutPending(_, _, _, b)
            | Op::PutUnit(_, _, _, _, b)
            | Op::PutLog(_, b)
            | Op::PutGuide(_, _, b) => b.len() as u64,
            // Records are a few hundred bytes of JSON: counted as their fixed overhead only.
            Op::PutJob(_) | Op::PutAudit(_) => 256,
            Op::DelPending(..)
            | Op::DelTile(..)
            | Op::DropSums(_)
            | Op::DropScene(_)
            | Op::DropLog(_)
            | Op::DropJob(_) => 0,
        }
    }
}

/// A worker an audit convicted: two other workers rendered one of its units to other bits.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AuditRecord {
    /// The coordinator's boot when it happened.
    pub epoch: u64,
    /// Conviction number within that boot.
    pub n: u64,
    /// Unix ms.
    pub time_ms: i64,
    /// The worker's public id.
    pub worker: String,
    /// The name it gave.
    pub name: String,
    /// The unit the audit caught it on: job, tile, batch.
    pub caught_on: (u64, u32, u32),
    /// Units of live jobs taken back to be rendered again: its own, and those whose tile had
    /// to be folded again without a stored copy.
    pub units_requeued: u64,
    /// Live jobs whose sums were rebuilt.
    pub jobs_rebuilt: Vec<u64>,
    /// Jobs it contributed to that had already finished: their images may hold its results.
    pub jobs_finished: Vec<u64>,
}

/// A job as loaded at start-up.
pub struct LoadedJob {
    /// Its record.
    pub record: JobRecord,
    /// (tile, merged sums) for the tiles that have any.
    pub tiles: Vec<(u32, Vec<u8>)>,
    /// ((tile, batch), sums) waiting for their turn.
    pub pending: Vec<((u32, u32), Vec<u8>)>,
    /// Its log as stored (JSON), if it has one and is active: an ended job's log stays in the
    /// store, read when asked for ([`crate::store::Store::log`]).
    pub log: Option<Vec<u8>>,
    /// Bytes of its stored log (0: none), for the logs' retention.
    pub log_bytes: u64,
    /// A guided job's trees by epoch (`Op::PutGuide`).
    pub guides: Vec<(u32, Vec<u8>)>,
}
