//! Store changes waiting for the next checkpoint, with the ones a later change makes moot
//! dropped: a tile merged a hundred times between two checkpoints is written once.
//!
//! The invariant: applying [`Coalesced::ops`] leaves the store exactly as applying every op
//! pushed, in push order, would have. Each op that writes one key replaces the earlier op on
//! that key in place (the earlier one is dropped, the later one keeps its own position, so the
//! order between different keys is the order they were last written in); a job's
//! [`Op::DropSums`] drops the earlier ops on that job's sums, which it would delete anyway.
//! Ops on no single key (scenes, convictions, whole-job deletions) are kept as they came.
//! A checkpoint is therefore the state after some prefix of the coordinator's changes, which
//! is what a restart has always resumed from (docs/reliability.md).

use std::collections::HashMap;

use super::Op;

/// The key an op writes, where it writes exactly one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Key {
    Job(u64),
    Tile(u64, u32),
    Pending(u64, u32, u32),
    Unit(u64, u32, u32),
    Log(u64),
    Guide(u64, u32),
}

impl Key {
    fn of(op: &Op) -> Option<Self> {
        match op {
            Op::PutJob(r) => Some(Key::Job(r.id)),
            Op::DropJob(j) => Some(Key::Job(*j)),
            Op::PutTile(j, t, _) | Op::DelTile(j, t) => Some(Key::Tile(*j, *t)),
            Op::PutPending(j, t, b, _) | Op::DelPending(j, t, b) => Some(Key::Pending(*j, *t, *b)),
            Op::PutUnit(j, t, b, _, _) => Some(Key::Unit(*j, *t, *b)),
            Op::PutLog(j, _) | Op::DropLog(j) => Some(Key::Log(*j)),
            Op::PutGuide(j, e, _) => Some(Key::Guide(*j, *e)),
            Op::PutScene(..) | Op::PutAudit(_) | Op::DropSums(_) | Op::DropScene(_) => None,
        }
    }

    fn job_sums(&self) -> Option<u64> {
        match self {
            Key::Tile(j, _) | Key::Pending(j, _, _) | Key::Unit(j, _, _) | Key::Guide(j, _) => {
                Some(*j)
            }
            Key::Job(_) | Key::Log(_) => None,
        }
    }
}

/// Store changes queued for one transaction, coalesced by key.
#[derive(Debug, Default)]
pub struct Coalesced {
    /// In push order; `None` where a later op made one moot.
    slots: Vec<Option<Op>>,
    /// The slot of the live op on each key.
    at: HashMap<Key, usize>,
    /// Payload bytes of the live ops ([`Op::payload_len`]).
    bytes: u64,
    /// Ops pushed since the last [`take`](Self::take), moot ones included.
    pushed: u64,
}

impl Coalesced {
    /// Queues `op` after every op already queued.
    pub fn push(&mut self, op: Op) {
        self.pushed += 1;
        if let Op::DropSums(job) = op {
            let moot: Vec<Key> = self
                .at
                .keys()
                .filter(|k| k.job_sums() == Some(job))
                .copied()
                .collect();
            for k in moot {
                self.drop_key(k);
            }
        }
        let key = Key::of(&op);
        if let Some(k) = key {
            self.drop_key(k);
            self.at.insert(k, self.slots.len());
        }
        self.bytes += op.payload_len();
        self.slots.push(Some(op));
    }

    fn drop_key(&mut self, k: Key) {
        if let Some(i) = self.at.remove(&k) {
            if let Some(old) = self.slots[i].take() {
                self.bytes -= old.payload_len();
            }
        }
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Payload bytes of the ops that will be written.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Ops pushed since the last take, including those a later one made moot.
    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    /// The live ops, in order, leaving the queue empty.
    pub fn take(&mut self) -> Vec<Op> {
        self.at.clear();
        self.bytes = 0;
        self.pushed = 0;
        std::mem::take(&mut self.slots)
            .into_iter()
            .flatten()
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{JobRecord, Store};

    fn record(id: u64, spp: u32) -> JobRecord {
        JobRecord {
            id,
            spp,
            ..JobRecord::default()
        }
    }

    /// A job as stored: id, spp, tiles and early results.
    type Stored = (u64, u32, Vec<(u32, Vec<u8>)>, Vec<((u32, u32), Vec<u8>)>);

    /// What the store holds after `ops`: every job with its tiles and early results.
    fn state(ops: Vec<Op>) -> Vec<Stored> {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path()).expect("open");
        for op in ops {
            store.apply(&[op]).expect("apply");
        }
        store
            .load()
            .expect("load")
            .into_iter()
            .map(|j| (j.record.id, j.record.spp, j.tiles, j.pending))
            .collect()
    }

    fn ops() -> Vec<Op> {
        vec![
            Op::PutJob(record(1, 4)),
            Op::PutTile(1, 0, vec![1]),
            Op::PutPending(1, 1, 2, vec![2]),
            Op::PutTile(1, 0, vec![3]),
            Op::PutJob(record(2, 8)),
            Op::PutTile(2, 5, vec![4]),
            Op::DelPending(1, 1, 2),
            Op::PutTile(1, 1, vec![5]),
            Op::PutPending(1, 1, 4, vec![6]),
            Op::PutJob(record(1, 16)),
            Op::DropSums(2),
            Op::PutTile(1, 0, vec![7]),
            Op::DelTile(1, 1),
            Op::PutTile(1, 1, vec![8]),
        ]
    }

    #[test]
    fn coalesced_ops_leave_the_store_as_every_op_would() {
        let all = ops();
        let n = all.len();
        // Every prefix: a checkpoint can fall anywhere.
        for cut in 0..=n {
            let mut q = Coalesced::default();
            for op in ops().into_iter().take(cut) {
                q.push(op);
            }
            assert_eq!(q.pushed(), cut as u64);
            let live = q.take();
            assert!(live.len() <= cut);
            assert!(q.is_empty() && q.bytes() == 0);
            assert_eq!(
                state(live),
                state(ops().into_iter().take(cut).collect()),
                "after {cut} ops"
            );
        }
    }

    #[test]
    fn only_the_last_write_of_a_tile_is_kept() {
        let mut q = Coalesced::default();
        for v in 0..100u8 {
            q.push(Op::PutTile(1, 0, vec![v; 10]));
        }
        q.push(Op::PutPending(1, 0, 9, vec![0; 5]));
        q.push(Op::DelPending(1, 0, 9));
        assert_eq!(q.bytes(), 10);
        let live = q.take();
        assert_eq!(live.len(), 2, "{live:?}");
        assert!(matches!(&live[0], Op::PutTile(1, 0, b) if b[0] == 99));
        assert!(matches!(live[1], Op::DelPending(1, 0, 9)));
    }
}
