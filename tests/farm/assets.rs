//! Scenes with files (meshes, textures) on the farm: each file uploaded once by its SHA-256, in chunks,
//! resumable (across a coordinator restart too); workers fetch and cache it by hash; the job's
//! identity covers it, so the farm's EXR is the local render's, bit for bit. And what a hostile
//! or broken client can send instead: wrong bytes for a hash, out-of-order chunks, files over
//! the limit, jobs naming files never uploaded.

use std::collections::BTreeMap;

use tessera_render::scene::assets::{sha256_hex, MemAssets};

use crate::common::*;

fn cube_obj() -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/meshes/cube.obj"))
        .expect("cube.obj")
}

/// cornell-mesh.toml at `size`².
fn mesh_scene(size: u32) -> String {
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-mesh.toml"),
    )
    .expect("cornell-mesh.toml")
    .replace("width = 256", &format!("width = {size}"))
    .replace("height = 256", &format!("height = {size}"))
}

fn chunk(hash: &str, offset: u64, total: u64, data: &[u8]) -> pb::AssetChunk {
    pb::AssetChunk {
        sha256: hash.into(),
        offset,
        total_size: total,
        data: data.to_vec(),
    }
}

async fn status(client: &mut Client, hash: &str) -> pb::AssetStatus {
    client
        .get_asset_status(pb::GetAssetStatusRequest {
            sha256: hash.into(),
        })
        .await
        .expect("status")
        .into_inner()
}

async fn upload(
    client: &mut Client,
    chunks: Vec<pb::AssetChunk>,
) -> Result<pb::AssetStatus, tonic::Status> {
    client
        .upload_asset(tokio_stream::iter(chunks))
        .await
        .map(|r| r.into_inner())
}

fn mesh_request(text: &str, hash: &str) -> pb::SubmitJobRequest {
    pb::SubmitJobRequest {
        assets: vec![pb::AssetRef {
            name: "meshes/cube.obj".into(),
            sha256: hash.into(),
        }],
        ..submit_request(text, 4, 2)
    }
}

/// The EXR `tessera render` writes for the mesh scene.
fn local_mesh_exr(text: &str, dir: &Path) -> Vec<u8> {
    let files = MemAssets(BTreeMap::from([(
        "meshes/cube.obj".to_string(),
        cube_obj(),
    )]));
    local_exr_files(
        text,
        &job_settings(4, 2),
        ExrChannels::default(),
        dir,
        &files,
    )
}

