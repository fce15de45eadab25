//! Tests of the generator: determinism, sane data for every family and the
//! extreme knobs, the noise floor against its definition, and that the
//! hidden effects are really there.
use super::excite::{Excitation, ExcitationKind};
use super::maps::{InputMap, RelayGrid};
use super::plant::{Core, Section, System};
use super::*;
use gb_core::metrics;

fn knobs(n: usize) -> Knobs {
    Knobs {
        n_train: Some(n),
        n_validate: Some(n / 2),
        ..Knobs::default()
    }
}

fn noise_free(k: &Knobs) -> Knobs {
    Knobs {
        noise_free: true,
        ..k.clone()
    }
}

#[test]
fn same_seed_same_data_other_seed_other_data() {
    for f in ["duffing", "two-input", "process-noise", "preisach"] {
        let a = draw_with(f, 5, &knobs(600)).unwrap();
        let b = draw_with(f, 5, &knobs(600)).unwrap();
        let c = draw_with(f, 6, &knobs(600)).unwrap();
        assert_eq!(a.train, b.train, "{f}");
        assert_eq!(a.validate, b.validate, "{f}");
        assert_eq!(a.parameters, b.parameters, "{f}");
        assert_ne!(a.train.output, c.train.output, "{f}");
        // training and validation inputs are independent realisations
        assert_ne!(a.train.inputs[0][..300], a.validate.inputs[0][..300], "{f}");
    }
    // the same seed in another family is another system
    let a = draw_with("linear", 5, &knobs(600)).unwrap();
    let b = draw_with("dead-time", 5, &knobs(600)).unwrap();
    assert_ne!(a.train.inputs, b.train.inputs);
}

#[test]
fn golden_values_pin_the_streams() {
    // a change of the draw order or of a stream changes these (relative 1e-9
    // leaves room for last-bit differences of libm between platforms)
    let c = draw("bouc-wen", 1).unwrap();
    let g = [
        (c.train.len() as f64, GOLDEN[0]),
        (c.train.output[100], GOLDEN[1]),
        (c.validate.inputs[0][7], GOLDEN[2]),
        (c.noise_floor_nrmse, GOLDEN[3]),
    ];
    for (i, (got, want)) in g.iter().enumerate() {
        assert!(
            (got - want).abs() <= 1e-9 * want.abs().max(1e-300),
            "golden value {i}: got {got:e}, want {want:e}"
        );
    }
}

const GOLDEN: [f64; 4] = [
    2582.0,
    0.009514578832109264,
    0.004996307556590952,
    0.015990601472909104,
];

fn check_sane(c: &Case, what: &str) {
    for d in [&c.train, &c.validate] {
        assert!(d.output.iter().all(|v| v.is_finite()), "{what}");
        assert!(metrics::std(&d.output) > 0.0, "{what}: constant output");
        for u in &d.inputs {
            assert!(metrics::std(u) > 0.0, "{what}: constant input");
        }
    }
    assert!(
        c.noise_floor_nrmse > 0.0 && c.noise_floor_nrmse < 0.5,
        "{what}: floor {}",
        c.noise_floor_nrmse
    );
    assert!(
        c.effect_strength.is_finite() && c.effect_strength >= 0.0,
        "{what}"
    );
    assert!(c.ts > 0.0 && c.model_order >= 1, "{what}");
    let fam = Family::parse(&c.family).unwrap();
    assert_eq!(fam.name(), c.family);
    for f in &c.foreign {
        assert!(
            !c.expected.contains(f),
            "{what}: {f} both expected and foreign"
        );
    }
}

#[test]
fn every_family_generates_sane_data() {
    for f in FAMILIES {
        for seed in 1..=3 {
            let c = draw_with(f, seed, &knobs(800)).unwrap();
            check_sane(&c, &format!("{f} seed {seed}"));
            assert_eq!(c.train.len(), 800);
            assert_eq!(c.validate.len(), 400);
        }
        // drawn knobs: lengths in range, validation about half, at least 300
        let c = draw(f, 11).unwrap();
        assert!((500..=20_000).contains(&c.train.len()), "{f}");
        assert!(c.validate.len() >= 300, "{f}");
        assert!((20.0..=45.0).contains(&c.snr_db), "{f}");
        assert!((5.0..=60.0).contains(&c.samples_per_period), "{f}");
    }
    assert!(draw("nope", 1).is_err());
    assert!(draw_with(
        "linear",
        1,
        &Knobs {
            n_train: Some(5),
            ..Knobs::default()
        }
    )
    .is_err());
}

#[test]
fn extreme_knobs_give_sane_data() {
    for f in FAMILIES {
        for (i, kind) in ExcitationKind::ALL.into_iter().enumerate() {
            let k = Knobs {
                n_train: Some(500),
                n_validate: Some(300),
                snr_db: Some(20.0),
                samples_per_period: Some(5.0),
                excitation: Some(kind),
                slow_component: Some(i % 2 == 1),
                noise_free: false,
            };
            let c = draw_with(f, 2, &k).unwrap();
            check_sane(&c, &format!("{f} {kind:?}"));
            assert_eq!((c.train.len(), c.validate.len()), (500, 300));
            assert_eq!(c.excitation.kind, kind);
        }
    }
}

