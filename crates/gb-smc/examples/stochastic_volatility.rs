//! PMMH on a stochastic volatility model (run with `cargo run --release -p gb-smc --example stochastic_volatility`).
//!
//! x_t = μ + φ (x_{t-1} − μ) + σ v_t,  y_t = exp(x_t / 2) e_t; θ = (μ, φ, σ) unknown.
use gb_smc::estimation::{ParametricModel, Pmmh, PmmhConfig, PmmhState};
use gb_smc::models::StochasticVolatility;
use gb_smc::Observations;

/// Flat priors on μ ∈ (−5, 5), φ ∈ (−1, 1), σ ∈ (0, 2).
struct SvParams;

impl ParametricModel for SvParams {
    type Model = StochasticVolatility;
    fn dim(&self) -> usize {
        3
    }
    fn build(&self, th: &[f64]) -> Option<StochasticVolatility> {
        StochasticVolatility::new(th[0], th[1], th[2]).ok()
    }
    fn log_prior(&self, th: &[f64]) -> f64 {
        if th[0].abs() < 5.0 && th[1].abs() < 1.0 && th[2] > 0.0 && th[2] < 2.0 {
            0.0
        } else {
            f64::NEG_INFINITY
        }
    }
}

fn main() -> Result<(), gb_smc::SmcError> {
    let truth = [-1.0, 0.95, 0.3];
    let model = StochasticVolatility::new(truth[0], truth[1], truth[2])?;
    let (_, y) = model.simulate(300, 42);
    let mut cfg = PmmhConfig::new(300, 3000, vec![0.1, 0.02, 0.05]);
    cfg.burn_in = 1000;
    cfg.adapt_start = 500;
    cfg.seed = 1;
    let mut progress = |s: &PmmhState| {
        if s.iter % 500 == 0 {
            println!(
                "iter {:5}: θ = [{:.3}, {:.3}, {:.3}], log p̂ = {:.2}, acceptance {:.2}",
                s.iter,
                s.theta[0],
                s.theta[1],
                s.theta[2],
                s.log_likelihood,
                s.acceptance_rate()
            );
        }
    };
    let res = Pmmh::new(cfg)?.run_with(
        &SvParams,
        &Observations::new(&y),
        &[0.0, 0.8, 0.5],
        &gb_smc::estimation::Silent,
        &mut progress,
    )?;
    println!("acceptance rate {:.3}", res.acceptance_rate);
    for (name, (s, t)) in ["mu", "phi", "sigma"]
        .iter()
        .zip(res.summary.iter().zip(truth))
    {
        println!(
            "{name:>5}: mean {:.3} sd {:.3}  95% [{:.3}, {:.3}]  (truth {t})",
            s.mean, s.sd, s.q025, s.q975
        );
    }
    Ok(())
}
