//! Integrating systems (force → position) with dry friction: the
//! generator's `integrator` family, diagnosed from its increments.
use gb_diagnose::generator::{draw_with, Knobs};
use gb_diagnose::{diagnose, DiagnoseData, DiagnoseOptions, OrderChoice};

/// The diagnosis of generated case `integrator`/`seed` at 8000 + 4000
/// samples: (named causes, final validation NRMSE over the noise floor,
/// the final model in words, the baseline's structure line).
fn diagnosed(seed: u64) -> (Vec<String>, f64, String, String) {
    let c = draw_with("integrator", seed, &Knobs::lengths(8000, 4000)).unwrap();
    let d = DiagnoseData::with_validation(c.train.clone(), c.validate.clone()).unwrap();
    let o = DiagnoseOptions {
        order: OrderChoice::Fixed(c.model_order),
        ..DiagnoseOptions::default()
    };
    let r = diagnose(&d, &o, None).unwrap().report;
    let causes = r.cause_names().iter().map(|c| c.to_string()).collect();
    let ratio = r.final_model.nrmse / c.noise_floor_nrmse;
    (causes, ratio, r.final_model.model.clone(), r.to_text())
}

/// Seed 8: a free mass with viscous and Coulomb friction (Fc = 0.44 F_rms)
/// driven by a sweep, its position measured at 31 dB. The ARX pole lies
/// beyond 1 (1.0005), but with dry friction neither linear model fits
/// (decision NRMSE 0.20 plain, 0.68 increments): while that comparison
/// decided, the plain model was kept, no cause was named, and it drifted
/// to 96× the noise floor on the validation record. Taken as an
/// integrator (policy `integrator_beyond_unit`), the increments get a
/// friction law and end within 1.3× the floor (1.09× while the law was
/// fitted over growing prefixes, 1.31× along one Levenberg–Marquardt path
/// from the increments' template, 1.13× since the velocity template starts
/// from the running sums' fit).
#[test]
fn an_integrator_with_dry_friction_is_modelled_from_its_increments() {
    let (causes, ratio, model, text) = diagnosed(8);
    assert!(
        causes == ["nonlinearity"] && ratio <= 1.3 && model.starts_with("integrating"),
        "named {causes:?}, final/floor {ratio:.2}, final {model}\n{text}"
    );
}

/// Seeds 3 and 9: dry friction under a repeated multisine (seed 3, 31 dB)
/// and under filtered noise (seed 9, a sharp law: ε = 0.022 v_rms, 37 dB).
/// The law fitted for the increments' error ended at 1.78× and 2.90× the
/// floor on the validation record; the same law refitted for the error of
/// their running sum (the position; proposed beside it on an integrating
/// plan, its velocity template started from the running sums) is chosen
/// and ends at 1.07× and 1.30×.
#[test]
fn a_dry_friction_law_is_fitted_for_the_integrated_position() {
    for (seed, bound) in [(3, 1.3), (9, 1.5)] {
        let (causes, ratio, model, text) = diagnosed(seed);
        assert!(
            causes == ["nonlinearity"] && ratio <= bound && model.starts_with("integrating"),
            "seed {seed}: named {causes:?}, final/floor {ratio:.2}, final {model}\n{text}"
        );
    }
}

/// Seeds 1 and 5: a free mass with viscous friction only (no dry
/// friction: no cause), driven by a sweep (seed 1, 44 dB) and by a PRBS
/// with slow components (seed 5, 35 dB). Its increments model trained for
/// the increments' error stayed at 1.93× and 2.83× the floor on the
/// validation record, and seed 1 took a dead time of 2 samples; trained
/// for the error of the summed increments (the position; policy
/// `integrated_criterion`) the linear baseline reaches 1.08× and 1.10×,
/// and nothing is named.
#[test]
fn a_linear_integrator_is_fitted_to_its_position_noise_floor() {
    for seed in [1, 5] {
        let (causes, ratio, model, text) = diagnosed(seed);
        assert!(
            causes.is_empty() && ratio <= 1.3 && model.starts_with("integrating"),
            "seed {seed}: named {causes:?}, final/floor {ratio:.2}, final {model}\n{text}"
        );
    }
}
