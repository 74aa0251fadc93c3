//! A job rebuilt after a restart from what the store held: its tiles' sums and early results,
//! the noise decisions made from them, and a guided job's epochs.

use std::sync::Arc;

use super::{add_noise, sums_in_range, Job, Source};
use crate::store::{decode_sums, JobPhase, LoadedJob};

impl Job {
    /// Rebuilds a job after a restart from what the store held.
    pub fn restore(loaded: LoadedJob) -> Result<Self, String> {
        let mut job = Self::new(loaded.record);
        if job.rec.phase != JobPhase::Active {
            return Ok(job);
        }
        for (tile, bytes) in loaded.tiles {
            let rect = job
                .tiles
                .get(tile)
                .ok_or_else(|| format!("tile {tile} is outside the job"))?;
            let sums = decode_sums(&bytes, rect).map_err(|e| format!("tile {tile}: {e}"))?;
            let batches = job.batches_through(sums.samples.end);
            if sums.samples.start != 0
                || job.batch_range(batches.saturating_sub(1)).end != sums.samples.end
            {
                return Err(format!(
                    "tile {tile}: sums cover samples {:?}",
                    sums.samples
                ));
            }
            job.units_done += batches as u64;
            job.samples_done += rect.area() as u64 * sums.samples.end as u64;
            job.nonfinite += sums.nonfinite;
            if batches > job.n_batches || !sums_in_range(&sums) {
                return Err(format!(
                    "tile {tile}: sums out of range for {} spp",
                    job.rec.spp
                ));
            }
            let audited = job.rec.audited;
            let acc = job.acc.entry(tile).or_default();
            acc.next = batches;
            if audited {
                acc.by = vec![Source::RESTORED; batches as usize];
            }
            acc.noise = sums.noise_parts();
            add_noise(&mut job.noise_total, acc.noise, 1.0);
            acc.sums = Some(Arc::new(sums));
        }
        for ((tile, batch), bytes) in loaded.pending {
            let rect = job
                .tiles
                .get(tile)
                .ok_or_else(|| format!("tile {tile} is outside the job"))?;
            let sums = decode_sums(&bytes, rect).map_err(|e| format!("tile {tile}: {e}"))?;
            if sums.samples != job.batch_range(batch) {
                return Err(format!(
                    "tile {tile} batch {batch}: samples {:?}",
                    sums.samples
                ));
            }
            job.units_done += 1;
            job.samples_done += rect.area() as u64 * sums.samples.len() as u64;
            job.nonfinite += sums.nonfinite;
            let audited = job.rec.audited;
            let acc = job.acc.entry(tile).or_default();
            acc.pending.insert(batch, sums);
            if audited {
                acc.pending_by.insert(batch, Source::RESTORED);
            }
        }
        // The decisions the merges made before the stop, made again from the same sums.
        let decided: Vec<u32> = job
            .acc
            .iter()
            .filter(|(_, a)| a.next >= job.first_batches)
            .map(|(t, _)| *t)
            .collect();
        job.pilots_in = decided.len() as u64;
        for &tile in &decided {
            let next = job.acc[&tile].next;
            job.units_planned += (next - job.first_batches) as u64;
        }
        if job.scale().is_some() {
            for tile in decided {
                job.decide(tile);
            }
        } else if job.pilots_in == job.tiles.len() as u64 && !job.past_pilot() {
            // Every pilot was in at the stop, and the scale not yet kept: the sums are the
            // pilots the scale is computed from.
            job.fix_scale();
        }
        if let Some(g) = &mut job.guiding {
            let hashes = job.rec.guiding.as_ref().map(|r| r.guides.clone());
            let n_tiles = job.tiles.len() as u64;
            let next = (0..n_tiles as u32).map(|t| job.acc.get(&t).map_or(0, |a| a.next));
            // Guides an epoch finished before the stop are in the record already; one this
            // finishes is recorded with the first commit.
            if !g
                .restore(
                    job.rec.id,
                    &hashes.unwrap_or_default(),
                    loaded.guides,
                    next,
                    n_tiles,
                )?
                .is_empty()
            {
                job.note_guides();
            }
        }
        job.started = job.units_done > 0;
        Ok(job)
    }

    /// Batches whose samples end at `end`, counted from the first (the next batch after a tile
    /// whose sums reach `end`).
    fn batches_through(&self, end: u32) -> u32 {
        match &self.guiding {
            Some(g) => g
                .ranges()
                .iter()
                .position(|r| r.end == end)
                .map_or(u32::MAX, |i| i as u32 + 1),
            None => end.div_ceil(self.rec.batch.max(1)),
        }
    }
}
