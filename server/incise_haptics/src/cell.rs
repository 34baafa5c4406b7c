//! Seqlock cells: one writer publishes a fixed-size record that readers copy out whole, with no
//! lock and no allocation on either side (what the haptic thread may use). The record is stored
//! as `N` 64-bit words in atomics, so the cell needs no `unsafe`: a reader that raced a write sees
//! the sequence number move and copies again.
//!
//! A writer never waits; a reader retries only while a write is under way (a few hundred
//! nanoseconds for the largest record here), so neither side can block the other.

use std::sync::atomic::{AtomicU64, Ordering, fence};

/// A record of `N` words with one writer and any number of readers.
#[derive(Debug)]
pub struct SeqCell<const N: usize> {
    /// Even: stable; odd: a write is under way. Starts at 0 (never written).
    seq: AtomicU64,
    words: [AtomicU64; N],
}

impl<const N: usize> Default for SeqCell<N> {
    fn default() -> Self {
        Self { seq: AtomicU64::new(0), words: std::array::from_fn(|_| AtomicU64::new(0)) }
    }
}

impl<const N: usize> SeqCell<N> {
    /// Publishes `words`. Only one thread may write a cell (the one that owns it).
    pub fn write(&self, words: &[u64; N]) {
        let s = self.seq.load(Ordering::Relaxed);
        self.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        for (w, &v) in self.words.iter().zip(words) {
            w.store(v, Ordering::Relaxed);
        }
        self.seq.store(s.wrapping_add(2), Ordering::Release);
    }

    /// The last record written and how many writes there have been (`None` before the first).
    pub fn read(&self) -> Option<([u64; N], u64)> {
        loop {
            let before = self.seq.load(Ordering::Acquire);
            if before == 0 {
                return None;
            }
            if before & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let words = std::array::from_fn(|k| self.words[k].load(Ordering::Relaxed));
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == before {
                return Some((words, before / 2));
            }
        }
    }

    /// How many writes there have been, without copying the record.
    pub fn version(&self) -> u64 {
        self.seq.load(Ordering::Acquire) / 2
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn a_reader_never_sees_a_torn_record() {
        // The writer stores records whose words are all equal; a torn read would mix two.
        let cell = Arc::new(SeqCell::<32>::default());
        assert!(cell.read().is_none());
        let writer = {
            let cell = Arc::clone(&cell);
            std::thread::spawn(move || {
                for i in 1..=200_000u64 {
                    cell.write(&[i; 32]);
                }
            })
        };
        let mut last = 0;
        let mut reads = 0;
        while !writer.is_finished() || reads == 0 {
            if let Some((words, version)) = cell.read() {
                assert!(words.iter().all(|&w| w == words[0]), "torn: {words:?}");
                assert!(words[0] >= last, "went back from {last} to {}", words[0]);
                assert_eq!(words[0], version, "the version counts the writes");
                last = words[0];
                reads += 1;
            }
        }
        writer.join().unwrap();
        assert_eq!(cell.read().unwrap().0[0], 200_000);
    }
}
