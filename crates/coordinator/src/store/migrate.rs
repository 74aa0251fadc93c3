//! Bringing a store of an earlier layout up to date.

use redb::{ReadableTable, Table};

use super::{dberr, job_key, pending_key, seal, tile_key, StoreError};

/// Layout 1 had the same values without checksums: seals each in place.
pub(super) fn seal_layout_1(
    scenes: &mut Table<&str, &[u8]>,
    jobs: &mut Table<u64, &[u8]>,
    tiles: &mut Table<(u64, u32), &[u8]>,
    pending: &mut Table<(u64, u32, u32), &[u8]>,
) -> Result<(), StoreError> {
    let all: Vec<(String, Vec<u8>)> = scenes
        .iter()
        .map_err(dberr)?
        .map(|r| r.map(|(k, v)| (k.value().to_string(), v.value().to_vec())))
        .collect::<Result<_, _>>()
        .map_err(dberr)?;
    for (k, v) in all {
        scenes
            .insert(k.as_str(), seal(k.as_bytes(), &v).as_slice())
            .map_err(dberr)?;
    }
    let all: Vec<(u64, Vec<u8>)> = jobs
        .iter()
        .map_err(dberr)?
        .map(|r| r.map(|(k, v)| (k.value(), v.value().to_vec())))
        .collect::<Result<_, _>>()
        .map_err(dberr)?;
    for (k, v) in all {
        jobs.insert(k, seal(&job_key(k), &v).as_slice())
            .map_err(dberr)?;
    }
    let all: Vec<((u64, u32), Vec<u8>)> = tiles
        .iter()
        .map_err(dberr)?
        .map(|r| r.map(|(k, v)| (k.value(), v.value().to_vec())))
        .collect::<Result<_, _>>()
        .map_err(dberr)?;
    for ((j, t), v) in all {
        tiles
            .insert((j, t), seal(&tile_key(j, t), &v).as_slice())
            .map_err(dberr)?;
    }
    let all: Vec<((u64, u32, u32), Vec<u8>)> = pending
        .iter()
        .map_err(dberr)?
        .map(|r| r.map(|(k, v)| (k.value(), v.value().to_vec())))
        .collect::<Result<_, _>>()
        .map_err(dberr)?;
    for ((j, t, b), v) in all {
        pending
            .insert((j, t, b), seal(&pending_key(j, t, b), &v).as_slice())
            .map_err(dberr)?;
    }
    Ok(())
}