/// An upload cut off half way resumes where it stopped, even after the coordinator restarts;
/// the job over the file renders on workers that fetch it, and its EXR is the local one.
///
/// Long because it is one scenario, its steps in the order they happen to the farm (each
/// step's state is the next one's start); split into functions, that order would be hidden.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_interrupted_upload_resumes_and_the_mesh_job_gives_the_local_bits() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    let coord = Coordinator::start(&data, lease).await;
    let addr = coord.addr;
    let mut client = coord.client().await;
    let bytes = cube_obj();
    let hash = sha256_hex(&bytes);
    let total = bytes.len() as u64;
    assert_eq!(status(&mut client, &hash).await.received, 0);
    // The first 100 bytes, in two chunks, then the stream ends.
    let held = upload(
        &mut client,
        vec![
            chunk(&hash, 0, total, &bytes[..60]),
            chunk(&hash, 60, total, &bytes[60..100]),
        ],
    )
    .await
    .expect("partial upload");
    assert_eq!((held.received, held.complete), (100, false));
    // A job over a file not all there is refused, naming it.
    let text = mesh_scene(16);
    let e = client
        .submit_job(mesh_request(&text, &hash))
        .await
        .expect_err("not uploaded");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("meshes/cube.obj"), "{}", e.message());
    // The partial upload survives a restart.
    drop(client);
    coord.stop().await;
    let coord = Coordinator::restart_at(addr, &data, lease).await;
    let mut client = coord.client().await;
    let s = status(&mut client, &hash).await;
    assert_eq!((s.received, s.complete), (100, false));
    // Resuming anywhere but at the bytes held is refused.
    let e = upload(&mut client, vec![chunk(&hash, 50, total, &bytes[50..])])
        .await
        .expect_err("wrong offset");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(
        e.message().contains("100 bytes are held"),
        "{}",
        e.message()
    );
    let done = upload(&mut client, vec![chunk(&hash, 100, total, &bytes[100..])])
        .await
        .expect("resume");
    assert_eq!((done.received, done.complete), (total, true));
    // Uploading it again stores nothing new.
    let again = upload(&mut client, vec![chunk(&hash, 0, total, &bytes)])
        .await
        .expect("again");
    assert!(again.complete);

    let job = client
        .submit_job(mesh_request(&text, &hash))
        .await
        .expect("submit")
        .into_inner();
    // Only a worker holding a lease of the job reads its scene and files (#79.5).
    let mut workers = workers_client(&coord.url());
    let outsider = register_as(&mut workers, "outsider", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let hand = register_as(&mut workers, "hand", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let units = lease_now(&mut workers, &hand, 1).await.expect("lease");
    assert_eq!(units.len(), 1);
    let scene_of = |worker_id: &str| pb::GetSceneRequest {
        scene_hash: units[0].scene_hash.clone(),
        worker_id: worker_id.into(),
    };
    let e = fetch_asset(&mut workers, &outsider, &hash)
        .await
        .expect_err("no lease");
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    assert!(e.message().contains("holds no lease"), "{}", e.message());
    let e = workers
        .get_scene(scene_of(&outsider))
        .await
        .expect_err("no lease");
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    // Another worker's id without its secret is no one's.
    let public = hand.split('.').next().expect("id");
    let e = fetch_asset(&mut workers, public, &hash)
        .await
        .expect_err("no secret");
    assert_ne!(e.code(), tonic::Code::Ok);
    let scene = workers
        .get_scene(scene_of(&hand))
        .await
        .expect("the leaseholder reads the scene")
        .into_inner();
    assert_eq!(scene.assets.len(), 1);
    assert_eq!(
        fetch_asset(&mut workers, &hand, &hash)
            .await
            .expect("the leaseholder fetches the file"),
        bytes
    );
    workers
        .release_leases(pb::ReleaseLeasesRequest {
            worker_id: hand.clone(),
            lease_ids: vec![units[0].lease_id.clone()],
            goodbye: false,
            cannot_render: String::new(),
        })
        .await
        .expect("release");
    let w = worker(&coord.url(), "mesh-worker");
    let s = wait(&mut client, &job.job_id).await;
    assert_eq!(s.state, pb::JobState::Done as i32, "{}", s.error);
    let farm = fetch(&mut client, &job.job_id).await;
    assert!(
        farm == local_mesh_exr(&text, dir.path()),
        "the farm's EXR differs from the local one"
    );
    // The job has ended: its files are no longer anyone's to read.
    let e = fetch_asset(&mut workers, &hand, &hash)
        .await
        .expect_err("ended");
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    w.abort();
    coord.stop().await;
}

/// A scene's files of every kind travel: textured.toml's two OBJ files and its PNG texture
/// are uploaded, named in the job, fetched by the worker, and the farm's EXR is the local
/// render's bit for bit.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_textured_job_carries_its_texture_and_gives_the_local_bits() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let text = std::fs::read_to_string(scenes.join("textured.toml"))
        .expect("textured.toml")
        .replace("width = 256", "width = 16")
        .replace("height = 256", "height = 16");
    let names = [
        "meshes/quad.obj",
        "meshes/textured-cube.obj",
        "textures/checker.png",
    ];
    let mut files = BTreeMap::new();
    let mut assets = Vec::new();
    for name in names {
        let bytes = std::fs::read(scenes.join(name)).expect("scene file");
        let hash = sha256_hex(&bytes);
        let done = upload(
            &mut client,
            vec![chunk(&hash, 0, bytes.len() as u64, &bytes)],
        )
        .await
        .expect("upload");
        assert!(done.complete, "{name}");
        assets.push(pb::AssetRef {
            name: name.into(),
            sha256: hash,
        });
        files.insert(name.to_string(), bytes);
    }
    // Without the texture the job is refused at the material that names it.
    let e = client
        .submit_job(pb::SubmitJobRequest {
            assets: assets[..2].to_vec(),
            ..submit_request(&text, 4, 2)
        })
        .await
        .expect_err("texture missing");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(
        e.message()
            .contains("`textures/checker.png` is not among the files sent with the job"),
        "{}",
        e.message()
    );
    let job = client
        .submit_job(pb::SubmitJobRequest {
            assets,
            ..submit_request(&text, 4, 2)
        })
        .await
        .expect("submit")
        .into_inner();
    let w = worker(&coord.url(), "texture-worker");
    let s = wait(&mut client, &job.job_id).await;
    assert_eq!(s.state, pb::JobState::Done as i32, "{}", s.error);
    let farm = fetch(&mut client, &job.job_id).await;
    let local = local_exr_files(
        &text,
        &job_settings(4, 2),
        ExrChannels::default(),
        dir.path(),
        &MemAssets(files),
    );
    assert!(farm == local, "the farm's EXR differs from the local one");
    w.abort();
    coord.stop().await;
}

