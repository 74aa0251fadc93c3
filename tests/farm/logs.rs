//! Workers' log lines over the wire (`ReportLog`, `GetLogs`): kept with the job whose unit they
//! are about, only from the worker that was leased it, bounded per call and per worker's rate,
//! and kept across a restart.

use crate::common::*;

fn line(lease: &str, message: &str) -> pb::WorkerLogLine {
    pb::WorkerLogLine {
        lease_id: lease.into(),
        level: pb::LogLevel::Warn as i32,
        message: message.into(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_workers_lines_stay_with_its_units_job_bounded_and_across_a_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    let coord = Coordinator::start(&data, lease).await;
    let text = scene_text(32);
    let mut client = coord.client().await;
    let a = submit(&mut client, &text, 4, 2, 1).await;
    let b = submit(&mut client, &text, 4, 2, 0).await;
    let mut hand = workers_client(&coord.url());
    let h = register_as(&mut hand, "h", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let other = register_as(&mut hand, "other", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let mine = lease_now(&mut hand, &h, 2).await.expect("lease");
    assert!(mine.iter().all(|u| u.job_id == a));
    let theirs = lease_now(&mut hand, &other, 8).await.expect("lease");
    let of_b = theirs.iter().find(|u| u.job_id == b).expect("a unit of b");
    let report = |lines: Vec<pb::WorkerLogLine>| pb::ReportLogRequest {
        worker_id: h.clone(),
        lines,
    };
    let r = hand
        .report_log(report(vec![
            line(&mine[0].lease_id, "12 non-finite samples were left out"),
            line(&mine[1].lease_id, "texture fell back\u{1b}[2J"),
            // Another worker's unit: not this worker's to write about.
            line(&of_b.lease_id, "forged"),
        ]))
        .await
        .expect("report")
        .into_inner();
    assert_eq!((r.kept, r.dropped), (2, 1));
    let logs = |job: &str, after: u64| pb::GetLogsRequest {
        job_id: job.into(),
        frame: None,
        after,
    };
    let got = client
        .get_logs(logs(&a, 0))
        .await
        .expect("logs")
        .into_inner();
    assert_eq!(got.entries.len(), 2);
    let first = &got.entries[0];
    assert_eq!(first.job_id, a);
    assert_eq!(first.worker_name, "h");
    assert_eq!(
        (first.tile_index, first.batch_index),
        (mine[0].tile_index, mine[0].batch_index)
    );
    assert!(first.message.contains("non-finite"));
    assert!(!got.ended);
    let b_logs = client.get_logs(logs(&b, 0)).await.expect("b").into_inner();
    assert!(
        b_logs.entries.is_empty(),
        "a forged line landed: {b_logs:?}"
    );
    // Following: only what came after the last line seen.
    let after = client
        .get_logs(logs(&a, first.seq))
        .await
        .expect("after")
        .into_inner();
    assert_eq!(after.entries.len(), 1);

    // Refused whole: too many lines in one call, or a lease id that is not one.
    for bad in [
        vec![line(&mine[0].lease_id, "x"); 33],
        vec![line("not-a-lease", "x")],
    ] {
        let e = hand.report_log(report(bad)).await.expect_err("refused");
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
    }
    // A chatty worker: past its burst, lines are dropped and counted, and a long line is cut.
    let long = "y".repeat(10_000);
    let mut kept = 0;
    let mut dropped = 0;
    for _ in 0..4 {
        let r = hand
            .report_log(report(vec![line(&mine[0].lease_id, &long); 32]))
            .await
            .expect("report")
            .into_inner();
        kept += r.kept;
        dropped += r.dropped;
    }
    assert!(kept < 60 && dropped > 60, "kept {kept}, dropped {dropped}");
    let got = client.get_logs(logs(&a, 0)).await.expect("a").into_inner();
    assert_eq!(got.dropped, u64::from(dropped));
    assert!(got.entries.iter().all(|e| e.message.chars().count() <= 500));

    // A restart keeps the lines (written with a checkpoint) and numbers new ones after them.
    let before = got.entries.len();
    let coord = coord.restarted(&data, lease).await;
    let mut client = coord.client().await;
    let again = client.get_logs(logs(&a, 0)).await.expect("a").into_inner();
    assert_eq!(again.entries.len(), before);
    assert_eq!(again.entries, got.entries);
    let e = client
        .get_logs(logs("job-000999", 0))
        .await
        .expect_err("unknown");
    assert_eq!(e.code(), tonic::Code::NotFound);
    let e = client
        .get_logs(pb::GetLogsRequest {
            frame: Some(3),
            ..logs(&a, 0)
        })
        .await
        .expect_err("no such frame");
    assert_eq!(e.code(), tonic::Code::NotFound);
}

/// An ended job's log is read from the store (a restart does not load it into memory, and the
/// collector's sweep moves it out): `GetLogs` gives the same lines before and after, and says
/// the job has ended.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_ended_jobs_log_is_read_from_the_store() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    // Assets kept 4 s: the collector, which sweeps logs too, runs every second.
    let fast = |c: &mut Config| c.asset_retention = Duration::from_secs(4);
    let coord = Coordinator::start_with(&data, lease, fast).await;
    let mut client = coord.client().await;
    let job = submit(&mut client, &scene_text(32), 4, 2, 0).await;
    let mut hand = workers_client(&coord.url());
    let h = register_as(&mut hand, "h", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let mine = lease_now(&mut hand, &h, 1).await.expect("lease");
    let r = hand
        .report_log(pb::ReportLogRequest {
            worker_id: h.clone(),
            lines: vec![line(&mine[0].lease_id, "a texture fell back")],
        })
        .await
        .expect("report")
        .into_inner();
    assert_eq!(r.kept, 1);
    client
        .cancel_job(pb::CancelJobRequest {
            job_id: job.clone(),
        })
        .await
        .expect("cancel");
    let logs = pb::GetLogsRequest {
        job_id: job.clone(),
        frame: None,
        after: 0,
    };
    // Past a sweep or two, the lines come from the store.
    tokio::time::sleep(Duration::from_secs(3)).await;
    let got = client
        .get_logs(logs.clone())
        .await
        .expect("logs")
        .into_inner();
    assert!(got.ended);
    assert_eq!(got.entries.len(), 1, "{got:?}");
    assert_eq!(got.entries[0].message, "a texture fell back");
    let coord = coord.restarted(&data, lease).await;
    let mut client = coord.client().await;
    let again = client.get_logs(logs).await.expect("logs").into_inner();
    assert_eq!(again.entries, got.entries);
    assert!(again.ended);
}
