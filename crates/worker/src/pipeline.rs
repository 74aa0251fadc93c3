//! The pipeline that keeps the cores busy: the fetcher leases the next unit while the current
//! one renders, the renderer runs units on the worker's rayon pool through `spawn_blocking`,
//! the submitter sends results (retrying through network errors), and the heartbeat renews
//! the leases held.

use std::future::Future;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use tessera_proto::convert::settings_from_wire;
use tessera_proto::v1 as pb;
use tessera_render::guiding::render_tile_guided;
use tessera_render::scene::Scene;
use tessera_render::{render_tile, PixelRect, RenderSettings, TileSums};
use tokio::sync::{mpsc, watch, OwnedSemaphorePermit, Semaphore};
use tracing::{debug, info, warn};

use crate::cache::{SceneCache, SceneError};
use crate::guide_cache::{GuideCache, Guided};
use crate::session::{backoff_delay, lock, transient, Session};

/// What the pipeline's tasks share: the session with the coordinator, the scenes and guides
/// built for units, and the pool units render on.
pub(crate) struct Worker {
    session: Session,
    scenes: SceneCache,
    guides: GuideCache,
    pool: rayon::ThreadPool,
}

impl Worker {
    /// A worker over `session`, rendering on `pool`, with nothing built yet.
    pub(crate) fn new(session: Session, pool: rayon::ThreadPool) -> Self {
        Self {
            session,
            scenes: SceneCache::new(),
            guides: GuideCache::new(),
            pool,
        }
    }

    /// Its session with the coordinator.
    pub(crate) fn session(&self) -> &Session {
        &self.session
    }
}

/// A leased unit, ready to render.
struct Ready {
    unit: pb::WorkUnit,
    scene: Arc<Scene>,
    rect: PixelRect,
    settings: RenderSettings,
    /// A guided unit's guide and structure.
    guided: Option<Arc<Guided>>,
    _slot: OwnedSemaphorePermit,
}

/// Checks a unit against its scene and turns it into renderer arguments.
fn prepare(unit: &pb::WorkUnit, scene: &Scene) -> Result<(PixelRect, RenderSettings), String> {
    let rect = PixelRect::from(unit.rect.ok_or("unit has no rect")?);
    if !rect.fits(scene.width, scene.height) {
        return Err(format!(
            "unit rect {rect:?} is outside the {}×{} image",
            scene.width, scene.height
        ));
    }
    // An unknown strategy is a coordinator newer than this worker.
    let settings = settings_from_wire(unit.settings.as_ref())
        .map_err(|e| format!("unit settings: {e} (is this worker older than the coordinator?)"))?;
    if unit.sample_start >= unit.sample_end || unit.sample_end > settings.spp {
        return Err(format!(
            "unit samples {}..{} do not fit spp {} in batches of {}",
            unit.sample_start, unit.sample_end, settings.spp, settings.batch
        ));
    }
    Ok((rect, settings))
}

/// The longest a lease call waits at the coordinator for a unit to come free.
const LEASE_WAIT: Duration = Duration::from_secs(2);

/// Leases units while there is room, and queues them for the renderer.
async fn fetcher(ctx: Arc<Worker>, tx: mpsc::Sender<Ready>) {
    // The units rendering and one queued ahead.
    let slots = Arc::new(Semaphore::new(MAX_HELD_UNITS));
    let mut attempt = 0;
    let mut stop = ctx.session.stop.clone();
    loop {
        let slot = tokio::select! {
            s = slots.clone().acquire_owned() => match s { Ok(s) => s, Err(_) => return },
            _ = stop.wait_for(|s| *s) => return,
        };
        let units = match lease_call(&ctx, &mut stop, &mut attempt).await {
            Leased::Units(units) => units,
            Leased::Again => continue,
            Leased::Stop => return,
        };
        let mut slot = Some(slot);
        for unit in units {
            debug!(
                "{} tile {} batch {}: leased",
                unit.job_id, unit.tile_index, unit.batch_index
            );
            lock(&ctx.session.held).insert(unit.lease_id.clone());
            let Some((scene, rect, settings, guided)) = prepare_unit(&ctx, &unit).await else {
                continue;
            };
            let Some(s) = slot.take() else { break };
            let ready = Ready {
                unit,
                scene,
                rect,
                settings,
                guided,
                _slot: s,
            };
            if let Err(unsent) = tx.send(ready).await {
                // The renderer stopped taking units (shutdown): this one goes back at once.
                ctx.session
                    .release(vec![unsent.0.unit.lease_id], false)
                    .await;
                return;
            }
        }
    }
}

