//! The wait loop of a consumer: it sleeps on its inputs' wake-ups with
//! per-input deadlines and an optional periodic tick, and never busy-polls.

use std::time::{Duration, Instant};

use crate::bell::Woke;
use crate::error::WaitError;
use crate::signal::{stop_requested, SIGNAL_POLL};
use crate::transport::{Waiting, Waker};

/// Why a wake-up happened in [`Bus::run`](crate::Bus::run).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wake {
    /// Input `i` (index into the inputs slice) has new samples.
    Input(usize),
    /// Input `i` sent nothing within its deadline.
    Missed(usize),
    /// The periodic tick.
    Tick,
}

/// What the [`Bus::run`](crate::Bus::run) callback wants next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// Wait for the next input or tick.
    Continue,
    /// Return from the loop: [`Bus::run`](crate::Bus::run) returns [`LoopExit::Stopped`].
    Stop,
}

/// Why [`Bus::run`](crate::Bus::run) returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoopExit {
    /// The callback asked to stop.
    Stopped,
    /// SIGINT or SIGTERM.
    Terminated,
}

/// Something [`Bus::run`](crate::Bus::run) can wait on.
pub trait Trigger {
    /// What wakes it; `None` for a polled subscriber.
    fn waker(&self) -> Option<Waker<'_>>;
    /// Its channel, for messages.
    fn channel_name(&self) -> &'static str;
}

/// See [`Bus::run`](crate::Bus::run).
pub(crate) fn run<F>(
    inputs: &[(&dyn Trigger, Option<Duration>)],
    tick: Option<Duration>,
    mut on_wake: F,
) -> Result<LoopExit, WaitError>
where
    F: FnMut(Wake) -> Flow,
{
    let wakers = inputs
        .iter()
        .map(|(trigger, _)| trigger.waker().ok_or(WaitError::Polled { channel: trigger.channel_name().into() }))
        .collect::<Result<Vec<Waker>, WaitError>>()?;
    let mut waiting = Waiting::new(&wakers)?;
    let start = Instant::now();
    let mut missed_at: Vec<Option<Instant>> = inputs.iter().map(|(_, d)| d.map(|d| start + d)).collect();
    let mut next_tick = tick.map(|t| start + t);
    loop {
        if stop_requested() {
            return Ok(LoopExit::Terminated);
        }
        // Bounds the time to notice a stop request, whatever the inputs do.
        let wake_at = missed_at.iter().flatten().chain(&next_tick).fold(Instant::now() + SIGNAL_POLL, |a, &b| a.min(b));
        // Interrupted: any signal (SIGCHLD included); the flag decides.
        if waiting.wait(wake_at)? == Woke::Interrupted {
            continue;
        }
        let now = Instant::now();
        for (i, waker) in wakers.iter().enumerate() {
            let deadline = inputs[i].1;
            let wake = if waker.take() {
                Wake::Input(i)
            } else if missed_at[i].is_some_and(|at| now >= at) {
                Wake::Missed(i)
            } else {
                continue;
            };
            missed_at[i] = deadline.map(|d| now + d);
            if on_wake(wake) == Flow::Stop {
                return Ok(LoopExit::Stopped);
            }
        }
        if let (Some(at), Some(period)) = (next_tick, tick) {
            if now >= at {
                let mut next = at + period;
                while next <= now {
                    next += period;
                }
                next_tick = Some(next);
                if on_wake(Wake::Tick) == Flow::Stop {
                    return Ok(LoopExit::Stopped);
                }
            }
        }
    }
}

/// Waits until `waker` wakes, `deadline` passes or a stop is requested (one
/// consumer blocking on one input).
pub(crate) fn wait_for(waker: Waker<'_>, deadline: Instant) -> Result<(), WaitError> {
    // Take first: a sample published from here on wakes the wait.
    if !waker.take() {
        // A signal cutting the wait short is fine: the stop flag decides what it meant.
        Waiting::new(&[waker])?.wait(deadline.min(Instant::now() + SIGNAL_POLL))?;
    }
    Ok(())
}
