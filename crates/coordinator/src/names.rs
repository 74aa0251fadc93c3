//! Output names: the name a job's EXR gets. Pure: it reads the output directory to avoid
//! files already there, and writes nothing.
//!
//! Names are never taken twice and files never overwritten: a name stays with its job for
//! good (so `fetch` always returns that job's image), a default-form name `job-NNNNNN.exr` is
//! kept for the job of that id, and a file already in the output directory is someone else's.

use std::path::Path;

use tessera_proto::ids::JobId;
use tessera_render::scene::FrameRange;

use crate::error::{truncate, Refusal};

/// Whether `name` is an acceptable output file name: a plain file name, never a path.
pub fn check_output_name(name: &str) -> Result<(), Refusal> {
    let ok = !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name.ends_with(".exr")
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'.' || b == b'_' || b == b'-');
    if !ok {
        return Err(Refusal::Invalid(format!(
            "output name {:?} must be 1–128 letters, digits, '.', '_' or '-', not start with \
             '.', and end in \".exr\"",
            truncate(name)
        )));
    }
    if JobId::is_default_output_name(name) {
        return Err(Refusal::Invalid(format!(
            "output name {name} is kept for the job of that id; choose another name, or none \
             to get the job's own"
        )));
    }
    Ok(())
}

/// Chooses output names in one output directory.
pub struct OutputNames<'a> {
    dir: &'a Path,
}

/// Most ids an unnamed job skips past files squatting on their default names.
const MAX_SKIPPED_IDS: u64 = 10_000;

impl<'a> OutputNames<'a> {
    /// Names in `dir`.
    pub fn new(dir: &'a Path) -> Self {
        Self { dir }
    }

    /// Whether something (a file, a link, even a dangling one) has this name in the directory.
    fn on_disk(&self, name: &str) -> bool {
        self.dir.join(name).symlink_metadata().is_ok()
    }

    /// The id and output name of a new job: `asked` if given (checked for form already), else
    /// the default name of `next` or, if a file already has that, of the first id after it
    /// whose default name is free (waiting for the file to go would block every unnamed job).
    /// `jobs` are the existing jobs' names.
    pub fn choose<'j>(
        &self,
        next: JobId,
        asked: Option<String>,
        mut jobs: impl Iterator<Item = (JobId, &'j str)>,
    ) -> Result<(JobId, String), Refusal> {
        let mut id = next;
        let name = match asked {
            Some(name) => name,
            None => {
                while id.0 - next.0 < MAX_SKIPPED_IDS && self.on_disk(&id.default_output_name()) {
                    id = JobId(id.0 + 1);
                }
                id.default_output_name()
            }
        };
        if let Some((other, _)) = jobs.find(|(_, n)| *n == name) {
            return Err(Refusal::Exists(format!(
                "output name {name} belongs to {other}; choose another"
            )));
        }
        if self.on_disk(&name) {
            return Err(Refusal::Exists(format!(
                "output name {name}: a file of that name is already in the output directory, \
                 and the coordinator never overwrites one; choose another"
            )));
        }
        Ok((id, name))
    }
}

impl OutputNames<'_> {
    /// The id and frame output names of a new frame-range job: `STEM.####.exr` for each
    /// frame (at least four digits), `STEM` the asked name without `.exr`, else the range's
    /// id, skipping ids whose names a file already has as [`choose`](Self::choose) does.
    pub fn choose_range<'j>(
        &self,
        next: JobId,
        asked: Option<String>,
        frames: FrameRange,
        jobs: impl Iterator<Item = (JobId, &'j str)>,
    ) -> Result<(JobId, Vec<String>), Refusal> {
        let names = |stem: &str| -> Vec<String> {
            frames
                .iter()
                .map(|f| format!("{stem}.{f:04}.exr"))
                .collect()
        };
        let taken: std::collections::HashMap<&str, JobId> = jobs.map(|(j, n)| (n, j)).collect();
        let mut id = next;
        let names = match asked {
            Some(name) => names(name.strip_suffix(".exr").unwrap_or(&name)),
            None => loop {
                let stem = id.to_string();
                let n = names(&stem);
                if id.0 - next.0 >= MAX_SKIPPED_IDS || !n.iter().any(|n| self.on_disk(n)) {
                    break n;
                }
                // Past the squatted id and as many more as the range's frames would take.
                id = JobId(id.0 + 1 + n.len() as u64);
            },
        };
        for name in &names {
            if let Some(other) = taken.get(name.as_str()) {
                return Err(Refusal::Exists(format!(
                    "output name {name} belongs to {other}; choose another"
                )));
            }
            if self.on_disk(name) {
                return Err(Refusal::Exists(format!(
                    "output name {name}: a file of that name is already in the output \
                     directory, and the coordinator never overwrites one; choose another"
                )));
            }
        }
        Ok((id, names))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_plain_files_and_default_forms_are_kept_for_their_jobs() {
        for bad in [
            "",
            ".exr",
            "a/b.exr",
            "../x.exr",
            "x.png",
            ".hidden.exr",
            "job-000004.exr",
        ] {
            assert!(check_output_name(bad).is_err(), "{bad:?}");
        }
        assert!(check_output_name("shot_010-v2.exr").is_ok());
    }

    #[test]
    fn an_unnamed_job_skips_ids_whose_default_name_a_file_has() {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::write(dir.path().join("job-000003.exr"), b"theirs").expect("write");
        #[cfg(unix)]
        std::os::unix::fs::symlink("/nonexistent", dir.path().join("job-000004.exr"))
            .expect("link");
        let names = OutputNames::new(dir.path());
        let (id, name) = names
            .choose(JobId(3), None, std::iter::empty())
            .expect("free");
        assert_eq!((id, name.as_str()), (JobId(5), "job-000005.exr"));
        let taken = [(JobId(1), "a.exr")];
        assert!(matches!(
            names.choose(JobId(6), Some("a.exr".into()), taken.into_iter()),
            Err(Refusal::Exists(m)) if m.contains("belongs to job-000001")
        ));
        std::fs::write(dir.path().join("b.exr"), b"theirs").expect("write");
        assert!(matches!(
            names.choose(JobId(6), Some("b.exr".into()), std::iter::empty()),
            Err(Refusal::Exists(m)) if m.contains("never overwrites")
        ));
    }
}
