//! The candidate extensions, one file each (see [`crate::Extension`]).
mod capacity;
mod hidden_state;
mod lolimot;
mod order;
mod preisach;
mod student_t;

pub use capacity::Capacity;
pub use hidden_state::HiddenState;
pub use lolimot::Lolimot;
pub use order::LinearOrder;
pub use preisach::PreisachColumns;
pub use student_t::StudentTNoise;

use crate::extension::{io_model, Context};
use crate::DiagnoseError;
use gb_core::FittedModel;
use gb_lmn::{IoNetworkParams, WarmStart};

/// Fit an input–output network on the fit block, warm-started from the
/// current model (its network for linear fits, its simulated output for
/// LOLIMOT's output-error construction).
pub(crate) fn fit_io(p: &IoNetworkParams, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
    let mut p = p.clone();
    p.fit = ctx.options.fit.clone();
    p.lolimot = ctx.options.lolimot.clone();
    let warm_net = crate::plan::core(&ctx.current.model)
        .as_any()
        .downcast_ref::<gb_lmn::LocalModelNetwork>();
    let net = p.check()?.fit(
        ctx.fit,
        WarmStart {
            simulated_output: ctx.simulated_fit,
            network: warm_net,
        },
    )?;
    io_model(net, ctx.fit)
}
