//! Sequences of gRPC calls from several fake workers and a client, through the coordinator's
//! real service handlers and its redb store (`InProcess`: everything `serve` runs but the
//! network): Register, Lease, Heartbeat, SubmitResult (honest, forged, under another worker's
//! lease or id), ReleaseLeases (with and without `cannot_render`), GetScene, SubmitJob
//! (one frame or frame ranges, good and bad), CancelJob, GetJob, ListWorkers, ListJobs;
//! asset chunks (in order or not, with the declared size right or wrong), GetAssetStatus,
//! FetchAsset, and the asset collection (with a retention of zero, so it deletes).
//!
//! Checks: no call panics; no result under another worker's lease or a forged id is merged;
//! no worker holds more than its share; every status is finite; a file said to be complete
//! is fetched whole, its bytes hashing to its name. At the end the coordinator is
//! closed and opened again on the same store, which must load; and if the main job finished
//! from honest results only, its EXR must be the bytes `tessera render` writes.
//! Inputs of odd length run the coordinator with `--audit 0.5`.
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use tessera_coordinator::{Config, InProcess};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_server::Jobs;
use tessera_proto::v1::workers_server::Workers;
use tessera_render::output::{render_metadata, write_exr, ExrChannels};
use tessera_render::scene::assets::sha256_hex;
use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::{render_frame, render_tile, PixelRect, RenderSettings, IMAGE_REVISION};
use tokio_stream::StreamExt;
use tonic::Request;

const SPP: u32 = 6;

/// The files the asset operations upload.
const FILES: [&[u8]; 2] = [b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", b"another file"];
const BATCH: u32 = 2;

fn scene_text() -> &'static str {
    static TEXT: OnceLock<String> = OnceLock::new();
    TEXT.get_or_init(|| {
        include_str!("../../scenes/cornell-box.toml")
            .replace("width = 256", "width = 8")
            .replace("height = 256", "height = 6")
    })
}

fn settings() -> RenderSettings {
    RenderSettings {
        seed: 3,
        spp: SPP,
        batch: BATCH,
        ..RenderSettings::default()
    }
}

fn scene() -> &'static Scene {
    static SCENE: OnceLock<Scene> = OnceLock::new();
    SCENE.get_or_init(|| {
        Scene::text(scene_text(), Format::Toml, "c.toml", &Limits::default())
            .load()
            .expect("scene")
    })
}

/// The EXR `tessera render` writes for the main job.
fn local_exr() -> &'static [u8] {
    static EXR: OnceLock<Vec<u8>> = OnceLock::new();
    EXR.get_or_init(|| {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("local.exr");
        let image = render_frame(scene(), &settings(), &|_| {}).finalize();
        write_exr(
            &path,
            &image,
            ExrChannels::default(),
            &render_metadata(&scene().hash, &settings()),
        )
        .expect("write");
        std::fs::read(path).expect("read")
    })
}

fn submit_request(output_name: String, frames: Option<pb::FrameRange>) -> pb::SubmitJobRequest {
    pb::SubmitJobRequest {
        scene_text: scene_text().into(),
        scene_format: pb::SceneFormat::Toml as i32,
        scene_name: "c.toml".into(),
        settings: Some(pb::RenderSettings {
            spp: SPP,
            seed: 3,
            batch: BATCH,
            strategy: pb::Strategy::Mis as i32,
            ..Default::default()
        }),
        tile_size: 4,
        output_name,
        priority: 0,
        channels: None,
        frames,
        assets: Vec::new(),
        after: String::new(),
        require: Vec::new(),
        min_memory_bytes: 0,
        progressive: false,
    }
}

fn honest(u: &pb::WorkUnit) -> pb::TileResult {
    let rect = PixelRect::from(u.rect.unwrap_or_default());
    pb::TileResult::from(&render_tile(
        scene(),
        &settings(),
        rect,
        u.sample_start..u.sample_end,
    ))
}

fn forged(u: &pb::WorkUnit, how: u8) -> pb::TileResult {
    let mut r = honest(u);
    match how % 6 {
        0 => r.sum_sq[0] = 1.7e308,
        1 => r.sum[1] = f64::NAN,
        2 => {
            r.count.pop();
        }
        3 => r.sample_end += 1,
        4 => r.nonfinite += 1,
        _ => r.rect = Some(pb::Rect::default()),
    }
    r
}

struct Fake {
    id: String,
    units: Vec<pb::WorkUnit>,
}

fn merged(r: &Result<tonic::Response<pb::SubmitResultResponse>, tonic::Status>) -> bool {
    matches!(r, Ok(x) if x.get_ref().outcome == pb::ResultOutcome::Merged as i32)
}

