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
        client.list_jobs(pb::ListJobsRequest::default()),
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

/// Opens a connection that speaks HTTP/2 (the client preface and SETTINGS) and then sends a
/// PING every `every`, never a request: traffic that resets any idle timer, and no token.
async fn pinger(addr: SocketAddr, every: Duration) -> Option<tokio::task::JoinHandle<()>> {
    use tokio::io::AsyncWriteExt;
    let mut s = tokio::net::TcpStream::connect(addr).await.ok()?;
    let mut hello = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n".to_vec();
    hello.extend_from_slice(&[0, 0, 0, 4, 0, 0, 0, 0, 0]);
    s.write_all(&hello).await.ok()?;
    Some(tokio::spawn(async move {
        let ping = [0u8, 0, 8, 6, 0, 0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8];
        // Reads are drained so the server never blocks writing to us; a closed connection ends
        // the task.
        let (mut r, mut w) = s.into_split();
        let drain = tokio::spawn(async move {
            use tokio::io::AsyncReadExt;
            let mut buf = [0u8; 1024];
            while matches!(r.read(&mut buf).await, Ok(n) if n > 0) {}
        });
        while w.write_all(&ping).await.is_ok() {
            if drain.is_finished() {
                return;
            }
            tokio::time::sleep(every).await;
        }
    }))
}

/// The attack of #55 E: a peer without the token opens many HTTP/2 connections and pings on
/// each, so the idle timer never closes them; before, they held every slot and authorised
/// clients waited for as long as the pings went on. Now a connection that has not made a
/// request with the token is closed to make room (and after `conn::PROVE_WITHIN` anyway), so
/// a client with the token is answered at once, well inside that deadline.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn unauthenticated_pinging_connections_do_not_shut_out_token_holders() {
    let token = Secret::new("farm-token-0123456789abcdef");
    let t = token.clone();
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.token = Some(t);
        c.max_connections = 16;
    })
    .await;
    let mut pingers = Vec::new();
    for _ in 0..64 {
        if let Some(p) = pinger(coord.addr, Duration::from_millis(100)).await {
            pingers.push(p);
        }
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let options = ClientOptions {
        token: Some(token),
        ..ClientOptions::default()
    };
    for round in 0..3 {
        let answered = tokio::time::timeout(Duration::from_secs(5), async {
            let mut client = client_with(&coord.url(), &options).await;
            client.list_jobs(pb::ListJobsRequest::default()).await
        })
        .await;
        assert!(
            matches!(answered, Ok(Ok(_))),
            "round {round}: a client with the token was not answered within 5 s: {answered:?}"
        );
        // The pingers keep opening connections as theirs are closed.
        for _ in 0..16 {
            if let Some(p) = pinger(coord.addr, Duration::from_millis(100)).await {
                pingers.push(p);
            }
        }
    }
    for p in pingers {
        p.abort();
    }
    coord.stop().await;
}