/// What one lease call came to.
enum Leased {
    /// The units granted (none if there was no work within the wait).
    Units(Vec<pb::WorkUnit>),
    /// Nothing now: call again (after a backoff, or a new registration).
    Again,
    /// Shutdown began, or the coordinator refused this worker for good.
    Stop,
}

/// One lease call, a long poll of at most [`LEASE_WAIT`]; network errors back off, and a
/// coordinator that forgot this worker gets it registered again.
async fn lease_call(ctx: &Worker, stop: &mut watch::Receiver<bool>, attempt: &mut u32) -> Leased {
    let req_id = ctx.session.id();
    let req = pb::LeaseRequest {
        worker_id: req_id.clone(),
        max_units: 1,
        wait_ms: LEASE_WAIT.as_millis() as u32,
    };
    let mut client = ctx.session.client.clone();
    let call = client.lease(req);
    tokio::pin!(call);
    let answered = tokio::select! {
        r = &mut call => Some(r),
        _ = stop.wait_for(|s| *s) => None,
    };
    let Some(resp) = answered else {
        // The coordinator may have granted units in the answer already on its way: dropping
        // the call would leave them leased to nobody until their leases lapse. The call is a
        // long poll of at most LEASE_WAIT, so take its answer and keep its units as held, for
        // the shutdown to hand back at once.
        let late = tokio::time::timeout(LEASE_WAIT + Duration::from_secs(1), call).await;
        if let Ok(Ok(r)) = late {
            let units: Vec<String> = r
                .into_inner()
                .units
                .into_iter()
                .map(|u| u.lease_id)
                .collect();
            // Handed back at once: the units go to other workers now, not when the ones
            // rendering here are done.
            lock(&ctx.session.held).extend(units.iter().cloned());
            ctx.session.release(units, false).await;
        }
        return Leased::Stop;
    };
    match resp {
        Ok(r) => {
            *attempt = 0;
            let r = r.into_inner();
            if r.drain {
                ctx.session.drain();
            }
            Leased::Units(r.units)
        }
        Err(e) if tessera_proto::reason::is_unknown_worker(&e) => {
            warn!("{}", e.message());
            if ctx.session.reregister(&req_id).await {
                Leased::Again
            } else {
                Leased::Stop
            }
        }
        Err(e) => {
            if attempt.is_multiple_of(10) {
                warn!(
                    "leasing from {}: {}",
                    ctx.session.config.coordinator,
                    e.message()
                );
            }
            if ctx.session.backoff(attempt).await {
                Leased::Again
            } else {
                Leased::Stop
            }
        }
    }
}

/// What a unit renders with: its scene, rectangle, settings and (guided) guide.
type Prepared = (Arc<Scene>, PixelRect, RenderSettings, Option<Arc<Guided>>);

/// Unit `unit`, ready to render; or `None` once it has been handed back: its scene is not at
/// hand here (another worker may have it), or this worker can never render it (the
/// coordinator fails its job with the reason).
async fn prepare_unit(ctx: &Worker, unit: &pb::WorkUnit) -> Option<Prepared> {
    let frame = unit.settings.as_ref().and_then(|s| s.frame);
    let resolution = unit
        .settings
        .as_ref()
        .and_then(|s| s.resolution)
        .map(|r| (r.width, r.height));
    let prepared = async {
        let scene = ctx
            .scenes
            .scene(&ctx.session, &unit.scene_hash, frame, resolution)
            .await?;
        let (rect, settings) = prepare(unit, &scene).map_err(SceneError::Unrenderable)?;
        let guided = if settings.guiding {
            let g = ctx
                .guides
                .guided(&ctx.session, &ctx.scenes, unit, &scene, &settings);
            Some(g.await?)
        } else {
            None
        };
        Ok::<Prepared, SceneError>((scene, rect, settings, guided))
    };
    match prepared.await {
        Ok(p) => Some(p),
        Err(SceneError::Unavailable(e)) => {
            warn!(
                "unit {} of {}: scene {}: {e}; handing it back",
                unit.lease_id, unit.job_id, unit.scene_hash
            );
            ctx.session.log(
                &unit.lease_id,
                pb::LogLevel::Warn,
                format!("scene unavailable here: {e}; handed back"),
            );
            ctx.session
                .release(vec![unit.lease_id.clone()], false)
                .await;
            None
        }
        Err(SceneError::Unrenderable(e)) => {
            warn!(
                "unit {} of {}: this worker cannot render it: {e}",
                unit.lease_id, unit.job_id
            );
            ctx.session.log(
                &unit.lease_id,
                pb::LogLevel::Error,
                format!("this worker cannot render it: {e}"),
            );
            ctx.session
                .hand_back(vec![unit.lease_id.clone()], false, e)
                .await;
            None
        }
    }
}

