//! Merging the node's input streams (each radar, odometry) into one stream in stamp order, as the
//! offline runner reads a bag, so that the pipeline sees the same sequence whatever the order in which
//! DDS delivers the topics.
//!
//! Entry point: [`StampMerger`]. An item is released when it is the oldest held and every other stream
//! has reached its stamp (a later message arrived there), or when it has waited `timeout` (wall time), or
//! when the other streams are idle (nothing for `idle`): a stalled or silent topic delays the others by
//! at most `timeout`. Ties keep the arrival order.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use crate::math::Stamp;

struct Stream<T> {
    /// Held items, sorted by (stamp, arrival number).
    queue: VecDeque<(Stamp, u64, Instant, T)>,
    newest: Option<Stamp>,
    last_arrival: Option<Instant>,
}

/// Holds items of several streams and releases them in stamp order (see the module documentation).
pub struct StampMerger<T> {
    streams: Vec<Stream<T>>,
    timeout: Duration,
    idle: Duration,
    seq: u64,
    held: usize,
}

impl<T> StampMerger<T> {
    /// A merger of `n` streams.
    pub fn new(n: usize, timeout: Duration, idle: Duration) -> Self {
        StampMerger {
            streams: (0..n)
                .map(|_| Stream {
                    queue: VecDeque::new(),
                    newest: None,
                    last_arrival: None,
                })
                .collect(),
            timeout,
            idle,
            seq: 0,
            held: 0,
        }
    }

    /// Items held now.
    pub fn len(&self) -> usize {
        self.held
    }

    /// True when nothing is held.
    pub fn is_empty(&self) -> bool {
        self.held == 0
    }

    /// Adds an item of stream `stream` (out of range: the last stream).
    pub fn push(&mut self, stream: usize, stamp: Stamp, now: Instant, item: T) {
        let last = self.streams.len() - 1;
        let s = &mut self.streams[stream.min(last)];
        let key = (stamp, self.seq);
        let at = s.queue.partition_point(|(st, q, _, _)| (*st, *q) <= key);
        s.queue.insert(at, (stamp, self.seq, now, item));
        s.newest = Some(s.newest.map_or(stamp, |n| n.max(stamp)));
        s.last_arrival = Some(now);
        self.seq += 1;
        self.held += 1;
    }

    /// The stream holding the oldest item.
    fn oldest(&self) -> Option<usize> {
        self.streams
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.queue.front().map(|(st, q, _, _)| ((*st, *q), i)))
            .min()
            .map(|(_, i)| i)
    }

    /// The oldest item if it may go now.
    pub fn pop_ready(&mut self, now: Instant) -> Option<T> {
        let i = self.oldest()?;
        let (stamp, _, arrived, _) = self.streams[i].queue.front()?;
        let waited = now.saturating_duration_since(*arrived) >= self.timeout;
        let others_past = self.streams.iter().enumerate().all(|(j, s)| {
            j == i
                || s.newest.is_some_and(|n| n >= *stamp)
                || s.last_arrival
                    .is_none_or(|a| now.saturating_duration_since(a) >= self.idle)
        });
        if waited || others_past {
            self.held -= 1;
            self.streams[i].queue.pop_front().map(|(_, _, _, t)| t)
        } else {
            None
        }
    }

    /// The oldest item, whatever the other streams (at shutdown).
    pub fn pop_any(&mut self) -> Option<T> {
        let i = self.oldest()?;
        self.held -= 1;
        self.streams[i].queue.pop_front().map(|(_, _, _, t)| t)
    }

    /// When the oldest item's wait runs out (`None` when nothing is held).
    pub fn deadline(&self) -> Option<Instant> {
        let i = self.oldest()?;
        self.streams[i]
            .queue
            .front()
            .map(|(_, _, a, _)| *a + self.timeout)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamp_order_whatever_the_arrival_order() {
        let t0 = Instant::now();
        let mut m = StampMerger::new(2, Duration::from_millis(200), Duration::from_secs(1));
        // Radar (stream 0) at 10 arrives before odometry (stream 1) at 5 and 12.
        m.push(0, Stamp(10), t0, "radar 10");
        assert_eq!(
            m.pop_ready(t0),
            Some("radar 10"),
            "odometry never seen: not waited for"
        );
        m.push(1, Stamp(5), t0, "odom 5");
        m.push(0, Stamp(20), t0, "radar 20");
        assert_eq!(m.pop_ready(t0), Some("odom 5"));
        assert_eq!(
            m.pop_ready(t0),
            None,
            "radar 20 waits for odometry to pass 20"
        );
        m.push(1, Stamp(15), t0, "odom 15");
        assert_eq!(m.pop_ready(t0), Some("odom 15"));
        assert_eq!(m.pop_ready(t0), None);
        m.push(1, Stamp(20), t0, "odom 20");
        assert_eq!(m.pop_ready(t0), Some("radar 20"), "ties in arrival order");
        assert_eq!(m.pop_ready(t0), Some("odom 20"));
        // Timeout and idle streams.
        m.push(1, Stamp(30), t0, "odom 30");
        assert_eq!(m.pop_ready(t0 + Duration::from_millis(100)), None);
        assert_eq!(m.deadline(), Some(t0 + Duration::from_millis(200)));
        assert_eq!(
            m.pop_ready(t0 + Duration::from_millis(250)),
            Some("odom 30")
        );
        let later = t0 + Duration::from_millis(1100);
        m.push(1, Stamp(40), later, "odom 40");
        assert_eq!(m.pop_ready(later), Some("odom 40"), "radar idle for 1.1 s");
        assert!(m.is_empty());
        m.push(0, Stamp(30), t0, "radar 30");
        m.push(0, Stamp(3), t0, "radar 3 (backwards)");
        assert_eq!(m.pop_any(), Some("radar 3 (backwards)"));
        assert_eq!(m.pop_any(), Some("radar 30"));
        assert_eq!(m.len(), 0);
    }
}
