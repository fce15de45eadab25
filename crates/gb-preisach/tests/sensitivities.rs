//! Full derivative of the Preisach output with respect to the input signal:
//! current sample plus stored extrema, checked by finite differences.
#![allow(clippy::needless_range_loop)]
use gb_preisach::{
    Everett, GridEverett, GridPreisachRegressor, HysteresisRegressor, InitialState,
    ParametricEverett, Preisach,
};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

fn input(seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut x = vec![0.0];
    let mut prev = 0.0;
    for _ in 0..40 {
        let next = rng.random_range(-0.95..0.95);
        for k in 1..=3 {
            x.push(prev + (next - prev) * k as f64 / 3.0);
        }
        prev = next;
    }
    x
}

fn check<E: Everett + Clone>(p: &Preisach<E>, x: &[f64], tol: f64) -> usize {
    let init = InitialState::History(vec![1.0, -1.0, 0.97]);
    let mut st = p.state(&init).unwrap();
    let mut d_now = 0.0;
    for &v in x {
        d_now = p.step_with_derivative(&mut st, v).1;
    }
    let sens = p.extremum_sensitivities(&st);
    let times = st.extremum_times();
    assert_eq!(sens.len(), times.len());
    let y_at = |xx: &[f64]| *p.simulate(xx, &init).unwrap().last().unwrap();
    let h = 1e-6;
    let mut checked = 0;
    for (s, t) in sens.iter().zip(&times) {
        let Some(t) = *t else { continue };
        let (mut up, mut dn) = (x.to_vec(), x.to_vec());
        up[t] += h;
        dn[t] -= h;
        let fd = (y_at(&up) - y_at(&dn)) / (2.0 * h);
        assert!((fd - s).abs() < tol, "t = {t}: fd {fd} vs {s}");
        checked += 1;
    }
    // Current sample: one-sided in the branch direction.
    let last = x.len() - 1;
    let dir = if st.ascending() { 1.0 } else { -1.0 };
    let mut up = x.to_vec();
    up[last] += dir * h;
    let fd = (y_at(&up) - y_at(x)) / (dir * h);
    assert!((fd - d_now).abs() < tol, "current: fd {fd} vs {d_now}");
    // Initial-state extrema have no sample index.
    assert!(times.iter().any(|t| t.is_none()) || checked == times.len());
    checked
}

#[test]
fn extremum_sensitivities_match_finite_differences() {
    let gauss = Preisach::new(ParametricEverett::gaussian(1.0, 0.3, 0.25, -0.3, 0.25).unwrap());
    let grid = Preisach::new(
        GridEverett::from_everett(
            &ParametricEverett::gaussian(1.0, 0.3, 0.25, -0.3, 0.25).unwrap(),
            -1.0,
            1.0,
            9,
        )
        .unwrap(),
    );
    let mut total = 0;
    for seed in 1..6 {
        let x = input(seed);
        total += check(&gauss, &x, 1e-5);
        total += check(&grid, &x, 1e-5);
    }
    assert!(total > 20, "too few extrema checked: {total}");
}

#[test]
fn regressor_extremum_derivatives_match_model() {
    let f = ParametricEverett::gaussian(1.0, 0.3, 0.25, -0.3, 0.25).unwrap();
    let g = GridEverett::from_everett(&f, -1.0, 1.0, 9).unwrap();
    let reg = GridPreisachRegressor::new(-1.0, 1.0, 9, InitialState::NegativeSaturation).unwrap();
    let model = reg.model(g.masses().to_vec()).unwrap();
    let x = input(3);
    let mut st = reg.start(x[0]).unwrap();
    let mut mst = model.state(&InitialState::NegativeSaturation).unwrap();
    let (mut row, mut d_row) = (vec![0.0; reg.n_columns()], vec![0.0; reg.n_columns()]);
    for &v in &x {
        reg.step(&mut st, v, &mut row, &mut d_row);
        model.step(&mut mst, v);
        let rows = reg.extremum_derivatives(&st);
        let sens = model.extremum_sensitivities(&mst);
        assert_eq!(rows.len(), sens.len());
        for (r, s) in rows.iter().zip(&sens) {
            let lin: f64 = r.iter().zip(g.masses()).map(|(a, w)| a * w).sum();
            assert!((lin - s).abs() < 1e-10);
        }
    }
}
