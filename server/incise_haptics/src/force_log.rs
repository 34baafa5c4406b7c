//! Every force the haptic loop sends, handed to a recorder without a lock or an allocation: a
//! single-producer, single-consumer ring of fixed-size records in atomics. The haptic thread
//! never waits on it: when the ring is full the force is dropped from the log (counted), never
//! from the device.

use incise_protocol::raw::RawToolForce;
use std::sync::atomic::{AtomicU64, Ordering};

/// Words per record: tool id and flags, pose sequence, timestamp, force (3), torque (3),
/// gripper force, the snapshot's frame.
const WORDS: usize = 12;

/// A force the loop sent, and the physics frame whose snapshot it was rendered from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SentForce {
    /// The force as sent.
    pub force: RawToolForce,
    /// The frame of the snapshot it extrapolated (0: none yet, the force is zero).
    pub snapshot_frame: u64,
}

/// The ring.
#[derive(Debug)]
pub struct ForceLog {
    slots: Box<[[AtomicU64; WORDS]]>,
    /// Records written (by the haptic thread only).
    head: AtomicU64,
    /// Records read (by the recorder only).
    tail: AtomicU64,
    dropped: AtomicU64,
}

impl ForceLog {
    /// A ring holding `capacity` records (at least 1).
    #[must_use]
    pub fn new(capacity: usize) -> Self {
        Self {
            slots: (0..capacity.max(1))
                .map(|_| std::array::from_fn(|_| AtomicU64::new(0)))
                .collect(),
            head: AtomicU64::new(0),
            tail: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
        }
    }

    /// Appends a record (the haptic thread); drops and counts it when the ring is full.
    pub fn push(&self, sent: &SentForce) {
        let head = self.head.load(Ordering::Relaxed);
        let capacity = self.slots.len() as u64;
        if head - self.tail.load(Ordering::Acquire) >= capacity {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        let f = &sent.force;
        let words: [u64; WORDS] = [
            u64::from(f.tool_id) | (u64::from(f.flags) << 32),
            f.pose_sequence,
            f.timestamp_ns,
            f.force[0].to_bits(),
            f.force[1].to_bits(),
            f.force[2].to_bits(),
            f.torque[0].to_bits(),
            f.torque[1].to_bits(),
            f.torque[2].to_bits(),
            f.gripper_force.to_bits(),
            sent.snapshot_frame,
            0,
        ];
        let slot = &self.slots[(head % capacity) as usize];
        for (cell, w) in slot.iter().zip(words) {
            cell.store(w, Ordering::Relaxed);
        }
        // Publishes the slot's words to the reader that sees the new head.
        self.head.store(head + 1, Ordering::Release);
    }

    /// Takes the oldest record (the recorder), if any.
    pub fn pop(&self) -> Option<SentForce> {
        let tail = self.tail.load(Ordering::Relaxed);
        if tail == self.head.load(Ordering::Acquire) {
            return None;
        }
        let slot = &self.slots[(tail % self.slots.len() as u64) as usize];
        let w: [u64; WORDS] = std::array::from_fn(|i| slot[i].load(Ordering::Relaxed));
        // Frees the slot for the writer only after its words were read.
        self.tail.store(tail + 1, Ordering::Release);
        let f = f64::from_bits;
        Some(SentForce {
            force: RawToolForce {
                tool_id: w[0] as u32,
                flags: (w[0] >> 32) as u32,
                pose_sequence: w[1],
                timestamp_ns: w[2],
                force: [f(w[3]), f(w[4]), f(w[5])],
                torque: [f(w[6]), f(w[7]), f(w[8])],
                gripper_force: f(w[9]),
            },
            snapshot_frame: w[10],
        })
    }

    /// Records dropped because the ring was full.
    #[must_use]
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sent(i: u64) -> SentForce {
        SentForce {
            force: RawToolForce {
                tool_id: (i % 3) as u32,
                flags: 5,
                pose_sequence: i,
                timestamp_ns: 1000 * i,
                force: [i as f64, -0.5, 1e-9],
                torque: [0.0, f64::MIN_POSITIVE, 3.0],
                gripper_force: 0.25,
            },
            snapshot_frame: i / 2,
        }
    }

    #[test]
    fn records_come_out_in_order_and_a_full_ring_drops_the_newest() {
        let log = ForceLog::new(4);
        for i in 0..6 {
            log.push(&sent(i));
        }
        assert_eq!(log.dropped(), 2);
        for i in 0..4 {
            assert_eq!(log.pop(), Some(sent(i)));
        }
        assert_eq!(log.pop(), None);
        log.push(&sent(9));
        assert_eq!(log.pop(), Some(sent(9)));
    }

    #[test]
    fn a_reader_on_another_thread_sees_every_record_whole() {
        let log = std::sync::Arc::new(ForceLog::new(64));
        let writer = {
            let log = std::sync::Arc::clone(&log);
            std::thread::spawn(move || {
                for i in 0..20_000 {
                    // A full ring drops; this writer waits instead, to check every record.
                    while log.head.load(Ordering::Relaxed) - log.tail.load(Ordering::Acquire) >= 64
                    {
                        std::thread::yield_now();
                    }
                    log.push(&sent(i));
                }
            })
        };
        let mut next = 0;
        while next < 20_000 {
            if let Some(s) = log.pop() {
                assert_eq!(s, sent(next));
                next += 1;
            } else {
                std::thread::yield_now();
            }
        }
        writer.join().unwrap();
        assert_eq!(log.dropped(), 0);
    }
}
