//! The timer on the real clock (it fires, never early, re-arms, cancels, drops cleanly) and on
//! tokio's paused clock. No test bounds how late it wakes: that depends on the machine's load
//! and is measured by the benchmark (the master's gap and the paced link's lateness).

use std::time::Duration;

use futures::FutureExt;
use tokio::time::Instant;

use super::*;

impl LineTimer {
    /// A timer that always uses tokio's sleep (the fallback of other systems).
    fn coarse() -> Self {
        Self {
            #[cfg(target_os = "linux")]
            fd: None,
        }
    }

    /// Whether the timer wakes finer than tokio's millisecond ticks (a timerfd).
    fn is_precise(&self) -> bool {
        #[cfg(target_os = "linux")]
        {
            self.fd.is_some()
        }
        #[cfg(not(target_os = "linux"))]
        {
            false
        }
    }
}

/// Short deadlines, a fraction of a millisecond to a few milliseconds ahead.
const AHEAD: [Duration; 5] = [
    Duration::from_micros(100),
    Duration::from_micros(350),
    Duration::from_micros(1_750),
    Duration::from_millis(3),
    Duration::ZERO,
];

#[tokio::test]
async fn it_fires_and_is_never_early() {
    let mut timer = LineTimer::new();
    #[cfg(target_os = "linux")]
    assert!(timer.is_precise(), "a timerfd inside a tokio runtime");
    for ahead in AHEAD.into_iter().cycle().take(20) {
        let deadline = Instant::now() + ahead;
        timer.sleep_until(deadline).await;
        assert!(Instant::now() >= deadline, "woke before {ahead:?}");
    }
    let start = Instant::now();
    timer.sleep(Duration::from_micros(500)).await;
    assert!(start.elapsed() >= Duration::from_micros(500));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn several_timers_fire_on_a_multi_thread_runtime() {
    let tasks: Vec<_> = (0..4u64)
        .map(|k| {
            tokio::spawn(async move {
                let mut timer = LineTimer::new();
                for _ in 0..10 {
                    let deadline = Instant::now() + Duration::from_micros(200 + 150 * k);
                    timer.sleep_until(deadline).await;
                    assert!(Instant::now() >= deadline);
                }
            })
        })
        .collect();
    for task in tasks {
        task.await.expect("timer task");
    }
}

#[tokio::test]
async fn a_passed_deadline_returns_at_once() {
    let mut timer = LineTimer::new();
    let past = Instant::now();
    tokio::time::sleep(Duration::from_micros(200)).await;
    assert_eq!(timer.sleep_until(past).now_or_never(), Some(()));
    assert_eq!(timer.sleep(Duration::ZERO).now_or_never(), Some(()));
}

#[tokio::test]
async fn it_can_be_re_armed_earlier_and_later() {
    let mut timer = LineTimer::new();
    // Armed an hour ahead, abandoned, re-armed 2 ms ahead: the new deadline counts.
    let far = Instant::now() + Duration::from_secs(3600);
    let abandoned = tokio::time::timeout(Duration::from_millis(2), timer.sleep_until(far)).await;
    assert!(abandoned.is_err());
    let near = Instant::now() + Duration::from_millis(2);
    timer.sleep_until(near).await;
    assert!(Instant::now() >= near);

    // Armed 300 us ahead and abandoned before it fired, re-armed 5 ms ahead: the stale expiry
    // (which comes while waiting for the later one) does not end the wait early.
    let first = Instant::now() + Duration::from_micros(300);
    assert_eq!(timer.sleep_until(first).now_or_never(), None);
    let later = Instant::now() + Duration::from_millis(5);
    timer.sleep_until(later).await;
    assert!(Instant::now() >= later);

    // Re-armed for the deadline it already waits for: no change.
    let same = Instant::now() + Duration::from_millis(1);
    assert_eq!(timer.sleep_until(same).now_or_never(), None);
    timer.sleep_until(same).await;
    assert!(Instant::now() >= same);
}

#[tokio::test]
async fn a_sleep_in_select_loses_to_an_earlier_branch_and_fires_next_time() {
    let mut timer = LineTimer::new();
    // Far beyond the two short sleeps that must win first, even on a loaded machine (with 3 ms a
    // busy runtime let the deadline pass during the second sleep).
    let deadline = Instant::now() + Duration::from_millis(200);
    let mut turns = 0;
    loop {
        turns += 1;
        tokio::select! {
            biased;
            () = tokio::time::sleep(Duration::from_micros(500)), if turns < 3 => {}
            () = timer.sleep_until_opt(Some(deadline)) => break,
        }
    }
    assert!(Instant::now() >= deadline);
    assert!(turns >= 3, "{turns}");
    // No deadline: never.
    let never = tokio::time::timeout(Duration::from_millis(2), timer.sleep_until_opt(None)).await;
    assert!(never.is_err());
}

#[cfg(target_os = "linux")]
#[tokio::test]
async fn cancel_disarms_the_timerfd() {
    let mut timer = LineTimer::new();
    let fd = |timer: &LineTimer| timer.fd.as_ref().expect("a timerfd").has_fired();

    // Armed 1 ms ahead and abandoned: the timerfd expires on its own (the control).
    assert_eq!(
        timer
            .sleep_until(Instant::now() + Duration::from_millis(1))
            .now_or_never(),
        None
    );
    std::thread::sleep(Duration::from_millis(3));
    assert!(fd(&timer).expect("read"));

    // Armed 1 ms ahead, abandoned and cancelled: it never expires.
    assert_eq!(
        timer
            .sleep_until(Instant::now() + Duration::from_millis(1))
            .now_or_never(),
        None
    );
    timer.cancel();
    std::thread::sleep(Duration::from_millis(3));
    assert!(!fd(&timer).expect("read"));

    // And it still works afterwards.
    let deadline = Instant::now() + Duration::from_micros(500);
    timer.sleep_until(deadline).await;
    assert!(Instant::now() >= deadline);
    assert!(timer.is_precise());
}

#[test]
fn dropping_it_is_clean_inside_and_after_the_runtime() {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let (armed, idle) = runtime.block_on(async {
        // Dropped while a sleep is armed and pending.
        let mut timer = LineTimer::new();
        let abandoned = tokio::time::timeout(
            Duration::from_millis(1),
            timer.sleep(Duration::from_secs(60)),
        )
        .await;
        assert!(abandoned.is_err());
        drop(timer);
        // Others keep working.
        let mut other = LineTimer::new();
        let deadline = Instant::now() + Duration::from_micros(300);
        other.sleep_until(deadline).await;
        assert!(Instant::now() >= deadline);
        // Two more, one armed, outliving the runtime.
        let mut armed = LineTimer::new();
        assert_eq!(armed.sleep(Duration::from_secs(60)).now_or_never(), None);
        (armed, LineTimer::new())
    });
    drop(runtime);
    drop(armed);
    drop(idle);
}

#[test]
fn outside_a_runtime_it_falls_back_to_tokio_sleep() {
    let timer = LineTimer::new();
    assert!(!timer.is_precise());
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let mut timer = timer;
    runtime.block_on(async {
        let deadline = Instant::now() + Duration::from_millis(2);
        timer.sleep_until(deadline).await;
        assert!(Instant::now() >= deadline);
        let mut coarse = LineTimer::coarse();
        assert!(!coarse.is_precise());
        let deadline = Instant::now() + Duration::from_millis(1);
        coarse.sleep_until(deadline).await;
        assert!(Instant::now() >= deadline);
        coarse.cancel();
    });
}

#[tokio::test(start_paused = true)]
async fn on_the_paused_clock_it_is_tokio_sleep() {
    let mut timer = LineTimer::new();
    let t0 = Instant::now();
    for ms in [1u64, 4, 10, 250] {
        let deadline = t0 + Duration::from_millis(ms);
        timer.sleep_until(deadline).await;
        // Virtual time moves to the deadline's tick, as for `tokio::time::sleep_until`.
        let now = Instant::now();
        assert!(now >= deadline && now <= deadline + Duration::from_millis(1));
    }
    // An hour of virtual time passes at once.
    let before = Instant::now();
    timer.sleep(Duration::from_secs(3600)).await;
    let slept = before.elapsed();
    assert!(slept >= Duration::from_secs(3600) && slept <= Duration::from_millis(3_600_001));
}

#[cfg(target_os = "linux")]
#[tokio::test(start_paused = true)]
async fn a_paused_clock_switches_it_to_tokio_sleep() {
    let mut timer = LineTimer::new();
    assert!(timer.is_precise());
    let deadline = Instant::now() + Duration::from_millis(1);
    // Armed 1 ms ahead on the real clock, which then passes while tokio's stands still.
    assert_eq!(timer.sleep_until(deadline).now_or_never(), None);
    std::thread::sleep(Duration::from_millis(3));
    timer.sleep_until(deadline).await;
    let now = Instant::now();
    assert!(now >= deadline && now <= deadline + Duration::from_millis(1));
    assert!(
        !timer.is_precise(),
        "the expiry tokio's clock did not follow"
    );
    // From now on tokio's sleep: a thousand short sleeps pass in virtual time.
    for _ in 0..1000 {
        let deadline = Instant::now() + Duration::from_micros(95);
        timer.sleep_until(deadline).await;
        assert!(Instant::now() >= deadline);
    }
}