/// Identity: the same scene text over other mesh bytes is another scene (another hash), and
/// a job that does not list a file its scene names is refused with the scene's own message.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_job_identity_covers_the_files() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    let a = cube_obj();
    let b = String::from_utf8(a.clone())
        .expect("text")
        .replace("v  1  1  1", "v  1  1  0.5")
        .into_bytes();
    let (ha, hb) = (sha256_hex(&a), sha256_hex(&b));
    for (h, bytes) in [(&ha, &a), (&hb, &b)] {
        upload(&mut client, vec![chunk(h, 0, bytes.len() as u64, bytes)])
            .await
            .expect("upload");
    }
    let text = mesh_scene(16);
    let ja = client
        .submit_job(mesh_request(&text, &ha))
        .await
        .expect("a")
        .into_inner();
    let jb = client
        .submit_job(mesh_request(&text, &hb))
        .await
        .expect("b")
        .into_inner();
    assert_ne!(ja.scene_hash, jb.scene_hash);
    let e = client
        .submit_job(submit_request(&text, 4, 2))
        .await
        .expect_err("files missing from the job");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(
        e.message().contains(
            "objects[6].file: `meshes/cube.obj` is not among the files sent with the job"
        ),
        "{}",
        e.message()
    );
    coord.stop().await;
}

/// What a hostile or broken client can send instead of a file.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn bad_uploads_are_refused_and_leave_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.limits.max_asset_bytes = 1000
    })
    .await;
    let mut client = coord.client().await;
    let bytes = cube_obj();
    let hash = sha256_hex(&bytes);
    let total = bytes.len() as u64;
    // Other bytes under this hash: refused once the last byte is in, and thrown away.
    let mut forged = bytes.clone();
    forged[10] ^= 1;
    let e = upload(&mut client, vec![chunk(&hash, 0, total, &forged)])
        .await
        .expect_err("forged content");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(
        e.message().contains("the upload is discarded"),
        "{}",
        e.message()
    );
    let s = status(&mut client, &hash).await;
    assert_eq!((s.received, s.complete), (0, false));
    // A file over the limit, chunks past the declared size, a malformed hash, two files in
    // one stream, and an empty stream.
    let big = "a".repeat(64);
    let e = upload(&mut client, vec![chunk(&big, 0, 1001, b"x")])
        .await
        .expect_err("too big");
    assert_eq!(e.code(), tonic::Code::ResourceExhausted, "{e:?}");
    let e = upload(&mut client, vec![chunk(&hash, 0, 10, &bytes[..20])])
        .await
        .expect_err("past the end");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(
        e.message().contains("past the declared size"),
        "{}",
        e.message()
    );
    for bad in ["../../etc/passwd", "ABCDEF", &"g".repeat(64)] {
        let e = upload(&mut client, vec![chunk(bad, 0, 1, b"x")])
            .await
            .expect_err("bad hash");
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{bad}");
    }
    let other = "b".repeat(64);
    let e = upload(
        &mut client,
        vec![
            chunk(&hash, 0, total, &bytes[..10]),
            chunk(&other, 10, total, &bytes[10..20]),
        ],
    )
    .await
    .expect_err("two files");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    let e = upload(&mut client, vec![]).await.expect_err("empty");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    // The first stream's 10 bytes were kept: the upload resumes from them.
    assert_eq!(status(&mut client, &hash).await.received, 10);
    let done = upload(&mut client, vec![chunk(&hash, 10, total, &bytes[10..])])
        .await
        .expect("resume");
    assert!(done.complete);
    // Many unfinished uploads: the 65th is refused rather than left to fill the disk.
    for k in 0..64u64 {
        let h = format!("{k:064x}");
        upload(&mut client, vec![chunk(&h, 0, 100, b"partial")])
            .await
            .expect("partial");
    }
    let e = upload(&mut client, vec![chunk(&"c".repeat(64), 0, 100, b"x")])
        .await
        .expect_err("hoarding");
    assert_eq!(e.code(), tonic::Code::ResourceExhausted);
    // A worker asking for a file never uploaded, or a malformed one: no job reads it.
    let mut workers = workers_client(&coord.url());
    let id = register_as(&mut workers, "asker", "0", IMAGE_REVISION)
        .await
        .expect("register");
    for h in [big.as_str(), "nope"] {
        let e = fetch_asset(&mut workers, &id, h)
            .await
            .expect_err("no file");
        assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    }
    // A job listing a file twice, or too many files.
    let mut req = mesh_request(&mesh_scene(16), &hash);
    req.assets.push(req.assets[0].clone());
    let e = client.submit_job(req).await.expect_err("twice");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    coord.stop().await;
}

