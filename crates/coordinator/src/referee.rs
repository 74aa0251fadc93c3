//! The coordinator's own render of an audited unit: the referee of disputes.
//!
//! An audit compares two workers' copies of a unit, from different hosts. When they differ,
//! counting more workers' votes cannot be trusted (one token holder can register any number
//! of workers that lie alike), and waiting for a third host can wait for ever on a farm of
//! two. Rendering is deterministic, so the coordinator renders the unit itself and compares:
//! whoever differs from its render is convicted ([`Scheduler::referee`]). It renders only what
//! audits send it (a dispute, or a held copy no other host took within a lease time), one unit
//! at a time, so a liar costs it one unit's render before its conviction.
//!
//! [`Scheduler::referee`]: crate::scheduler::Scheduler::referee

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use tessera_proto::ids::JobId;
use tessera_render::guiding::render_tile_guided;
use tessera_render::render_tile;
use tessera_render::scene::{Format, Scene};
use tracing::{info, warn};

use crate::assets::JobAssets;
use crate::job::Unit;
use crate::output::finish_job;
use crate::scheduler::{Merged, UnitResult};
use crate::shared::{durable, now_ms, Shared};
use crate::store::JobPhase;

/// One referee render at a time: they are rare, and each may take every core for a moment.
static ONE_AT_A_TIME: tokio::sync::Semaphore = tokio::sync::Semaphore::const_new(1);

/// Starts a render for every unit the scheduler wants refereed.
pub(crate) fn spawn_pending(shared: &Arc<Shared>) {
    let wanted = shared.scheduler().take_referee_work();
    for (job, unit) in wanted {
        tokio::spawn(settle(shared.clone(), job, unit));
    }
}

/// Renders `unit` of `job` here and hands it to the scheduler, which convicts whoever's copy
/// differs; a job whose unit cannot be rendered here fails with the reason.
async fn settle(shared: Arc<Shared>, job: JobId, unit: Unit) {
    let Ok(_turn) = ONE_AT_A_TIME.acquire().await else {
        return;
    };
    let gathered = {
        let core = shared.scheduler();
        core.job(job).filter(|j| j.is_live()).and_then(|j| {
            // A guided unit renders with its epoch's guide and records into its structure,
            // as a worker's does (decoded here, under the lock: referee renders are rare).
            let guided = j.guiding.as_ref().map(|g| g.unit_inputs(unit.batch));
            Some((
                j.rec.scene_hash.clone(),
                j.settings(),
                j.tiles.get(unit.tile)?,
                j.batch_range(unit.batch),
                guided,
            ))
        })
    };
    let Some((hash, settings, rect, samples, guided)) = gathered else {
        return;
    };
    let limits = shared.config.limits.clone();
    let (store, assets) = (shared.store.clone(), shared.assets.clone());
    let rendered = tokio::task::spawn_blocking(move || {
        let stored = store
            .scene(&hash)
            .map_err(|e| e.to_string())?
            .ok_or_else(|| format!("scene {hash} is not in the store"))?;
        let files = JobAssets {
            store: &assets,
            names: stored.assets.iter().cloned().collect::<BTreeMap<_, _>>(),
        };
        let format = if stored.json {
            Format::Json
        } else {
            Format::Toml
        };
        let scene = Scene::text(&stored.text, format, &stored.name, &limits)
            .at(settings.shot())
            .assets(&files)
            .load()
            .map_err(|e| e.to_string())?;
        if scene.hash != hash {
            return Err(format!("scene {hash} loads with hash {}", scene.hash));
        }
        Ok(match guided {
            None => UnitResult::from(render_tile(&scene, &settings, rect, samples)),
            Some(inputs) => {
                let (guide, train) = inputs?;
                let (sums, train) = render_tile_guided(
                    &scene,
                    &settings,
                    rect,
                    samples,
                    guide.as_ref(),
                    train.as_ref(),
                );
                UnitResult { sums, train }
            }
        })
    })
    .await
    .map_err(|e| e.to_string())
    .and_then(|r| r);
    let rx = {
        let mut core = shared.scheduler();
        match rendered {
            Ok(result) => {
                match core.referee(job, unit, result, Instant::now(), &*shared.store, now_ms()) {
                    Ok(Merged::New { ops, finished }) => {
                        info!(
                            "{job} tile {} batch {}: settled by the coordinator's own render",
                            unit.tile, unit.batch
                        );
                        Some((shared.queue_write(ops), finished))
                    }
                    Ok(_) => None,
                    Err(e) => {
                        warn!("{job}: the referee's result was refused: {e:?}");
                        None
                    }
                }
            }
            Err(e) => {
                let why = format!(
                    "the coordinator could not render tile {} batch {} to settle its audit: {e}",
                    unit.tile, unit.batch
                );
                warn!("{job}: {why}");
                let ops = core.end_job(job, JobPhase::Failed, why, now_ms());
                Some((shared.queue_write(ops), false))
            }
        }
    };
    if let Some((rx, finished)) = rx {
        if let Err(e) = durable(rx).await {
            warn!("{job}: recording the referee's result: {e}");
            return;
        }
        if finished {
            tokio::spawn(finish_job(shared.clone(), job));
        }
    }
    shared.bump_work();
    shared.bump_changed();
}
