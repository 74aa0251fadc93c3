//! # tessera-proto
//!
//! The farm's wire protocol, `tessera.v1`, generated from `proto/tessera/v1/farm.proto` (see
//! that file for what every message and field means), plus the few conversions every side
//! needs. Generated code is allowed to lack doc comments; the .proto documents it.

#![allow(missing_docs, clippy::all)]

/// Version 1 of the protocol.
pub mod v1 {
    tonic::include_proto!("tessera.v1");
}

/// Lease and job ids are strings on the wire so that their form can change without a protocol
/// change; these are the largest accepted, to bound what a peer can make us store.
pub const MAX_ID_LEN: usize = 64;
