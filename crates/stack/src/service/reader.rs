//! The services that read every channel on their own clock: the recorder, the
//! Foxglove viewer, the Zenoh bridge. Polled subscribers never wake them, so
//! publishers never wait for them; each wakes every period, takes what
//! arrived, and reports what it lost.

use std::time::Duration;

use jetbench_bus::Wake;
use jetbench_msgs::ServiceId;

use super::{Context, Schedule, Service, ServiceError, Setup};
use crate::clock::PERIOD;

/// A reader of every channel; [`Reader`] runs it as a service.
pub trait ChannelReader: Sized {
    /// Which service it is.
    const ID: ServiceId;
    /// How often it takes what arrived.
    const PERIOD: Duration = PERIOD;

    /// Subscribes to every channel and opens what it writes or serves.
    fn open(setup: &Setup<'_>) -> Result<Self, ServiceError>;

    /// Takes everything published since the last call and passes it on.
    fn pump(&mut self) -> Result<(), ServiceError>;

    /// Samples lost on the bus before it took them (`seq` gaps), every channel.
    fn gaps(&self) -> u64;

    /// At the end, after a last [`ChannelReader::pump`]: release, report.
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
        self.0.pump()?;
        ctx.health().set_input_gaps(self.0.gaps());
        ctx.cycle(false)?;
        Ok(())
    }

    fn stop(&mut self, _inputs: &(), _ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        // What arrived while the set was stopping.
        self.0.pump()?;
        self.0.finish()
    }
}