#[test]
fn noise_floor_is_what_was_put_in() {
    for f in FAMILIES {
        let k = knobs(4000);
        let c = draw_with(f, 4, &k).unwrap();
        let clean = draw_with(f, 4, &noise_free(&k)).unwrap();
        assert_eq!(c.train.inputs, clean.train.inputs, "{f}");
        assert_eq!(clean.noise_floor_nrmse, 0.0);
        let e_va: Vec<f64> = c
            .validate
            .output
            .iter()
            .zip(&clean.validate.output)
            .map(|(a, b)| a - b)
            .collect();
        let e_tr: Vec<f64> = c
            .train
            .output
            .iter()
            .zip(&clean.train.output)
            .map(|(a, b)| a - b)
            .collect();
        let floor = match c.noise {
            NoiseKind::Process { .. } => metrics::rms(&e_va) / metrics::std(&c.validate.output),
            _ => metrics::std(&e_va) / metrics::std(&c.validate.output),
        };
        assert!(
            (floor - c.noise_floor_nrmse).abs() < 1e-12,
            "{f}: {floor} vs {}",
            c.noise_floor_nrmse
        );
        // SNR: noise std against the noise-free training output
        let snr = 20.0 * (metrics::std(&clean.train.output) / metrics::std(&e_tr)).log10();
        let tol = match c.noise {
            NoiseKind::StudentT { .. } => 4.0, // heavy tails: the sample std scatters
            NoiseKind::Coloured { .. } => 2.0,
            _ => 1.0,
        };
        assert!(
            (snr - c.snr_db).abs() < tol,
            "{f}: SNR {snr:.2} dB, nominal {:.2}",
            c.snr_db
        );
    }
}

/// Free-run NRMSE of a generous ARX model (na 6, input lags 0..=16) fitted
/// on noise-free training data, on noise-free validation data.
fn generous_arx(c: &Case) -> f64 {
    let lags: Vec<Vec<usize>> = vec![(0..=16).collect(); c.train.n_inputs()];
    arx_misfit(
        (&c.train.inputs, &c.train.output),
        (&c.validate.inputs, &c.validate.output),
        6,
        &lags,
    )
    .unwrap()
}

#[test]
fn hidden_nonlinearity_is_real() {
    let k = noise_free(&knobs(3000));
    let mut linear_worst: f64 = 0.0;
    for f in ["linear", "dead-time", "student-t"] {
        for seed in 1..=4 {
            let c = draw_with(f, seed, &k).unwrap();
            linear_worst = linear_worst.max(generous_arx(&c));
            assert!(
                c.effect_strength < 1e-4,
                "{f} {seed}: {}",
                c.effect_strength
            );
        }
    }
    assert!(
        linear_worst < 1e-3,
        "a linear family is not linear: {linear_worst}"
    );
    let nonlinear = [
        "duffing",
        "hammerstein-odd",
        "hammerstein-even",
        "wiener",
        "saturation",
        "deadzone",
        "friction",
        "backlash",
        "preisach",
        "bouc-wen",
        "two-input",
    ];
    for f in nonlinear {
        let mut e = vec![];
        for seed in 1..=4 {
            let c = draw_with(f, seed, &k).unwrap();
            e.push(generous_arx(&c).min(c.effect_strength));
        }
        e.sort_by(f64::total_cmp);
        // every draw clearly above the linear families, the typical one by far
        assert!(e[0] > 10.0 * linear_worst.max(1e-4), "{f}: {e:?}");
        assert!(e[1] > 0.02, "{f}: {e:?}");
    }
}

/// Free-run NRMSE of a least-squares ARX model (orders true + 1) on the
/// inputs plus extra columns made from them.
type Columns = dyn Fn(&[Vec<f64>]) -> Vec<Vec<f64>>;

fn free_run(c: &Case, extra: &Columns) -> f64 {
    let n = c.true_order + 1;
    let lags = |k: usize| -> Vec<Vec<usize>> { vec![(1..=n).collect(); k] };
    let (ut, uv) = (extra(&c.train.inputs), extra(&c.validate.inputs));
    let m = Arx::fit(&ut, &c.train.output, n, &lags(ut.len())).unwrap();
    m.free_run_nrmse(&uv, &c.validate.output).unwrap()
}

