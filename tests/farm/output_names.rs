//! Output names are never taken twice, nor files overwritten.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn output_names_are_never_taken_twice_nor_files_overwritten() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let text = scene_text(16);
    let mut client = coord.client().await;
    // A later job's default name cannot be taken in advance.
    let e = submit_named(&mut client, &text, "job-000004.exr")
        .await
        .expect_err("a default name");
    assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
    let w = worker(&coord.url(), "w");
    let first = submit_named(&mut client, &text, "shot.exr")
        .await
        .expect("named");
    assert_eq!(
        wait(&mut client, &first).await.state,
        pb::JobState::Done as i32
    );
    let before = fetch(&mut client, &first).await;
    // The name stays with the finished job: fetch keeps returning its image.
    let e = submit_named(&mut client, &scene_text(24), "shot.exr")
        .await
        .expect_err("a finished job's name");
    assert_eq!(e.code(), tonic::Code::AlreadyExists, "{e:?}");
    assert_eq!(fetch(&mut client, &first).await, before);
    // A file someone put in the output directory is theirs.
    std::fs::write(coord.out.join("mine.exr"), b"not ours").expect("write");
    let e = submit_named(&mut client, &text, "mine.exr")
        .await
        .expect_err("a file in the way");
    assert_eq!(e.code(), tonic::Code::AlreadyExists, "{e:?}");
    // Default names squatted by files are passed over, not waited for. (Refused submissions
    // take no id: the next one would be the second.)
    for n in [2, 3] {
        std::fs::write(coord.out.join(format!("job-{n:06}.exr")), b"squat").expect("write");
    }
    let job = submit(&mut client, &text, 2, 2, 0).await;
    assert_eq!(job, "job-000004");
    assert_eq!(
        wait(&mut client, &job).await.state,
        pb::JobState::Done as i32
    );
    // A job whose name is taken while it renders fails rather than overwrite the file.
    w.abort();
    let job = submit(&mut client, &text, 2, 2, 0).await;
    let next = format!("{job}.exr");
    std::fs::write(coord.out.join(&next), b"also not ours").expect("write");
    let w = worker(&coord.url(), "w2");
    let s = wait(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Failed as i32);
    assert!(s.error.contains("exists"), "{}", s.error);
    assert_eq!(
        std::fs::read(coord.out.join(&next)).expect("kept"),
        b"also not ours"
    );
    w.abort();
    coord.stop().await;
}

/// The attack of #55 A: a link planted in the output directory at the name the coordinator
/// used to write its temporary EXR to (`.NAME.tmp-<pid>`, predictable) had its target
/// overwritten with the EXR, and the output became a link to it. Now the temporary name is
/// random and made with `O_EXCL`, and the output is a file of its own.
#[cfg(unix)]
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_link_at_the_old_temporary_name_is_not_followed() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let victim = dir.path().join("victim.txt");
    std::fs::write(&victim, b"the victim's bytes").expect("victim");
    let mut client = coord.client().await;
    // Once the coordinator answers, its output directory exists.
    client
        .list_jobs(pb::ListJobsRequest::default())
        .await
        .expect("list");
    let planted = coord
        .out
        .join(format!(".sq.exr.tmp-{}", std::process::id()));
    std::os::unix::fs::symlink(&victim, &planted).expect("link");
    let w = worker(&coord.url(), "w");
    let job = submit_named(&mut client, &scene_text(16), "sq.exr")
        .await
        .expect("named");
    assert_eq!(
        wait(&mut client, &job).await.state,
        pb::JobState::Done as i32
    );
    assert_eq!(
        std::fs::read(&victim).expect("victim"),
        b"the victim's bytes"
    );
    let out = coord.out.join("sq.exr");
    assert!(!std::fs::symlink_metadata(&out).expect("stat").is_symlink());
    assert_eq!(
        std::fs::read(&out).expect("out"),
        fetch(&mut client, &job).await
    );
    // The planted link is left as it was, and no temporary file is left beside it.
    let names: Vec<String> = std::fs::read_dir(&coord.out)
        .expect("ls")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
    w.abort();
    coord.stop().await;
}
