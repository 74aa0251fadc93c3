//! The bytes each table's checksum covers with a value: the table's key, tagged where two
//! tables' keys would otherwise look alike, so a value moved between them by damage is caught.

pub(super) fn job_key(id: u64) -> [u8; 8] {
    id.to_le_bytes()
}

pub(super) fn log_key(job: u64) -> [u8; 9] {
    let mut k = [b'l'; 9];
    k[1..].copy_from_slice(&job.to_le_bytes());
    k
}

pub(super) fn tile_key(job: u64, tile: u32) -> [u8; 12] {
    let mut k = [0u8; 12];
    k[..8].copy_from_slice(&job.to_le_bytes());
    k[8..].copy_from_slice(&tile.to_le_bytes());
    k
}

pub(super) fn pending_key(job: u64, tile: u32, batch: u32) -> [u8; 16] {
    let mut k = [0u8; 16];
    k[..12].copy_from_slice(&tile_key(job, tile));
    k[12..].copy_from_slice(&batch.to_le_bytes());
    k
}

/// The checksummed key of a kept unit: the pending key's bytes under another table's tag, so
/// that a value moved between the two tables by damage is caught too.
pub(super) fn unit_key(job: u64, tile: u32, batch: u32) -> [u8; 17] {
    let mut k = [b'u'; 17];
    k[1..].copy_from_slice(&pending_key(job, tile, batch));
    k
}

pub(super) fn audit_key(epoch: u64, n: u64) -> [u8; 17] {
    let mut k = [b'a'; 17];
    k[1..9].copy_from_slice(&epoch.to_le_bytes());
    k[9..].copy_from_slice(&n.to_le_bytes());
    k
}

/// A guided job's tree of one epoch: the tile key's bytes under its own tag.
pub(super) fn guide_key(job: u64, epoch: u32) -> [u8; 13] {
    let mut k = [b'g'; 13];
    k[1..].copy_from_slice(&tile_key(job, epoch));
    k
}
