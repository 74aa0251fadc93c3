//! A job runs end to end over TLS.

use crate::common::*;

/// A job runs end to end over TLS (server certificate from a test CA), with a token too.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_job_completes_over_tls() {
    let (ca, cert_pem, key_pem) = test_ca_and_cert();

    let dir = tempfile::tempdir().expect("tempdir");
    let token = Secret::new("tls-token-0123456789abcdef");
    let t = token.clone();
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.token = Some(t);
        c.tls = Some(tessera_coordinator::ServerTls {
            cert_pem: cert_pem.into_bytes(),
            key_pem: Secret::new(key_pem),
            client_ca_pem: None,
        });
    })
    .await;
    let url = format!("https://localhost:{}", coord.addr.port());
    let options = ClientOptions {
        token: Some(token),
        tls: Some(ClientTls {
            ca_pem: Some(ca.pem().into_bytes()),
            identity: None,
            domain: None,
        }),
        ..ClientOptions::default()
    };
    // Plain HTTP to a TLS port fails rather than leaking anything.
    let plain = format!("http://127.0.0.1:{}", coord.addr.port());
    let channel = endpoint(&plain, &ClientOptions::default())
        .expect("ep")
        .connect_lazy();
    let mut raw = JobsClient::new(channel);
    assert!(raw.list_jobs(pb::ListJobsRequest::default()).await.is_err());

    render_one_job(&url, &options, &scene_text(16), dir.path()).await;
    coord.stop().await;
}
