//! Merging the node's input streams (each radar, odometry) into one stream in stamp order, as the
//! offline runner reads a bag, so that the pipeline sees the same sequence whatever the order in which
//! DDS delivers the topics.
//!
//! Entry point: [`StampMerger`]. It releases the oldest item held when every other stream has passed
//! its stamp (by a message stamped there or later, or because the stream's recent stamp gaps,
//! [`GAP_MARGIN`] and [`GAPS_KEPT`], say its next message cannot be that early), when the item has
//! waited `timeout`, or when the other streams are idle; ties keep the arrival order. A stream that
//! has sent nothing yet counts as having sent when the first item of any stream came: while the
//! inputs start, its first message is waited for (at most `timeout` per item), so that the sensor
//! whose driver happens to be delivered first does not go ahead of an earlier-stamped one.
//! docs/algorithm.md, "Input order", has the rule in full and why the stamp gaps bound the wait.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use dc_loc_core::math::Stamp;

/// Stamp gaps remembered per stream.
pub const GAPS_KEPT: usize = 16;

/// Share of the shortest remembered gap that the next stamp is certainly later by.
pub const GAP_MARGIN: f64 = 0.9;

/// Gaps needed before a stream's next stamp is predicted.
const GAPS_NEEDED: usize = 4;

struct Stream<T> {
    /// Held items, sorted by (stamp, arrival number).
    queue: VecDeque<(Stamp, u64, Instant, T)>,
    newest: Option<Stamp>,
    last_arrival: Option<Instant>,
    /// The last stamp gaps (ns, positive), newest last.
    gaps: VecDeque<i64>,
}

impl<T> Stream<T> {
    /// True when no message of this stream can come stamped at or before `stamp`.
    fn passed(&self, stamp: Stamp) -> bool {
        let Some(newest) = self.newest else {
            return false;
        };
        if newest >= stamp {
            return true;
        }
        if self.gaps.len() < GAPS_NEEDED {
            return false;
        }
        let shortest = self.gaps.iter().copied().min().unwrap_or(0);
        newest.0 + (shortest as f64 * GAP_MARGIN) as i64 > stamp.0
    }

    fn note_stamp(&mut self, stamp: Stamp) {
        match self.newest {
            Some(n) if stamp > n => {
                if self.gaps.len() == GAPS_KEPT {
                    self.gaps.pop_front();
                }
                self.gaps.push_back(stamp.0 - n.0);
                self.newest = Some(stamp);
            }
            // Backwards (a bag restarted): the history no longer describes the stream.
            Some(n) if stamp < n => {
                self.gaps.clear();
            }
            Some(_) => {
                // A repeated stamp: no gap, and the next one may come at the usual rate.
            }
            None => self.newest = Some(stamp),
        }
    }
}

/// Holds items of several streams and releases them in stamp order (see the module documentation).
pub struct StampMerger<T> {
    streams: Vec<Stream<T>>,
    timeout: Duration,
    idle: Duration,
    seq: u64,
    held: usize,
    /// When the first item of any stream came.
    started: Option<Instant>,
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
                    gaps: VecDeque::with_capacity(GAPS_KEPT),
                })
                .collect(),
            timeout,
            idle,
            seq: 0,
            held: 0,
            started: None,
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
        s.note_stamp(stamp);
        s.last_arrival = Some(now);
        self.started.get_or_insert(now);
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
                || s.passed(*stamp)
                || s.last_arrival
                    .or(self.started)
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
            None,
            "the inputs start: odometry's first message is waited for"
        );
        m.push(1, Stamp(5), t0, "odom 5");
        assert_eq!(m.pop_ready(t0), Some("odom 5"));
        assert_eq!(
            m.pop_ready(t0),
            None,
            "radar 10 waits for odometry to pass 10"
        );
        m.push(1, Stamp(12), t0, "odom 12");
        assert_eq!(m.pop_ready(t0), Some("radar 10"));
        m.push(0, Stamp(20), t0, "radar 20");
        assert_eq!(m.pop_ready(t0), Some("odom 12"));
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

    /// A stream that never sends delays the first items by at most `timeout`, and none once the
    /// others have flowed for `idle` without it.
    #[test]
    fn a_silent_stream_is_waited_for_only_while_the_inputs_start() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut m = StampMerger::new(2, ms(200), ms(1000));
        m.push(0, Stamp(10), t0, "radar 10");
        assert_eq!(m.pop_ready(t0 + ms(100)), None);
        assert_eq!(m.pop_ready(t0 + ms(200)), Some("radar 10"), "timeout");
        m.push(0, Stamp(20), t0 + ms(1000), "radar 20");
        assert_eq!(m.pop_ready(t0 + ms(1000)), Some("radar 20"), "idle");
    }

    /// Two radars at 10 Hz, half a period apart: once their rates are known, an item goes as soon as the
    /// other radar's next message cannot be stamped before it, and waits while that message is due.
    #[test]
    fn a_periodic_stream_is_passed_before_its_next_message() {
        let ms = |v: i64| Stamp(v * 1_000_000);
        let t0 = Instant::now();
        let mut m = StampMerger::new(2, Duration::from_secs(5), Duration::from_secs(5));
        // Warm-up: both streams in step. Once four gaps are known each, b at 550 goes before a's next
        // message: that cannot be stamped before 500 + 90.
        for k in 0..6 {
            m.push(0, ms(100 * k), t0, ("a", 100 * k));
            m.push(1, ms(100 * k + 50), t0, ("b", 100 * k + 50));
        }
        let mut out = Vec::new();
        while let Some(x) = m.pop_ready(t0) {
            out.push(x.1);
        }
        assert_eq!(
            out,
            vec![0, 50, 100, 150, 200, 250, 300, 350, 400, 450, 500, 550]
        );
        // a at 600 goes at once: b's next cannot be stamped before 550 + 90.
        m.push(0, ms(600), t0, ("a", 600));
        assert_eq!(m.pop_ready(t0), Some(("a", 600)));
        // a at 700 while b's 650 has not come: b's next may be stamped at 640, so a waits.
        m.push(0, ms(700), t0, ("a", 700));
        assert_eq!(m.pop_ready(t0), None);
        m.push(1, ms(650), t0, ("b", 650));
        assert_eq!(m.pop_ready(t0), Some(("b", 650)));
        assert_eq!(m.pop_ready(t0), Some(("a", 700)));
        // A short gap (an irregular stream) shrinks the bound: b at 660 makes 10 ms the shortest gap,
        // so a at 800 waits for b to reach it.
        m.push(1, ms(660), t0, ("b", 660));
        m.push(0, ms(800), t0, ("a", 800));
        assert_eq!(m.pop_ready(t0), Some(("b", 660)));
        assert_eq!(m.pop_ready(t0), None);
        // Stamps going backwards forget the rate.
        m.push(1, ms(100), t0, ("b", 100));
        assert_eq!(m.pop_ready(t0), Some(("b", 100)));
        assert!(m.streams[1].gaps.is_empty());
    }
}