fuzz_target!(|data: &[u8]| {
    let Ok(rt) = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    else {
        return;
    };
    let dir = tempfile::tempdir_in("/dev/shm")
        .or_else(|_| tempfile::tempdir())
        .expect("tmp");
    let mut config = Config::new(dir.path());
    config.max_leases_per_worker = 3;
    config.asset_retention = std::time::Duration::ZERO;
    // Inputs of odd length run with audits: half the accepted results are held for a second
    // copy, and the audited job keeps every unit's result in the store, which must reopen.
    if data.len() % 2 == 1 {
        config.audit = 0.5;
    }
    let out = config.output_dir();
    rt.block_on(async {
        let farm = InProcess::open(config.clone()).expect("a fresh store opens");
        let svc = farm.service();
        let main = svc
            .submit_job(Request::new(submit_request(String::new(), None)))
            .await
            .expect("the main job")
            .into_inner()
            .job_id;
        let mut fakes: Vec<Fake> = Vec::new();
        let mut tainted = false;
        let mut bytes = data.iter().copied();
        while let (Some(op), Some(arg)) = (bytes.next(), bytes.next()) {
            let pick = |n: usize| arg as usize % n.max(1);
            match op % 14 {
                0 if fakes.len() < 4 => {
                    let name: String = (0..(arg % 8)).map(|i| char::from(b'a' + i)).collect();
                    let r = svc
                        .register(Request::new(pb::RegisterRequest {
                            name: format!("{name}\u{1b}[2J"),
                            cores: arg as u32,
                            version: "0".into(),
                            image_revision: if arg == 255 {
                                IMAGE_REVISION + 1
                            } else {
                                IMAGE_REVISION
                            },
                            // Tags and features well formed, malformed, or too many; memory
                            // none, some, or the most a u64 says.
                            tags: match arg / 8 % 4 {
                                0 => Vec::new(),
                                1 => vec!["pool=fast".into(), "big-mem".into()],
                                2 => vec!["a b".into()],
                                _ => (0..40).map(|i| format!("t{i}")).collect(),
                            },
                            cpu_features: if arg & 0x20 != 0 {
                                vec!["avx2".into()]
                            } else {
                                Vec::new()
                            },
                            memory_bytes: [0, 8 << 30, u64::MAX][usize::from(arg / 64 % 3)],
                            draining: arg & 0x40 != 0 && arg & 0x80 != 0,
                            denoise_version: i32::from(arg & 0x10 != 0) * 20501,
                        }))
                        .await;
                    if let Ok(r) = r {
                        fakes.push(Fake {
                            id: r.into_inner().worker_id,
                            units: Vec::new(),
                        });
                    }
                }
                1 if !fakes.is_empty() => {
                    let f = pick(fakes.len());
                    let r = svc
                        .lease(Request::new(pb::LeaseRequest {
                            worker_id: fakes[f].id.clone(),
                            max_units: (arg % 6) as u32,
                            wait_ms: 0,
                        }))
                        .await;
                    if let Ok(r) = r {
                        fakes[f].units.extend(r.into_inner().units);
                    }
                }
                2 if !fakes.is_empty() => {
                    let f = &fakes[pick(fakes.len())];
                    let mut ids: Vec<String> = f.units.iter().map(|u| u.lease_id.clone()).collect();
                    ids.push(format!("L1-{arg}"));
                    // Log lines about its own units, a forged lease, or too many at once.
                    let n = if arg % 7 == 0 {
                        40
                    } else {
                        usize::from(arg % 4)
                    };
                    let lines = ids
                        .iter()
                        .cycle()
                        .take(n)
                        .map(|l| pb::WorkerLogLine {
                            lease_id: l.clone(),
                            level: i32::from(arg % 5),
                            message: "x\u{1b}[2J".repeat(usize::from(arg)),
                        })
                        .collect();
                    let _ = svc
                        .report_log(Request::new(pb::ReportLogRequest {
                            worker_id: f.id.clone(),
                            lines,
                        }))
                        .await;
                    let _ = svc
                        .heartbeat(Request::new(pb::HeartbeatRequest {
                            worker_id: f.id.clone(),
                            lease_ids: ids,
                        }))
                        .await;
                }
                3..=5 if !fakes.is_empty() => {
                    // An honest result (3), a forged one (4), or one sent under another
                    // worker's lease or a forged id (5).
                    let f = pick(fakes.len());
                    let owner = if op % 14 == 5 {
                        (f + 1) % fakes.len()
                    } else {
                        f
                    };
                    let Some(unit) = fakes[owner].units.first().cloned() else {
                        continue;
                    };
                    let worker_id = match (op % 14, arg % 3) {
                        (5, 0) => fakes[owner]
                            .id
                            .split('.')
                            .next()
                            .unwrap_or_default()
                            .to_string(),
                        (5, 1) => format!(
                            "{}.{}",
                            fakes[owner].id.split('.').next().unwrap_or_default(),
                            "0".repeat(32)
                        ),
                        _ => fakes[f].id.clone(),
                    };
                    let result = if op % 14 == 4 {
                        forged(&unit, arg)
                    } else {
                        honest(&unit)
                    };
                    let r = svc
                        .submit_result(Request::new(pb::SubmitResultRequest {
                            worker_id,
                            lease_id: unit.lease_id.clone(),
                            job_id: unit.job_id.clone(),
                            tile_index: unit.tile_index,
                            batch_index: unit.batch_index,
                            result: Some(result),
                        }))
                        .await;
                    if op % 14 == 4 || (op % 14 == 5 && owner != f) || (op % 14 == 5 && arg % 3 < 2)
                    {
                        assert!(!merged(&r), "op {op} arg {arg}: merged {r:?}");
                    }
                    if op % 14 == 3 {
                        fakes[f].units.remove(0);
                    }
                }
                6 if !fakes.is_empty() => {
                    let f = pick(fakes.len());
                    let leases: Vec<String> =
                        fakes[f].units.drain(..).map(|u| u.lease_id).collect();
                    let refuse = arg % 5 == 0;
                    let _ = svc
                        .release_leases(Request::new(pb::ReleaseLeasesRequest {
                            worker_id: fakes[f].id.clone(),
                            lease_ids: leases,
                            goodbye: arg % 3 == 0,
                            cannot_render: if refuse {
                                "too big".into()
                            } else {
                                String::new()
                            },
                        }))
                        .await;
                    if refuse {
                        tainted = true;
                    }
                }
                7 => {
                    let hash = if arg % 2 == 0 {
                        scene().hash.clone()
                    } else {
                        format!("{arg}")
                    };
                    let _ = svc
                        .get_scene(Request::new(pb::GetSceneRequest { scene_hash: hash }))
                        .await;
                }
                8 => {
                    let name = match arg % 4 {
                        0 => String::new(),
                        1 => "shot.exr".into(),
                        2 => "job-000009.exr".into(),
                        _ => "../x.exr".into(),
                    };
                    let range = |first, last, step| Some(pb::FrameRange { first, last, step });
                    let frames = match arg / 4 % 5 {
                        0 => None,
                        1 => range(1, 3, 1),
                        2 => range(0, u32::MAX, u32::MAX),
                        3 => range(5, 1, 1),
                        _ => range(1, 2, 0),
                    };
                    // A dependency on the main job, on one that may not exist, or malformed.
                    let after = match arg / 20 % 4 {
                        0 => String::new(),
                        1 => main.clone(),
                        2 => format!("job-{:06}", arg % 7),
                        _ => "job-".into(),
                    };
                    let require = match arg / 80 % 3 {
                        0 => Vec::new(),
                        1 => vec!["big-mem".into(), "cpu:avx2".into()],
                        _ => vec!["=".into()],
                    };
                    let _ = svc
                        .submit_job(Request::new(pb::SubmitJobRequest {
                            after,
                            progressive: arg & 1 == 1,
                            require,
                            min_memory_bytes: u64::from(arg % 3) << 32,
                            ..submit_request(name, frames)
                        }))
                        .await;
                }
                9 => {
                    let job = if arg % 4 == 0 {
                        main.clone()
                    } else {
                        format!("job-{:06}", arg % 5 + 2)
                    };
                    if arg & 0x10 != 0 {
                        // Pause, resume or reprioritise: the main job's bits do not depend on
                        // it, only whether it finishes (a paused main job is left unchecked).
                        let _ = svc
                            .update_job(Request::new(pb::UpdateJobRequest {
                                job_id: job,
                                paused: (arg & 0x20 != 0).then_some(arg & 0x40 != 0),
                                priority: (arg & 0x80 != 0).then_some(i32::from(arg) - 200),
                            }))
                            .await;
                        continue;
                    }
                    if job == main {
                        tainted = true;
                    }
                    let _ = svc
                        .cancel_job(Request::new(pb::CancelJobRequest { job_id: job }))
                        .await;
                }
                10 => {
                    if arg & 0x20 != 0 {
                        // A retry puts a failed job back; the main job's bits are then still
                        // its own, but its history is not the plain run's.
                        let job = format!("job-{:06}", arg % 4);
                        let retried = svc
                            .retry_job(Request::new(pb::RetryJobRequest {
                                job_id: job.clone(),
                                frame: (arg & 0x40 != 0).then_some(u32::from(arg % 4)),
                            }))
                            .await;
                        if retried.is_ok() && job == main {
                            tainted = true;
                        }
                    }
                    if let Ok(l) = svc
                        .get_logs(Request::new(pb::GetLogsRequest {
                            job_id: format!("job-{:06}", arg % 4),
                            frame: (arg & 0x40 != 0).then_some(u32::from(arg % 4)),
                            after: u64::from(arg / 8),
                        }))
                        .await
                    {
                        let l = l.into_inner();
                        assert!(l.entries.len() <= 200 * 3, "{}", l.entries.len());
                        assert!(l.entries.iter().all(|e| e.message.chars().count() <= 500));
                    }
                    if let Ok(s) = svc
                        .get_job(Request::new(pb::GetJobRequest {
                            job_id: format!("job-{:06}", arg % 4),
                        }))
                        .await
                    {
                        let s = s.into_inner();
                        assert!(s.units_done <= s.units_total);
                        assert!(s.noise_rms.is_finite() && s.noise_relative.is_finite());
                    }
                }
                11 => {
                    let listed = svc
                        .list_workers(Request::new(pb::ListWorkersRequest {}))
                        .await
                        .expect("list workers")
                        .into_inner()
                        .workers;
                    for w in &listed {
                        assert!(w.leases <= 3, "{w:?}");
                        assert!(!w.worker_id.contains('.'), "a secret listed: {w:?}");
                    }
                    let _ = svc
                        .list_jobs(Request::new(pb::ListJobsRequest::default()))
                        .await
                        .expect("list jobs");
                    if arg % 5 == 0 {
                        // Drain one by name or public id, or one that does not exist. A
                        // drained worker leases nothing more; the main job may then stay
                        // unfinished, and is not checked.
                        let who = match (fakes.get(pick(fakes.len())), arg % 3) {
                            (Some(f), 0) => f.id.split('.').next().unwrap_or_default().into(),
                            (Some(_), 1) => "abcdef\u{1b}[2J".into(),
                            _ => "nobody".to_string(),
                        };
                        let _ = svc
                            .drain_worker(Request::new(pb::DrainWorkerRequest { worker: who }))
                            .await;
                    }
                }
                12 => {
                    let file = FILES[usize::from(arg % 2)];
                    let hash = sha256_hex(file);
                    let held = farm.assets().status(&hash).map_or(0, |h| h.received);
                    let len = file.len() as u64;
                    let (offset, total) = match arg / 2 % 4 {
                        0 | 1 => (held, len),
                        2 => (held + 1, len),
                        _ => (held, len + u64::from(arg)),
                    };
                    let start = (offset as usize).min(file.len());
                    let end = (start + 1 + usize::from(arg / 8)).min(file.len());
                    let _ = farm
                        .assets()
                        .append(&hash, offset, total, &file[start..end]);
                }
                13 if arg % 2 == 0 => {
                    farm.collect_assets().expect("the collection runs");
                }
                13 => {
                    for file in FILES {
                        let hash = sha256_hex(file);
                        let s = svc
                            .get_asset_status(Request::new(pb::GetAssetStatusRequest {
                                sha256: hash.clone(),
                            }))
                            .await
                            .expect("status")
                            .into_inner();
                        assert!(s.received <= file.len() as u64, "{s:?}");
                        if !s.complete {
                            continue;
                        }
                        let mut stream = svc
                            .fetch_asset(Request::new(pb::FetchAssetRequest {
                                sha256: hash.clone(),
                                offset: 0,
                            }))
                            .await
                            .expect("a complete file is fetched")
                            .into_inner();
                        let mut bytes = Vec::new();
                        while let Some(chunk) = stream.next().await {
                            bytes.extend(chunk.expect("a chunk").data);
                        }
                        assert_eq!(sha256_hex(&bytes), hash, "a complete file's bytes");
                    }
                }
                _ => farm.expire(),
            }
        }
        let done = svc
            .get_job(Request::new(pb::GetJobRequest {
                job_id: main.clone(),
            }))
            .await
            .expect("main job")
            .into_inner()
            .state
            == pb::JobState::Done as i32;
        farm.close().await;
        // Whatever happened, the store opens again.
        let again = InProcess::open(config).expect("the store reopens");
        again.close().await;
        if done && !tainted {
            let exr = std::fs::read(out.join(format!("{main}.exr"))).expect("the EXR");
            assert!(
                exr == local_exr(),
                "the farm's EXR differs from tessera render's"
            );
            // Once a process, so a run's log shows that its inputs reach this far.
            static SAID: std::sync::Once = std::sync::Once::new();
            SAID.call_once(|| {
                eprintln!("rpc_surface: a finished job's EXR matched tessera render's")
            });
        }
    });
});
