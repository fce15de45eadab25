//! Particle smoothers against the exact RTS smoother.
use gb_smc::smoothing::{
    backward_simulation, ffbsm_weights, fixed_lag, weighted_moments, BackwardMethod,
};
use gb_smc::{FilterConfig, KalmanFilter, LinearGaussian, Observations, StepSummary};

fn setup(t: usize) -> (LinearGaussian, Vec<f64>) {
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
    let (_, y) = model.simulate(t, 21);
    (model, y)
}

/// Root-mean-square standardised error `(m̂_t − m_t) / sd_t` over time.
fn rms_z(est: &[f64], mean: &[f64], var: &[f64]) -> f64 {
    let s: f64 = est
        .iter()
        .zip(mean)
        .zip(var)
        .map(|((e, m), v)| (e - m).powi(2) / v)
        .sum();
    (s / est.len() as f64).sqrt()
}

fn means(s: &[StepSummary]) -> Vec<f64> {
    s.iter().map(|x| x.mean[0]).collect()
}

#[test]
fn ffbsm_matches_rts() {
    let (model, y) = setup(50);
    let obs = Observations::new(&y);
    let kf = KalmanFilter::new(&model);
    let (ms, ps) = kf.smooth(&y).unwrap();
    let filt = kf.filter(&y).unwrap();
    // negative control: filtering means are far from the smoothed ones
    let control = rms_z(&filt.mean, &ms, &ps);
    let pf = FilterConfig::new(400)
        .seed(3)
        .store_history(true)
        .build()
        .unwrap();
    let h = pf.run(&model, &obs).unwrap().history.unwrap();
    let w = ffbsm_weights(&model, &h, &obs).unwrap();
    let s = weighted_moments(&h, &w);
    let z = rms_z(&means(&s), &ms, &ps);
    let var_ratio: f64 =
        s.iter().zip(&ps).map(|(a, p)| a.var[0] / p).sum::<f64>() / ps.len() as f64;
    println!("FFBSm rms z = {z:.3} (filter control {control:.3}), var ratio {var_ratio:.3}");
    assert!(z < 0.12, "rms z = {z}");
    assert!(control > 0.3, "control {control}");
    assert!((var_ratio - 1.0).abs() < 0.15, "var ratio {var_ratio}");
}

#[test]
fn backward_simulation_matches_rts() {
    let (model, y) = setup(50);
    let obs = Observations::new(&y);
    let (ms, ps) = KalmanFilter::new(&model).smooth(&y).unwrap();
    let pf = FilterConfig::new(500)
        .seed(4)
        .store_history(true)
        .build()
        .unwrap();
    let h = pf.run(&model, &obs).unwrap().history.unwrap();
    for method in [
        BackwardMethod::Exact,
        BackwardMethod::Rejection { max_tries: 100 },
    ] {
        let tr = backward_simulation(&model, &h, &obs, 400, 8, method).unwrap();
        let s = tr.moments();
        let z = rms_z(&means(&s), &ms, &ps);
        let var_ratio: f64 =
            s.iter().zip(&ps).map(|(a, p)| a.var[0] / p).sum::<f64>() / ps.len() as f64;
        println!(
            "{method:?}: rms z = {z:.3}, var ratio {var_ratio:.3}, acceptance {:.3}",
            tr.acceptance_rate
        );
        assert!(z < 0.15, "{method:?}: rms z = {z}");
        assert!(
            (var_ratio - 1.0).abs() < 0.15,
            "{method:?}: var ratio {var_ratio}"
        );
        if let BackwardMethod::Rejection { .. } = method {
            assert!(tr.acceptance_rate > 0.05 && tr.acceptance_rate <= 1.0);
        }
    }
}

#[test]
fn fixed_lag_matches_truncated_rts() {
    let (model, y) = setup(60);
    let obs = Observations::new(&y);
    let lag = 5;
    let kf = KalmanFilter::new(&model);
    let (mut m_lag, mut v_lag) = (Vec::new(), Vec::new());
    for t in 0..y.len() {
        let end = (t + lag).min(y.len() - 1);
        let (ms, ps) = kf.smooth(&y[..=end]).unwrap();
        m_lag.push(ms[t]);
        v_lag.push(ps[t]);
    }
    let pf = FilterConfig::new(8000)
        .seed(5)
        .store_history(true)
        .build()
        .unwrap();
    let h = pf.run(&model, &obs).unwrap().history.unwrap();
    let s = fixed_lag(&h, lag).unwrap();
    let z = rms_z(&means(&s), &m_lag, &v_lag);
    let filt = kf.filter(&y).unwrap();
    let control = rms_z(&filt.mean, &m_lag, &v_lag);
    println!("fixed-lag rms z = {z:.3} (filter control {control:.3})");
    assert!(z < 0.12, "rms z = {z}");
    assert!(control > 0.3);
    // lag 0 is the filter itself
    let s0 = fixed_lag(&h, 0).unwrap();
    let z0 = rms_z(&means(&s0), &filt.mean, &filt.var);
    assert!(z0 < 0.1, "lag-0 rms z = {z0}");
}

#[test]
fn smoothing_needs_history() {
    let (model, y) = setup(10);
    let obs = Observations::new(&y);
    let pf = FilterConfig::new(50).store_history(true).build().unwrap();
    let h = pf.run(&model, &obs).unwrap().history.unwrap();
    let short = Observations::new(&y[..5]);
    assert!(ffbsm_weights(&model, &h, &short).is_err());
    assert!(backward_simulation(&model, &h, &obs, 0, 1, BackwardMethod::Exact).is_err());
}
