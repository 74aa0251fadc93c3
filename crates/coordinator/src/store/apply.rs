//! Writing: one list of [`Op`]s committed in order as one durable transaction, each value
//! sealed with its key's checksum.

use super::*;

impl Store {
    /// Applies `ops` in order as one durable transaction.
    pub fn apply(&self, ops: &[Op]) -> Result<(), StoreError> {
        let tx = self.db()?.begin_write().map_err(dberr)?;
        {
            let mut scenes = tx.open_table(SCENES).map_err(dberr)?;
            let mut jobs = tx.open_table(JOBS).map_err(dberr)?;
            let mut tiles = tx.open_table(TILES).map_err(dberr)?;
            let mut pending = tx.open_table(PENDING).map_err(dberr)?;
            let mut units = tx.open_table(UNITS).map_err(dberr)?;
            let mut audits = tx.open_table(AUDITS).map_err(dberr)?;
            let mut logs = tx.open_table(LOGS).map_err(dberr)?;
            let mut guides = tx.open_table(GUIDES).map_err(dberr)?;
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
                                .insert(hash.as_str(), seal(hash.as_bytes(), &bytes).as_slice())
                                .map_err(dberr)?;
                        }
                    }
                    Op::PutJob(record) => {
                        let bytes =
                            serde_json::to_vec(record).map_err(|e| StoreError::Corrupt {
                                what: format!("job {}", record.id),
                                why: e.to_string(),
                            })?;
                        jobs.insert(record.id, seal(&job_key(record.id), &bytes).as_slice())
                            .map_err(dberr)?;
                    }
                    Op::PutTile(job, tile, bytes) => {
                        tiles
                            .insert(
                                (*job, *tile),
                                seal(&tile_key(*job, *tile), bytes).as_slice(),
                            )
                            .map_err(dberr)?;
                    }
                    Op::PutPending(job, tile, batch, bytes) => {
                        pending
                            .insert(
                                (*job, *tile, *batch),
                                seal(&pending_key(*job, *tile, *batch), bytes).as_slice(),
                            )
                            .map_err(dberr)?;
                    }
                    Op::DelPending(job, tile, batch) => {
                        pending.remove((*job, *tile, *batch)).map_err(dberr)?;
                    }
                    Op::DelTile(job, tile) => {
                        tiles.remove((*job, *tile)).map_err(dberr)?;
                    }
                    Op::PutUnit(job, tile, batch, serial, bytes) => {
                        let mut value = serial.to_le_bytes().to_vec();
                        value.extend_from_slice(bytes);
                        units
                            .insert(
                                (*job, *tile, *batch),
                                seal(&unit_key(*job, *tile, *batch), &value).as_slice(),
                            )
                            .map_err(dberr)?;
                    }
                    Op::PutAudit(r) => {
                        let bytes = serde_json::to_vec(r).map_err(|e| StoreError::Corrupt {
                            what: format!("audit {}-{}", r.epoch, r.n),
                            why: e.to_string(),
                        })?;
                        audits
                            .insert(
                                (r.epoch, r.n),
                                seal(&audit_key(r.epoch, r.n), &bytes).as_slice(),
                            )
                            .map_err(dberr)?;
                    }
                    Op::PutLog(job, bytes) => {
                        logs.insert(*job, seal(&log_key(*job), bytes).as_slice())
                            .map_err(dberr)?;
                    }
                    Op::DropLog(job) => {
                        logs.remove(*job).map_err(dberr)?;
                    }
                    Op::DropJob(job) => {
                        jobs.remove(*job).map_err(dberr)?;
                    }
                    Op::PutGuide(job, e, bytes) => {
                        guides
                            .insert((*job, *e), seal(&guide_key(*job, *e), bytes).as_slice())
                            .map_err(dberr)?;
                    }
                    Op::DropScene(hash) => {
                        scenes.remove(hash.as_str()).map_err(dberr)?;
                    }
                    Op::DropSums(job) => {
                        tiles
                            .retain_in((*job, 0)..=(*job, u32::MAX), |_, _| false)
                            .map_err(dberr)?;
                        pending
                            .retain_in((*job, 0, 0)..=(*job, u32::MAX, u32::MAX), |_, _| false)
                            .map_err(dberr)?;
                        units
                            .retain_in((*job, 0, 0)..=(*job, u32::MAX, u32::MAX), |_, _| false)
                            .map_err(dberr)?;
                        guides
                            .retain_in((*job, 0)..=(*job, u32::MAX), |_, _| false)
                            .map_err(dberr)?;
                    }
                }
            }
        }
        tx.commit().map_err(dberr)?;
        Ok(())
    }
}