#[test]
fn two_input_nonlinearity_is_on_the_recorded_input() {
    let k = noise_free(&knobs(3000));
    for seed in 1..=6 {
        let c = draw_with("two-input", seed, &k).unwrap();
        let j = c.nonlinear_input.unwrap();
        let poly = |i: usize| {
            move |u: &[Vec<f64>]| -> Vec<Vec<f64>> {
                let mut v = u.to_vec();
                v.push(u[i].iter().map(|x| x * x).collect());
                v.push(u[i].iter().map(|x| x * x * x).collect());
                v.push(u[i].iter().map(|x| x * x.abs()).collect());
                v
            }
        };
        let lin = free_run(&c, &|u| u.to_vec());
        let on_j = free_run(&c, &poly(j));
        let on_other = free_run(&c, &poly(1 - j));
        assert!(
            on_j < 0.5 * on_other && on_j < 0.5 * lin,
            "seed {seed}: input {j} linear {lin:.4}, poly on it {on_j:.4}, on the other {on_other:.4}"
        );
    }
}

#[test]
fn zoh_sampling_delay_and_feedthrough() {
    let tau = 0.3;
    let mut s = System::new(Core::Cascade(vec![Section::First { tau }]), 1);
    s.ts = 0.1;
    s.delay = 2;
    s.feedthrough = 0.5;
    s.set_substeps(0.0);
    let y = s.simulate(&[vec![1.0; 10]], None, None).unwrap();
    assert_eq!(&y[..2], &[0.0, 0.0]);
    assert!((y[2] - 0.5).abs() < 1e-12);
    for k in 3..10 {
        let want = 0.5 + 1.0 - (-((k - 2) as f64) * 0.1 / tau).exp();
        assert!((y[k] - want).abs() < 1e-6, "k {k}: {} vs {want}", y[k]);
    }
}

#[test]
fn maps_and_relays() {
    let mut st = 0.0;
    let b = InputMap::Backlash(0.5);
    assert_eq!(b.apply(0.3, &mut st), 0.0);
    assert_eq!(b.apply(1.0, &mut st), 0.5);
    assert_eq!(b.apply(0.6, &mut st), 0.5);
    assert_eq!(b.apply(-1.0, &mut st), -0.5);
    assert_eq!(InputMap::DeadZone(0.2).apply(0.1, &mut st), 0.0);
    assert!((InputMap::DeadZone(0.2).apply(-0.5, &mut st) + 0.3).abs() < 1e-15);
    let mut g = RelayGrid::new(1.0, 16, 0.5);
    let y0 = g.step(0.0);
    g.step(0.6);
    assert!(g.step(0.0) > y0 + 1e-3, "no loop");
    g.step(1.0);
    let a = g.step(0.2);
    g.step(-0.4);
    g.step(1.0);
    assert!((g.step(0.2) - a).abs() < 1e-12, "no wiping out");
}

#[test]
fn excitations_have_unit_rms_and_their_shape() {
    let mut r = gb_core::rng::seeded(3);
    for kind in ExcitationKind::ALL {
        let mut e = Excitation::draw(&mut r, Some(kind), Some(false));
        e.band_hi = 2.0;
        e.band_lo = 0.2;
        let x = e.realise(4096, 0.05, &mut r);
        assert!((metrics::rms(&x) - 1.0).abs() < 1e-12, "{kind:?}");
        if kind == ExcitationKind::Prbs {
            let a = x[0].abs();
            assert!(
                x.iter().all(|v| (v.abs() - a).abs() < 1e-12),
                "PRBS not binary"
            );
        }
        if kind == ExcitationKind::Multisine {
            // one period: no power outside the band [0.01, 0.1] cycles/sample
            let n = x.len() as f64;
            let power = |k: usize| {
                let (mut c, mut s) = (0.0, 0.0);
                for (t, v) in x.iter().enumerate() {
                    let w = 2.0 * std::f64::consts::PI * (k * t) as f64 / n;
                    c += v * w.cos();
                    s += v * w.sin();
                }
                c * c + s * s
            };
            assert!(power(20) < 1e-12 * power(100), "below the band");
            assert!(power(600) < 1e-12 * power(100), "above the band");
        }
    }
}

#[test]
fn right_and_foreign_causes() {
    let mut c = draw_with("coloured-noise", 1, &knobs(600)).unwrap();
    let v = |s: &[&str]| -> Vec<String> { s.iter().map(|x| x.to_string()).collect() };
    assert!(c.causes_right(&v(&["noise"])));
    assert!(c.causes_right(&v(&[])));
    assert!(!c.causes_right(&v(&["dynamics"])));
    assert_eq!(
        c.foreign_named(&v(&["dynamics", "noise"])),
        v(&["dynamics"])
    );
    c.expected = v(&["nonlinearity"]);
    c.acceptable_alternatives = vec![];
    assert!(!c.causes_right(&v(&[])));
    assert!(!c.causes_right(&v(&["nonlinearity", "dynamics"])));
    let l = draw_with("linear", 1, &knobs(600)).unwrap();
    assert!(l.causes_right(&[]) && !l.causes_right(&v(&["dynamics"])));
    assert_eq!(l.foreign.len(), 4);
    let f = draw_with("bouc-wen", 1, &knobs(600)).unwrap();
    assert_eq!(f.expected, v(&["hysteresis"]));
    assert_eq!(f.foreign, v(&["nonlinearity", "dynamics", "noise"]));
}