/// A rendered unit on its way back. It keeps its fetcher slot until the coordinator has the
/// result: a unit waiting to be sent counts against what the worker may hold, or a worker
/// that renders faster than it can send would lease without bound.
struct Done {
    unit: pb::WorkUnit,
    sums: TileSums,
    /// A guided unit's trained tree, encoded.
    train: Vec<u8>,
    _slot: OwnedSemaphorePermit,
}

/// Units rendering at once. Two, so that while one unit's last rows finish on a few threads,
/// the other keeps the rest of the pool busy (rayon steals across both).
const OVERLAP: usize = 2;

/// The most units a worker holds leases for at once: those rendering or waiting for their
/// result to be acknowledged, and one queued ahead. A unit keeps its slot until its result is
/// acknowledged, so results waiting to be sent count too, and a worker whose units render
/// faster than results are committed cannot lease without bound.
pub const MAX_HELD_UNITS: usize = OVERLAP + 1;

/// Renders queued units on the whole pool, [`OVERLAP`] at a time.
async fn renderer(
    ctx: Arc<Worker>,
    mut rx: mpsc::Receiver<Ready>,
    tx: mpsc::UnboundedSender<Done>,
) {
    let mut stop = ctx.session.stop.clone();
    let mut running: tokio::task::JoinSet<Done> = tokio::task::JoinSet::new();
    let mut open = true;
    let mut stopped = false;
    while open || !running.is_empty() {
        if std::mem::take(&mut stopped) {
            hand_back_queued(&ctx, &mut rx).await;
        }
        tokio::select! {
            biased;
            // Shutdown: take no new unit and hand back the queued ones at once, so that they
            // wait for no one; finish the ones started.
            _ = stop.wait_for(|s| *s), if open => {
                open = false;
                stopped = true;
            }
            Some(done) = running.join_next(), if !running.is_empty() => match done {
                Ok(done) => {
                    let _ = tx.send(done);
                }
                Err(e) => warn!("render task failed: {e}"),
            },
            r = rx.recv(), if open && running.len() < OVERLAP => {
                let Some(ready) = r else {
                    open = false;
                    continue;
                };
                if lock(&ctx.session.revoked).remove(&ready.unit.lease_id) {
                    lock(&ctx.session.held).remove(&ready.unit.lease_id);
                    continue;
                }
                let work = ctx.clone();
                running.spawn_blocking(move || {
                    let samples = ready.unit.sample_start..ready.unit.sample_end;
                    let started = std::time::Instant::now();
                    let (sums, train) = work.pool.install(|| match &ready.guided {
                        Some(g) => {
                            let (sums, trained) = render_tile_guided(
                                &ready.scene,
                                &ready.settings,
                                ready.rect,
                                samples,
                                g.guide.as_ref(),
                                g.train.as_ref(),
                            );
                            (sums, trained.map(|t| t.encode()).unwrap_or_default())
                        }
                        None => (
                            render_tile(&ready.scene, &ready.settings, ready.rect, samples),
                            Vec::new(),
                        ),
                    });
                    debug!(
                        "{} tile {} batch {}: rendered in {:.3} s",
                        ready.unit.job_id,
                        ready.unit.tile_index,
                        ready.unit.batch_index,
                        started.elapsed().as_secs_f64()
                    );
                    if sums.nonfinite > 0 {
                        work.session.log(
                            &ready.unit.lease_id,
                            pb::LogLevel::Warn,
                            format!(
                                "{} non-finite samples (NaN or infinite) were left out of the sums",
                                sums.nonfinite
                            ),
                        );
                    }
                    Done {
                        unit: ready.unit,
                        sums,
                        train,
                        _slot: ready._slot,
                    }
                });
            }
        }
    }
    hand_back_queued(&ctx, &mut rx).await;
}

