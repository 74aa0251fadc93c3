//! The rows a benchmark measures, as CSV, and the peer protocol: a peer renderer run as a
//! child process that measures one point at a time, interleaved with tessera's.

use std::io::{BufRead, BufReader, Write as _};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

/// One timed render.
#[derive(Clone, Debug)]
pub(super) struct Row {
    pub(super) renderer: String,
    pub(super) scene: String,
    pub(super) spp: u32,
    pub(super) seed: u64,
    pub(super) threads: usize,
    pub(super) seconds: f64,
    pub(super) msamples_per_s: f64,
    pub(super) relmse: f64,
    /// Mean FLIP against the reference ([`super::stats::flip`]), where the renderer's row
    /// has one: tessera's always, a peer's when it writes the column.
    pub(super) flip: Option<f64>,
}

/// The CSV columns; a peer may leave out the last (`flip`), or leave it empty.
pub(super) const CSV_HEADER: &str =
    "renderer,scene,spp,seed,threads,seconds,msamples_per_s,relmse,flip";

impl Row {
    /// tessera's row for one timed render of `scene` (named `name`) with `settings` on
    /// `threads` threads: `seconds` for it, and its relMSE and FLIP against the reference
    /// ([`super::stats::errors`]).
    pub(super) fn timed(
        renderer: &str,
        (scene, name): (&tessera_render::scene::Scene, &str),
        settings: &tessera_render::RenderSettings,
        (threads, seconds): (usize, f64),
        (relmse, flip): (f64, f64),
    ) -> Self {
        let samples = scene.width as f64 * scene.height as f64 * settings.spp as f64;
        Row {
            renderer: renderer.into(),
            scene: name.to_string(),
            spp: settings.spp,
            seed: settings.seed,
            threads,
            seconds,
            msamples_per_s: samples / seconds / 1e6,
            relmse,
            flip: Some(flip),
        }
    }

    pub(super) fn to_csv(&self) -> String {
        format!(
            "{},{},{},{},{},{:.6},{:.4},{:.6e},{}",
            self.renderer,
            self.scene,
            self.spp,
            self.seed,
            self.threads,
            self.seconds,
            self.msamples_per_s,
            self.relmse,
            self.flip.map_or(String::new(), |f| format!("{f:.6e}"))
        )
    }

    /// One CSV row; `at` says where it came from (`FILE:LINE`) for the error.
    pub(super) fn parse(line: &str, at: &str) -> Result<Self> {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != 8 && f.len() != 9 {
            bail!(
                "{}: expected 8 or 9 comma-separated fields ({CSV_HEADER}), found {}",
                at,
                f.len()
            );
        }
        let num = |i: usize, what: &str| -> Result<f64> {
            let v: f64 = f[i]
                .parse()
                .with_context(|| format!("{}: {what} {:?} is not a number", at, f[i]))?;
            if !v.is_finite() || v < 0.0 {
                bail!(
                    "{}: {what} must be a finite non-negative number, got {v}",
                    at
                );
            }
            Ok(v)
        };
        let row = Row {
            renderer: f[0].to_string(),
            scene: f[1].to_string(),
            spp: num(2, "spp")? as u32,
            seed: num(3, "seed")? as u64,
            threads: num(4, "threads")? as usize,
            seconds: num(5, "seconds")?,
            msamples_per_s: num(6, "msamples_per_s")?,
            relmse: num(7, "relmse")?,
            flip: match f.get(8) {
                None | Some(&"") => None,
                Some(_) => Some(num(8, "flip")?),
            },
        };
        if row.renderer.is_empty() || row.scene.is_empty() || row.seconds <= 0.0 || row.spp == 0 {
            bail!(
                "{}: renderer and scene must be named, spp and seconds positive",
                at
            );
        }
        Ok(row)
    }
}

/// A peer renderer run as a child process that measures one point at a time, so that each of
/// its points is timed right after tessera's point of the same scene, spp and seed. A peer
/// measured in a separate pass runs minutes away from tessera's matching point, and a slow
/// minute of a shared machine then lands on one side of the ratio only.
///
/// The protocol is one line at a time. tessera writes `SCENE SPP SEED`. The peer answers with
/// zero or more rows in the CSV format (one per renderer it runs at that point, none for a
/// scene it has no counterpart of) and then `done`. A line `error: MESSAGE` ends the run with
/// that message. Closing its stdin asks it to exit.
pub(super) struct PeerCommand {
    command: String,
    child: Child,
    stdin: Option<ChildStdin>,
    stdout: BufReader<ChildStdout>,
    /// Lines read so far, to say which line of the peer's output was wrong.
    lines: usize,
}

