//! The services that read every channel on their own clock: the recorder, the
//! Foxglove viewer, the Zenoh bridge. Polled subscribers never wake them, so
//! publishers never wait for them; each wakes every period, takes what
//! arrived, and reports what it lost. At the end each takes what still comes
//! until the bus is quiet: the last samples of services stopping with it (when
//! the launcher died, every service stops at once).

use std::time::{Duration, Instant};

use jetbench_bus::Wake;
use jetbench_msgs::ServiceId;

use super::{Context, Schedule, Service, ServiceError, Setup};
use crate::runtime::clock::PERIOD;

/// At the end, a reader takes what is still coming until the bus has been
/// quiet this long (the launcher stops readers last) ...
const QUIET: Duration = Duration::from_millis(50);
/// ... or this long when the launcher died and every service stops at once:
/// actuation's last sample comes after the board's disarm, which it retries
/// for up to 100 ms, on a machine busy with the whole set stopping ...
const QUIET_ORPHANED: Duration = Duration::from_millis(400);
/// ... but no longer than this.
const LAST_SAMPLES_WAIT: Duration = Duration::from_secs(2);

/// A reader of every channel; [`Reader`] runs it as a service.
pub trait ChannelReader: Sized {
    /// Which service it is.
    const ID: ServiceId;
    /// How often it takes what arrived.
    const PERIOD: Duration = PERIOD;

    /// Subscribes to every channel and opens what it writes or serves.
    fn open(setup: &Setup<'_>) -> Result<Self, ServiceError>;

    /// Takes everything published since the last call and passes it on;
    /// returns how many samples there were. A failure it can run on is
    /// counted on `ctx` ([`Context::reject`]) rather than returned.
    fn pump(&mut self, ctx: &mut Context<'_>) -> Result<usize, ServiceError>;

    /// Samples lost on the bus before it took them (`seq` gaps), every channel.
    fn gaps(&self) -> u64;

    /// At the end, once the bus is quiet: release, report.
    fn finish(&mut self) -> Result<(), ServiceError>;
}

/// A [`ChannelReader`] as a service: woken every [`ChannelReader::PERIOD`].
pub struct Reader<R>(R);

impl<R: ChannelReader> Service for Reader<R> {
    const ID: ServiceId = R::ID;
    type Inputs = ();

    fn new(setup: &Setup<'_>) -> Result<(Self, ()), ServiceError> {
        Ok((Reader(R::open(setup)?), ()))
    }

    fn schedule(&self) -> Schedule {
        Schedule::Tick(R::PERIOD)
    }

    fn process(&mut self, wake: Wake, _inputs: &(), ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        if wake != Wake::Tick {
            return Ok(());
        }
        self.0.pump(ctx)?;
        ctx.health().set_input_gaps(self.0.gaps());
        ctx.cycle(false)?;
        Ok(())
    }

    fn stop(&mut self, _inputs: &(), ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        let quiet = if super::launcher_gone() { QUIET_ORPHANED } else { QUIET };
        let start = Instant::now();
        let mut last_sample = start;
        while last_sample.elapsed() < quiet && start.elapsed() < LAST_SAMPLES_WAIT {
            if self.0.pump(ctx)? > 0 {
                last_sample = Instant::now();
            }
            std::thread::sleep(R::PERIOD);
        }
        self.0.finish()
    }
}
