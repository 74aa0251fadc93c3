//! Several workers give the bits of one local render.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn three_workers_render_the_same_bits_as_a_local_render() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let workers: Vec<_> = (0..3)
        .map(|i| worker(&coord.url(), &format!("w{i}")))
        .collect();
    let text = scene_text(48);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 24, 8, 0).await;
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    assert_eq!(status.units_done, status.units_total);
    assert_eq!(status.units_total, 9 * 3);
    let farm = fetch(&mut client, &job).await;
    assert_eq!(
        std::fs::read(coord.out.join(format!("{job}.exr"))).expect("output file"),
        farm
    );
    let local = local_exr(&text, 24, 8, dir.path());
    assert!(farm == local, "farm EXR differs from the local render");

    let listed = list_workers(&mut client).await;
    assert_eq!(listed.len(), 3);
    assert_eq!(listed.iter().map(|w| w.units_done).sum::<u64>(), 27);
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}