impl PeerCommand {
    pub(super) fn start(command: &str) -> Result<Self> {
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(command)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("starting --peer-command {command:?}"))?;
        let (Some(stdin), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
            bail!("--peer-command {command:?}: no pipe to its stdin or stdout");
        };
        Ok(Self {
            command: command.to_string(),
            child,
            stdin: Some(stdin),
            stdout: BufReader::new(stdout),
            lines: 0,
        })
    }

    /// The peer's rows for one point, checked to be that point's.
    pub(super) fn measure(&mut self, scene: &str, spp: u32, seed: u64) -> Result<Vec<Row>> {
        let point = format!("{scene} {spp} {seed}");
        let sent = self.stdin.as_mut().is_some_and(|stdin| {
            writeln!(stdin, "{point}")
                .and_then(|()| stdin.flush())
                .is_ok()
        });
        if !sent {
            return Err(self.ended(&point));
        }
        let mut rows = Vec::new();
        loop {
            let mut line = String::new();
            let read = self.stdout.read_line(&mut line).with_context(|| {
                format!(
                    "--peer-command {:?}: reading its answer to `{point}`",
                    self.command
                )
            })?;
            if read == 0 {
                return Err(self.ended(&point));
            }
            self.lines += 1;
            let line = line.trim();
            if line == "done" {
                return Ok(rows);
            }
            if let Some(message) = line.strip_prefix("error:") {
                bail!(
                    "--peer-command {:?} failed at `{point}`: {}",
                    self.command,
                    message.trim()
                );
            }
            let at = format!("--peer-command output line {}", self.lines);
            let row = Row::parse(line, &at)?;
            if (row.scene.as_str(), row.spp, row.seed) != (scene, spp, seed) {
                bail!(
                    "{at}: a row for scene {} at {} spp, seed {}, in answer to `{point}`",
                    row.scene,
                    row.spp,
                    row.seed
                );
            }
            if row.renderer == "tessera" {
                bail!("{at}: a peer's row may not be named tessera");
            }
            rows.push(row);
        }
    }

    /// The error for a peer that closed its pipes before answering `point`, with how it ended.
    pub(super) fn ended(&mut self, point: &str) -> anyhow::Error {
        self.stdin = None;
        let status = self
            .child
            .wait()
            .map_or_else(|e| format!("cannot tell how: {e}"), |s| s.to_string());
        anyhow::anyhow!(
            "--peer-command {:?} ended ({status}) before it answered `{point}`",
            self.command
        )
    }
}

impl Drop for PeerCommand {
    /// Closes the peer's stdin, which asks it to exit, and waits a little for it; a peer that
    /// does not exit by then is killed, so that it never outlives the bench.
    fn drop(&mut self) {
        self.stdin = None;
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            match self.child.try_wait() {
                Ok(Some(_)) | Err(_) => return,
                Ok(None) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_rows_round_trip_and_bad_rows_name_their_line() {
        let r = Row {
            renderer: "mitsuba-llvm_ad_rgb".into(),
            scene: "cornell-box".into(),
            spp: 64,
            seed: 2,
            threads: 2,
            seconds: 1.5,
            msamples_per_s: 2.8,
            relmse: 1.25e-3,
            flip: Some(0.125),
        };
        let back = Row::parse(&r.to_csv(), "p.csv:2").expect("parses");
        assert_eq!((back.spp, back.seed, back.relmse), (64, 2, 1.25e-3));
        assert_eq!(back.flip, Some(0.125));
        // A peer that measures no FLIP leaves the column out, or empty.
        let no_flip = Row { flip: None, ..r };
        let line = no_flip.to_csv();
        assert!(line.ends_with(','), "{line}");
        assert_eq!(Row::parse(&line, "p.csv:4").expect("empty").flip, None);
        let eight = line.trim_end_matches(',');
        assert_eq!(Row::parse(eight, "p.csv:5").expect("eight").flip, None);
        let e = Row::parse(&format!("{eight},-1"), "p.csv:6").expect_err("negative");
        assert!(e.to_string().contains("flip"), "{e}");
        let e = Row::parse("a,b,1,2", "p.csv:7").expect_err("short");
        assert!(e.to_string().contains("p.csv:7"), "{e}");
        let e = Row::parse("a,b,4,1,2,NaN,1,1", "p.csv:3").expect_err("nan");
        assert!(e.to_string().contains("seconds"), "{e}");
    }
}