/// Closes the renderer's queue and hands back the units in it, which no render has started.
async fn hand_back_queued(ctx: &Worker, rx: &mut mpsc::Receiver<Ready>) {
    rx.close();
    let mut back = Vec::new();
    while let Ok(r) = rx.try_recv() {
        back.push(r.unit.lease_id);
    }
    if !back.is_empty() {
        info!("handing back {} queued unit(s)", back.len());
        ctx.session.release(back, false).await;
    }
}

/// Sends results, retrying through network errors.
async fn submitter(ctx: Arc<Worker>, mut rx: mpsc::UnboundedReceiver<Done>) {
    while let Some(done) = rx.recv().await {
        let mut attempt = 0u32;
        let started = std::time::Instant::now();
        loop {
            let sent_as = ctx.session.id();
            let req = pb::SubmitResultRequest {
                worker_id: sent_as.clone(),
                lease_id: done.unit.lease_id.clone(),
                job_id: done.unit.job_id.clone(),
                tile_index: done.unit.tile_index,
                batch_index: done.unit.batch_index,
                // Made from the sums for each attempt: one copy of a large result in memory
                // beside its encoding, not a message kept for retries and a clone to send.
                result: Some(pb::TileResult {
                    guide_train: done.train.clone(),
                    ..pb::TileResult::from(&done.sums)
                }),
            };
            match ctx.session.client.clone().submit_result(req).await {
                Ok(_) => {
                    debug!(
                        "{} tile {} batch {}: sent in {:.3} s",
                        done.unit.job_id,
                        done.unit.tile_index,
                        done.unit.batch_index,
                        started.elapsed().as_secs_f64()
                    );
                    break;
                }
                Err(e) if tessera_proto::reason::is_unknown_worker(&e) => {
                    if !ctx.session.reregister(&sent_as).await {
                        break;
                    }
                }
                Err(e) if transient(&e) => {
                    if attempt.is_multiple_of(10) {
                        warn!("sending a result: {}; retrying", e.message());
                    }
                    // Keep retrying during shutdown too, but not past the grace period
                    // (enforced by the caller's timeout).
                    let delay = backoff_delay(attempt, ctx.session.config.max_backoff);
                    attempt += 1;
                    tokio::time::sleep(delay).await;
                }
                Err(e) => {
                    warn!(
                        "result for {} tile {} batch {} refused: {}",
                        done.unit.job_id,
                        done.unit.tile_index,
                        done.unit.batch_index,
                        e.message()
                    );
                    ctx.session.log(
                        &done.unit.lease_id,
                        pb::LogLevel::Error,
                        format!("its result was refused: {}", e.message()),
                    );
                    break;
                }
            }
        }
        lock(&ctx.session.held).remove(&done.unit.lease_id);
    }
}

/// Renews leases and learns which were revoked.
async fn heartbeat(ctx: Arc<Worker>) {
    loop {
        let every = Duration::from_millis(ctx.session.heartbeat_ms.load(Ordering::Relaxed));
        tokio::time::sleep(every).await;
        ctx.session.send_logs().await;
        let lease_ids: Vec<String> = lock(&ctx.session.held).iter().cloned().collect();
        let req = pb::HeartbeatRequest {
            worker_id: ctx.session.id(),
            lease_ids,
        };
        match ctx.session.client.clone().heartbeat(req).await {
            Ok(r) => {
                let r = r.into_inner();
                if r.drain {
                    ctx.session.drain();
                }
                let revoked = r.revoked;
                if !revoked.is_empty() {
                    debug!("{} lease(s) revoked", revoked.len());
                    let mut held = lock(&ctx.session.held);
                    let mut gone = lock(&ctx.session.revoked);
                    for l in revoked {
                        held.remove(&l);
                        gone.insert(l);
                    }
                }
            }
            Err(e) => debug!("heartbeat: {}", e.message()),
        }
    }
}

