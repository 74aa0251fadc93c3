//! Audits on a running farm: a worker that returns plausible but wrong finite sums (every sum
//! 1% high) on one unit in 50 is caught, convicted and its results rendered again by the
//! honest workers, and the EXR is bit-identical to `tessera render`'s; in a guided job the
//! conviction rewinds the job to the first epoch the liar trained, and the EXR is `tessera
//! render --guiding`'s. Each worker connects
//! from an address of its own on the loopback network (127.0.0.2, …), so the coordinator sees
//! the hosts a real farm has.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

use tessera_render::guide::SdTree;

use crate::common::*;

/// The liar: leases one unit at a time, renders it for real (a guided unit with its guide,
/// fetched by hash, and its epoch's structure, as a worker does), scales one result's sums in
/// 50, and keeps going until the coordinator refuses it or the test stops it. Returns how many
/// wrong results it sent.
async fn liar(url: String, text: String, settings: RenderSettings, stop: Arc<AtomicBool>) -> u64 {
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let mut client = WorkersClient::new(
        endpoint(&url, &from_host(9))
            .expect("endpoint")
            .connect_lazy(),
    );
    let id = register_as(&mut client, "liar", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let mut guides: HashMap<String, SdTree> = HashMap::new();
    let (mut sent, mut forged) = (0u64, 0u64);
    while !stop.load(Ordering::Relaxed) {
        let units = match lease_now(&mut client, &id, 1).await {
            Ok(u) => u,
            Err(e) if e.code() == tonic::Code::PermissionDenied => {
                assert!(e.message().contains("audit"), "{e:?}");
                break;
            }
            Err(e) => panic!("lease: {e:?}"),
        };
        let Some(u) = units.into_iter().next() else {
            tokio::time::sleep(Duration::from_millis(2)).await;
            continue;
        };
        let mut r = if settings.guiding {
            let hash = u.guide_sha256.clone();
            if !hash.is_empty() && !guides.contains_key(&hash) {
                let Ok(bytes) = fetch_asset(&mut client, &id, &hash).await else {
                    break;
                };
                guides.insert(hash.clone(), SdTree::decode(&bytes).expect("a guide"));
            }
            honest_guided(&scene, &settings, &u, guides.get(&hash))
        } else {
            honest_result(&scene, &settings, &u)
        };
        sent += 1;
        if sent % 50 == 7 {
            forged += 1;
            for v in r.sum.iter_mut().chain(r.sum_sq.iter_mut()) {
                *v *= 1.01;
            }
        }
        let _ = client.submit_result(result_for(&id, &u, r)).await;
    }
    forged
}

/// Client options that connect from 127.0.0.`n`: another host, as the coordinator sees it.
fn from_host(n: u8) -> ClientOptions {
    ClientOptions {
        source_address: Some(std::net::Ipv4Addr::new(127, 0, 0, n).into()),
        ..ClientOptions::default()
    }
}

/// With `--audit 0.6`, a job of 2048 units: the liar sends some 20 wrong results, each
/// merged unchecked with probability 0.4, so the ones merged before it is caught must be taken
/// back; the chance that none of them is checked is about 0.4^20 ≈ 1e-8.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_lying_worker_is_convicted_and_the_image_is_still_bit_identical() {
    lying_worker_among(2, false).await;
}

/// The same in a guided job: the liar's results train guides before it is caught, so the
/// conviction rewinds the job to the first epoch it trained, and the EXR is still `tessera
/// render --guiding`'s.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_lying_worker_in_a_guided_job_is_convicted_and_the_job_rewinds_to_the_local_bits() {
    lying_worker_among(2, true).await;
}

/// #55 D1 on a running farm: one honest worker and the liar. Before, their first dispute made
/// both suspects with no work, and the job never finished; now the coordinator's own render
/// settles each dispute.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn one_honest_worker_and_a_liar_still_finish_with_the_right_bits() {
    lying_worker_among(1, false).await;
}

/// The liar and `n_honest` honest workers, each on a host of its own, render an audited job
/// (`guided`: with `--guiding`).
async fn lying_worker_among(n_honest: u8, guided: bool) {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.audit = 0.6;
    })
    .await;
    let url = coord.url();
    let text = scene_text(32);
    let (spp, batch) = (32, 1);
    let settings = RenderSettings {
        guiding: guided,
        ..job_settings(spp, batch)
    };
    let mut client = coord.client().await;
    let job = client
        .submit_job(pb::SubmitJobRequest {
            tile_size: 4,
            ..submit_request_with(&text, &settings)
        })
        .await
        .expect("submit")
        .into_inner()
        .job_id;
    let stop = Arc::new(AtomicBool::new(false));
    let liar = tokio::spawn(liar(
        url.clone(),
        text.clone(),
        settings.clone(),
        stop.clone(),
    ));
    let honest: Vec<_> = (0..n_honest)
        .map(|i| worker_with(&url, &format!("honest-{i}"), from_host(2 + i)))
        .collect();
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    stop.store(true, Ordering::Relaxed);
    let forged = liar.await.expect("liar");
    assert!(forged > 0, "the liar sent no wrong result");

    let workers = list_workers(&mut client).await;
    let liar_info = workers.iter().find(|w| w.name == "liar").expect("listed");
    assert!(
        liar_info.convicted.contains("audit") && liar_info.quarantined,
        "{liar_info:?}"
    );
    let passed = AtomicU64::new(0);
    for w in workers.iter().filter(|w| w.name.starts_with("honest")) {
        assert!(
            w.convicted.is_empty() && !w.quarantined && !w.suspect,
            "{w:?}"
        );
        passed.fetch_add(w.audits_passed, Ordering::Relaxed);
    }
    assert!(passed.load(Ordering::Relaxed) > 0, "no audit ran");

    let farm = fetch(&mut client, &job).await;
    let local = local_exr_with(&text, &settings, ExrChannels::default(), dir.path());
    assert!(
        farm == local,
        "the farm's EXR differs from tessera render's"
    );
    for h in honest {
        h.abort();
    }
    coord.stop().await;
}
