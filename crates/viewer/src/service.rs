//! The viewer as a service of the set: started by `jetbench up --foxglove`,
//! run by the runtime's one runner (bus, ready, heartbeat), reading the bus on
//! its own clock.

use jetbench_bus::Wake;
use jetbench_msgs::ServiceId;
use jetbench_stack::service::{Context, Schedule, Service, ServiceError, Setup};

use crate::{FoxgloveServer, LiveView, ServerOptions, ViewerError, DEFAULT_ADDR, POLL_PERIOD};

impl From<ViewerError> for ServiceError {
    fn from(e: ViewerError) -> Self {
        ServiceError::Other(Box::new(e))
    }
}

/// The Foxglove live view, served on `--listen` (default [`DEFAULT_ADDR`]).
pub struct Viewer {
    view: LiveView,
}

impl Service for Viewer {
    const ID: ServiceId = ServiceId::Viewer;
    type Inputs = ();

    fn new(setup: &Setup<'_>) -> Result<(Self, ()), ServiceError> {
        let server = FoxgloveServer::start(setup.listen.unwrap_or(DEFAULT_ADDR), &ServerOptions::default())?;
        let view = LiveView::open(setup.bus, server)?;
        tracing::info!("Foxglove live view on {}", view.server().url());
        Ok((Viewer { view }, ()))
    }

    fn schedule(&self) -> Schedule {
        Schedule::Tick(POLL_PERIOD)
    }

    fn process(&mut self, _wake: Wake, _inputs: &(), ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        self.view.pump()?;
        ctx.health().set_input_gaps(self.view.gaps());
        ctx.cycle(false)?;
        Ok(())
    }

    fn stop(&mut self, _inputs: &(), _ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        self.view.pump()?;
        eprint!("{}", self.view.report());
        self.view.stop();
        Ok(())
    }
}
