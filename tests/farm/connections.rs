//! Silent connections are closed and do not starve clients.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn silent_connections_are_closed_and_do_not_starve_clients() {
    use tokio::io::AsyncReadExt;
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.max_connections = 4;
        c.idle_connection = Duration::from_millis(500);
    })
    .await;
    // Every connection slot taken by a peer that sends nothing.
    let mut silent = Vec::new();
    for _ in 0..4 {
        silent.push(
            tokio::net::TcpStream::connect(coord.addr)
                .await
                .expect("connect"),
        );
    }
    // A real client still gets its answer, once the silent ones are cut off.
    let mut client = coord.client().await;
    let listed = tokio::time::timeout(
        Duration::from_secs(20),
        client.list_jobs(pb::ListJobsRequest {}),
    )
    .await
    .expect("answered in time")
    .expect("list");
    assert!(listed.into_inner().jobs.is_empty());
    for mut s in silent {
        let mut buf = [0u8; 64];
        // The server's HTTP/2 preface may come first; then the connection is closed.
        let closed = tokio::time::timeout(Duration::from_secs(10), async {
            loop {
                match s.read(&mut buf).await {
                    Ok(0) | Err(_) => return,
                    Ok(_) => {}
                }
            }
        })
        .await;
        assert!(closed.is_ok(), "a silent connection was kept open");
    }
    coord.stop().await;
}
