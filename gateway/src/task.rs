//! Every task the gateway spawns, spawned in one place with a name: [`spawn`] on the runtime,
//! [`watch`] for a future handed to a task tracker.
//!
//! A build with the `stall-watch` feature times each poll of every such task: a poll longer than
//! [`STALL`] holds a worker of the runtime (a blocking call, a large render, a busy loop) and
//! delays every task behind it. It also times each wake-up until the poll it asked for: longer
//! than [`STALL`], the task waited for a worker (held by another task, or the process by the
//! machine). Each one is logged at WARN under `gateway::task` with the task's name, the place that
//! spawned it and the time, and counted per task; [`stalls`] is the table of them (the binary
//! prints it on stderr when it ends). Without the feature (the default) [`watch`] hands the
//! future back unchanged and nothing is timed.

use std::future::Future;

use tokio::task::JoinHandle;

/// A poll longer than this is a stall.
pub const STALL: std::time::Duration = std::time::Duration::from_millis(1);

/// Spawns `future` on the current runtime as the task `name` (see the module doc).
#[track_caller]
pub fn spawn<F>(name: &'static str, future: F) -> JoinHandle<F::Output>
where
    F: Future + Send + 'static,
    F::Output: Send + 'static,
{
    tokio::spawn(watch(name, future))
}

/// `future` as the task `name`, timed poll by poll under `stall-watch`.
#[cfg(not(feature = "stall-watch"))]
#[track_caller]
pub fn watch<F: Future>(_name: &'static str, future: F) -> F {
    future
}

/// `future` as the task `name`, timed poll by poll under `stall-watch`.
#[cfg(feature = "stall-watch")]
#[track_caller]
pub fn watch<F: Future>(name: &'static str, future: F) -> watched::Watched<F> {
    watched::Watched {
        name,
        site: std::panic::Location::caller(),
        future: Box::pin(future),
        stamp: None,
    }
}

/// The stalls seen so far: a line with their number, then one per task and spawn site with the
/// most first (count, longest and total time). Empty without `stall-watch`.
pub fn stalls() -> String {
    #[cfg(feature = "stall-watch")]
    return watched::table();
    #[cfg(not(feature = "stall-watch"))]
    String::new()
}

#[cfg(feature = "stall-watch")]
mod watched {
    use std::collections::BTreeMap;
    use std::fmt::Write as _;
    use std::future::Future;
    use std::panic::Location;
    use std::pin::Pin;
    use std::sync::{Arc, Mutex, PoisonError};
    use std::task::{Context, Poll, Wake, Waker};
    use std::time::{Duration, Instant};

    const POLLS: &str = "polls > 1 ms";
    const LATE: &str = "wake-ups polled > 1 ms late";

    /// A future whose polls are timed, and the time from each wake-up to the poll it asked for.
    pub struct Watched<F> {
        pub(super) name: &'static str,
        pub(super) site: &'static Location<'static>,
        pub(super) future: Pin<Box<F>>,
        /// The waker the last poll handed on, with the moment it was first woken.
        pub(super) stamp: Option<Arc<Stamp>>,
    }

    /// The runtime's waker, noting when it is first woken.
    pub(super) struct Stamp {
        waker: Waker,
        woken: Mutex<Option<Instant>>,
    }

    impl Wake for Stamp {
        fn wake(self: Arc<Self>) {
            self.wake_by_ref();
        }

        fn wake_by_ref(self: &Arc<Self>) {
            lock(&self.woken).get_or_insert_with(Instant::now);
            self.waker.wake_by_ref();
        }
    }

    impl<F: Future> Future for Watched<F> {
        type Output = F::Output;

        fn poll(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<F::Output> {
            let start = Instant::now();
            let woken = self.stamp.take().and_then(|s| *lock(&s.woken));
            if let Some(late) = woken.map(|at| start.saturating_duration_since(at)) {
                if late > super::STALL {
                    record(self.name, self.site, LATE, late);
                }
            }
            let stamp = Arc::new(Stamp {
                waker: cx.waker().clone(),
                woken: Mutex::new(None),
            });
            let waker = Waker::from(Arc::clone(&stamp));
            self.stamp = Some(stamp);
            let poll = self.future.as_mut().poll(&mut Context::from_waker(&waker));
            let took = start.elapsed();
            if took > super::STALL {
                record(self.name, self.site, POLLS, took);
            }
            poll
        }
    }

    fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
        m.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Per task, spawn site and kind: count, longest, total.
    type Table = BTreeMap<(&'static str, String, &'static str), (u64, Duration, Duration)>;

    static STALLS: Mutex<Table> = Mutex::new(BTreeMap::new());

    fn record(
        task: &'static str,
        site: &'static Location<'static>,
        what: &'static str,
        took: Duration,
    ) {
        let ms = took.as_secs_f64() * 1e3;
        if what == POLLS {
            tracing::warn!(task, %site, poll_ms = ms, "stall: a poll held a worker");
        } else {
            tracing::warn!(task, %site, late_ms = ms, "stall: a woken task waited for a worker");
        }
        let mut stalls = lock(&STALLS);
        let entry = stalls.entry((task, site.to_string(), what)).or_default();
        entry.0 += 1;
        entry.1 = entry.1.max(took);
        entry.2 += took;
    }

    pub(super) fn table() -> String {
        let stalls = lock(&STALLS);
        let mut rows: Vec<_> = stalls.iter().collect();
        rows.sort_by_key(|(_, (count, ..))| std::cmp::Reverse(*count));
        let all = |kind: &str| -> u64 {
            rows.iter()
                .filter(|((.., what), _)| *what == kind)
                .map(|(_, (count, ..))| count)
                .sum()
        };
        let mut out = format!(
            "stall-watch: {} {POLLS}, {} {LATE}\n",
            all(POLLS),
            all(LATE)
        );
        for ((task, site, what), (count, longest, total)) in &rows {
            let _ = writeln!(
                out,
                "stall: task {task} spawned at {site}: {count} {what}, longest {:.3} ms, \
                 total {:.3} ms",
                longest.as_secs_f64() * 1e3,
                total.as_secs_f64() * 1e3,
            );
        }
        out
    }
}

#[cfg(all(test, feature = "stall-watch"))]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_poll_that_blocks_five_milliseconds_is_reported_with_its_task_and_call_site() {
        let line = line!() + 1;
        spawn("blocks-5ms", async {
            std::thread::sleep(std::time::Duration::from_millis(5));
        })
        .await
        .expect("the task ends");
        let table = stalls();
        let row = table
            .lines()
            .find(|l| l.contains("task blocks-5ms"))
            .unwrap_or_else(|| panic!("no stall of the task in {table:?}"));
        assert!(
            row.contains(&format!("spawned at {}:{line}:", file!())),
            "{row}"
        );
        assert!(row.contains(": 1 polls > 1 ms, longest "), "{row}");
    }

    #[tokio::test]
    async fn a_task_woken_while_the_worker_is_held_is_reported_late() {
        let notify = std::sync::Arc::new(tokio::sync::Notify::new());
        let waiter = spawn("woken-late", {
            let notify = notify.clone();
            async move { notify.notified().await }
        });
        tokio::task::yield_now().await;
        spawn("wakes-then-blocks", async move {
            notify.notify_one();
            std::thread::sleep(std::time::Duration::from_millis(5));
        })
        .await
        .expect("the task ends");
        waiter.await.expect("the task ends");
        let table = stalls();
        assert!(
            table
                .lines()
                .any(|l| l.contains("task woken-late")
                    && l.contains(": 1 wake-ups polled > 1 ms late")),
            "{table}"
        );
    }

    #[tokio::test]
    async fn a_task_that_waits_without_blocking_is_no_stall() {
        spawn(
            "sleeps",
            tokio::time::sleep(std::time::Duration::from_millis(5)),
        )
        .await
        .expect("the task ends");
        assert!(!stalls().contains("task sleeps"), "{}", stalls());
    }
}
