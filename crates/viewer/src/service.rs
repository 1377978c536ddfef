//! The viewer as a service of the set: started by `jetbench up --foxglove`,
//! run by the runtime's one runner as a reader of every channel.

use jetbench_msgs::ServiceId;
use jetbench_stack::runtime::{ChannelReader, Context, ServiceError, Setup};

use crate::{FoxgloveServer, LiveView, ServerOptions, ViewerError, DEFAULT_ADDR};

impl From<ViewerError> for ServiceError {
    fn from(e: ViewerError) -> Self {
        ServiceError::Other(Box::new(e))
    }
}

/// The Foxglove live view, served on `--listen` (default [`DEFAULT_ADDR`]).
pub struct Viewer {
    view: LiveView,
}

impl ChannelReader for Viewer {
    const ID: ServiceId = ServiceId::Viewer;

    fn open(setup: &Setup<'_>) -> Result<Self, ServiceError> {
        let listen = setup.listen.unwrap_or(DEFAULT_ADDR);
        let token = crate::operator::operator_token(setup.config.operator.as_ref(), crate::parse_listen(listen)?);
        let (gateway, services) =
            crate::operator::FoxgloveGateway::open(setup.bus, token).map_err(ViewerError::from)?;
        tracing::info!("Foxglove services: {}", gateway.offered().join(", "));
        let server = FoxgloveServer::start_with_services(listen, &ServerOptions::default(), services)?;
        let view = LiveView::with_gateway(setup.bus, server, gateway)?;
        tracing::info!("Foxglove live view on {}", view.server().url());
        Ok(Viewer { view })
    }

    fn pump(&mut self, _ctx: &mut Context<'_>) -> Result<usize, ServiceError> {
        Ok(self.view.pump()?)
    }

    fn gaps(&self) -> u64 {
        self.view.gaps()
    }

    fn finish(&mut self) -> Result<(), ServiceError> {
        eprint!("{}", self.view.report());
        self.view.stop();
        Ok(())
    }
}
