//! The block-oriented and polynomial nonlinearity extensions: a generated
//! Hammerstein system is diagnosed as `nonlinearity` and the final model
//! reaches the noise floor.
use gb_diagnose::generator::draw;
use gb_diagnose::sweep::{run_diagnosis, OrderMode};
use gb_diagnose::EXTENSIONS;

#[test]
fn the_nonlinearity_extensions_are_registered() {
    for name in ["hammerstein", "wiener", "poly-noe"] {
        assert!(EXTENSIONS.iter().any(|e| e.name() == name), "{name}");
    }
}

/// The generated case `family`/`seed` is diagnosed with the right causes
/// (and, with `nonlinearity`, names it) and ends within `max_ratio` of its
/// noise floor.
fn assert_right_within(family: &str, seed: u64, max_ratio: f64, names_nonlinearity: bool) {
    let c = draw(family, seed).unwrap();
    let out = run_diagnosis(&c, OrderMode::Case).unwrap();
    let ratio = out.final_nrmse / c.noise_floor_nrmse;
    let named = !names_nonlinearity || out.causes.iter().any(|n| n == "nonlinearity");
    assert!(
        named && c.causes_right(&out.causes) && ratio <= max_ratio,
        "{}: named {:?}, final/floor {ratio:.2}, steps {:?}",
        c.description,
        out.causes,
        out.steps
    );
}

/// `hammerstein-odd` seed 1 (an odd static map before second-order dynamics).
#[test]
fn a_generated_hammerstein_system_is_named_and_reaches_the_floor() {
    assert_right_within("hammerstein-odd", 1, 1.5, true);
}

/// `saturation` seed 6: a hard saturation dominates the response, the
/// linear baseline's delay scan lands five samples late (nk 6), and the
/// Hammerstein candidates at that delay and one sample either side stay
/// 2.3× above the floor; the candidate at the plain one-sample delay
/// reaches it.
#[test]
fn a_saturation_whose_linear_delay_is_far_off_reaches_the_floor() {
    assert_right_within("saturation", 6, 1.5, false);
}

/// `deadzone` seed 3 and `hammerstein-even` seed 3: the Hammerstein
/// candidates have the true structure, but while the block fitter started
/// every simulation from the first noisy outputs they stayed above the
/// floor (2.95× and 2.30×, the latter beaten by the linear baseline); with
/// the starting history estimated for each trial model both reach it.
#[test]
fn a_hammerstein_with_the_true_structure_reaches_the_floor() {
    for (family, seed) in [("deadzone", 3), ("hammerstein-even", 3)] {
        assert_right_within(family, seed, 1.3, false);
    }
}

/// `friction` seeds 4 (a free mass, velocity output, 575 samples) and 5
/// (a mass on a spring, position output): Coulomb friction `F_c·tanh(v/ε)`.
/// Before the blind templates had a dry-friction law, seed 4 was named
/// `noise` at 6.9× the floor and seed 5 ended at 1.7× after a polynomial
/// model; the first- and second-order templates with `−f·tanh(x/ε)` reach
/// the floor in one step.
#[test]
fn dry_friction_on_a_velocity_reaches_the_floor() {
    for seed in [4, 5] {
        assert_right_within("friction", seed, 1.3, true);
    }
}

/// `hammerstein-odd` seed 10 (`u + a·u³` before a first-order lag, 586
/// training samples, the validation input beyond the training range) and
/// `wiener` seed 8 (a sensor law `y + a₂y² + a₃y³` after third-order
/// dynamics, 667 samples): the cubic polynomial among the block-oriented
/// maps fits as well as the splines and extrapolates as itself; with
/// splines only (linear beyond the training range) they ended at 1.87×
/// and 1.47× the floor.
#[test]
fn a_polynomial_law_extrapolates_beyond_the_training_range() {
    for (family, seed) in [("hammerstein-odd", 10), ("wiener", 8)] {
        assert_right_within(family, seed, 1.3, true);
    }
}

/// `duffing` seed 3 at 8000 + 4000 samples (a sweep, 30 samples per
/// period): the Preisach columns and the LOLIMOT network tie on the select
/// block (+0.237 each), and the model with both gains nothing over either
/// (−0.2 % each way). The unique contributions then cannot tell: the
/// candidate with fewer parameters wins (the network, 60 against 99), as
/// for the engineer's model. Before, the larger of two equal negative
/// contributions gave the tie to hysteresis, a foreign cause.
#[test]
fn a_tie_the_model_with_both_cannot_resolve_goes_to_fewer_parameters() {
    use gb_diagnose::generator::{draw_with, Knobs};
    let knobs = Knobs::lengths(8000, 4000);
    let c = draw_with("duffing", 3, &knobs).unwrap();
    let out = run_diagnosis(&c, OrderMode::Case).unwrap();
    let ratio = out.final_nrmse / c.noise_floor_nrmse;
    assert!(
        out.causes == ["nonlinearity"] && ratio <= 1.05,
        "named {:?}, final/floor {ratio:.2}, steps {:?}",
        out.causes,
        out.steps
    );
}

/// `saturation` seed 1 at 8000 + 4000 samples (a sweep with slow
/// components; the validation input spans 30 % beyond the training input):
/// the accepted Wiener–Hammerstein network's outermost local models, with
/// no training data in their validity regions, had slopes of 19–64 beyond
/// the training range of its internal signal, and the final model reached
/// 67.9× the noise floor on the validation record. Extrapolated with its
/// outer trend, it ends within 1.3× the floor.
#[test]
fn a_saturation_beyond_the_training_range_stays_near_the_floor() {
    use gb_diagnose::generator::{draw_with, Knobs};
    let c = draw_with("saturation", 1, &Knobs::lengths(8000, 4000)).unwrap();
    let out = run_diagnosis(&c, OrderMode::Case).unwrap();
    let ratio = out.final_nrmse / c.noise_floor_nrmse;
    assert!(
        c.causes_right(&out.causes) && ratio <= 1.3,
        "named {:?}, final/floor {ratio:.2}, steps {:?}",
        out.causes,
        out.steps
    );
}
