//! End-to-end farm tests: a coordinator and workers in-process on loopback (port 0), driven
//! through the real gRPC API, one behaviour per file (as tonic's integration tests are
//! organised), in one test binary so that they link once. The farm's EXR must be bit-identical
//! to the local renderer's.

mod common;

mod adaptive;
mod after;
mod assets;
mod audit;
mod auth;
mod bad_submissions;
mod bound_ids;
mod checkpoints;
mod connections;
mod control;
mod dashboard;
mod denoise_workers;
mod drain;
mod forged_results;
mod frames;
mod guiding;
mod http_api;
mod logs;
mod output_checks;
mod output_names;
mod parses;
mod priorities;
mod restart;
mod retention;
mod retry;
mod revisions;
mod same_bits;
mod scene_gc;
mod tls;
mod unrenderable;
mod users;
mod worker_death;