/// The pipeline's tasks, running: dropping them stops them.
pub(crate) struct Pipeline {
    /// Renews the leases held.
    pub heartbeat: Task,
    /// Leases units; ends by itself only when the coordinator refused this worker for good.
    pub fetch: Task,
    /// Renders queued units.
    pub render: Task,
    /// Sends results.
    pub submit: Task,
}

impl Pipeline {
    /// Starts the tasks over `ctx`.
    pub(crate) fn start(ctx: &Arc<Worker>) -> Self {
        let (ready_tx, ready_rx) = mpsc::channel(1);
        let (done_tx, done_rx) = mpsc::unbounded_channel();
        Self {
            heartbeat: Task::spawn(heartbeat(ctx.clone())),
            fetch: Task::spawn(fetcher(ctx.clone(), ready_tx)),
            render: Task::spawn(renderer(ctx.clone(), ready_rx, done_tx)),
            submit: Task::spawn(submitter(ctx.clone(), done_rx)),
        }
    }
}

/// A spawned task that is aborted when dropped, so that dropping (aborting) [`run`] stops
/// everything the worker started, as a crash would.
pub(crate) struct Task(tokio::task::JoinHandle<()>);

impl Task {
    pub(crate) fn spawn(f: impl Future<Output = ()> + Send + 'static) -> Self {
        Self(tokio::spawn(f))
    }

    pub(crate) async fn join(&mut self) {
        let _ = (&mut self.0).await;
    }
}

impl Drop for Task {
    fn drop(&mut self) {
        self.0.abort();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_render::scene::{Format, Limits};
    use tessera_render::Strategy;

    fn scene() -> Scene {
        let text = include_str!("../../../scenes/cornell-box.toml")
            .replace("width = 256", "width = 8")
            .replace("height = 256", "height = 8");
        Scene::text(&text, Format::Toml, "c.toml", &Limits::default())
            .load()
            .expect("scene")
    }

    fn unit(rect: pb::Rect, start: u32, end: u32, strategy: i32) -> pb::WorkUnit {
        pb::WorkUnit {
            rect: Some(rect),
            sample_start: start,
            sample_end: end,
            settings: Some(pb::RenderSettings {
                spp: 8,
                seed: 1,
                batch: 4,
                strategy,
                ..Default::default()
            }),
            ..pb::WorkUnit::default()
        }
    }

    #[test]
    fn backoff_doubles_from_a_tenth_of_a_second_up_to_the_cap() {
        let cap = Duration::from_secs(10);
        let waits: Vec<u128> = (0..9).map(|a| backoff_delay(a, cap).as_millis()).collect();
        assert_eq!(
            waits,
            [100, 200, 400, 800, 1600, 3200, 6400, 10_000, 10_000]
        );
        // However long a coordinator stays away, the shift never overflows.
        assert_eq!(backoff_delay(u32::MAX, cap), cap);
        assert_eq!(
            backoff_delay(3, Duration::from_millis(250)).as_millis(),
            250
        );
    }

    #[test]
    fn units_a_worker_cannot_render_as_sent_are_refused_with_the_reason() {
        let scene = scene();
        let inside = pb::Rect {
            x0: 4,
            y0: 4,
            width: 4,
            height: 4,
        };
        let (rect, settings) =
            prepare(&unit(inside, 4, 8, pb::Strategy::Nee as i32), &scene).expect("fits");
        assert_eq!((rect.x0, rect.width), (4, 4));
        assert_eq!(settings.strategy, Strategy::Nee);
        let outside = pb::Rect { x0: 6, ..inside };
        let e = prepare(&unit(outside, 0, 4, 1), &scene).expect_err("outside");
        assert!(e.contains("outside the 8×8 image"), "{e}");
        let e = prepare(&unit(inside, 4, 9, 1), &scene).expect_err("past spp");
        assert!(e.contains("do not fit spp 8"), "{e}");
        let e = prepare(&unit(inside, 0, 4, 99), &scene).expect_err("a strategy from the future");
        assert!(e.contains("unknown strategy 99"), "{e}");
    }
}