/// The coordinator deletes the files no active job names once their retention has passed:
/// a job's mesh stays while the job is active, an upload no job names goes, and the mesh
/// goes once the job ends, after which a job naming it is refused until it is uploaded
/// again. Run in-process with a retention of zero, collecting by hand, so that what is
/// collected does not depend on timing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn files_no_active_job_names_are_collected() {
    use tessera_coordinator::{Config, InProcess};
    use tessera_proto::v1::jobs_server::Jobs;
    let dir = tempfile::tempdir().expect("tempdir");
    let mut config = Config::new(dir.path());
    config.asset_retention = Duration::ZERO;
    let farm = InProcess::open(config).expect("open");
    let cube = cube_obj();
    let hash = sha256_hex(&cube);
    let held = |farm: &InProcess, h: &str| farm.assets().status(h).expect("status").complete;
    farm.assets()
        .append(&hash, 0, cube.len() as u64, &cube)
        .expect("upload the mesh");
    let stray = b"a file no job names".to_vec();
    let stray_hash = sha256_hex(&stray);
    farm.assets()
        .append(&stray_hash, 0, stray.len() as u64, &stray)
        .expect("upload the stray file");
    let text = mesh_scene(8);
    let job = farm
        .service()
        .submit_job(tonic::Request::new(mesh_request(&text, &hash)))
        .await
        .expect("submit")
        .into_inner()
        .job_id;
    let c = farm
        .collect_assets()
        .expect("collect")
        .expect("not held off");
    assert_eq!((c.files, c.bytes), (1, stray.len() as u64), "{c:?}");
    assert!(held(&farm, &hash), "the active job's mesh was collected");
    assert!(!held(&farm, &stray_hash));
    farm.service()
        .cancel_job(tonic::Request::new(pb::CancelJobRequest { job_id: job }))
        .await
        .expect("cancel");
    let c = farm
        .collect_assets()
        .expect("collect")
        .expect("not held off");
    assert_eq!(c.files, 1, "{c:?}");
    assert!(!held(&farm, &hash), "the ended job's mesh was kept");
    let e = farm
        .service()
        .submit_job(tonic::Request::new(mesh_request(&text, &hash)))
        .await
        .expect_err("its mesh is gone");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition);
    assert!(e.message().contains("meshes/cube.obj"), "{}", e.message());
    farm.close().await;
}

/// Over gRPC, an upload that would pass the store's byte budget is refused
/// (`RESOURCE_EXHAUSTED`), naming the budget and the flag, and leaves nothing behind; files
/// within it are taken.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_asset_store_budget_refuses_what_would_pass_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cube = cube_obj();
    let budget = cube.len() as u64 + 10;
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.asset_store_bytes = budget
    })
    .await;
    let mut client = coord.client().await;
    let hash = sha256_hex(&cube);
    let total = cube.len() as u64;
    let s = upload(&mut client, vec![chunk(&hash, 0, total, &cube)])
        .await
        .expect("within the budget");
    assert!(s.complete);
    let other = vec![b'#'; 11];
    let other_hash = sha256_hex(&other);
    let e = upload(&mut client, vec![chunk(&other_hash, 0, 11, &other)])
        .await
        .expect_err("over the budget");
    assert_eq!(e.code(), tonic::Code::ResourceExhausted, "{e:?}");
    assert!(
        e.message().contains(&format!("budget of {budget}"))
            && e.message().contains("--asset-store-bytes"),
        "{}",
        e.message()
    );
    let s = status(&mut client, &other_hash).await;
    assert_eq!((s.received, s.complete), (0, false));
    // Ten bytes still fit.
    let small = vec![b'#'; 10];
    let s = upload(&mut client, vec![chunk(&sha256_hex(&small), 0, 10, &small)])
        .await
        .expect("the last ten bytes");
    assert!(s.complete);
    coord.stop().await;
}
