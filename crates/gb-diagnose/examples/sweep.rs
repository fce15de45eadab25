//! Run the diagnosis on every generated system for a few seeds and print
//! the named causes against the hidden ones.
//!
//! `cargo run --release -p gb-diagnose --example sweep [SYSTEM...]`
use gb_diagnose::{diagnose, systems, DiagnoseData, DiagnoseOptions};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let list: Vec<String> = if args.is_empty() {
        systems::SYSTEMS.iter().map(|s| s.to_string()).collect()
    } else {
        args
    };
    for s in &list {
        for seed in [1u64, 2] {
            let t = std::time::Instant::now();
            let g = match systems::generate(s, seed, 8000, 4000) {
                Ok(g) => g,
                Err(e) => {
                    println!("{s}: {e}");
                    continue;
                }
            };
            let floor = g.noise_floor_nrmse;
            let d = DiagnoseData::with_validation(g.train, g.validate).unwrap();
            match diagnose(&d, &DiagnoseOptions::default(), None) {
                Ok(r) => {
                    let rep = &r.report;
                    println!(
                        "{s:>15} seed {seed}: expect {:?} got {:?}  base {:.4} final {:.4} floor {:.4} ratio {:.2}  {:.1}s",
                        systems::expected_cause(s),
                        rep.causes,
                        rep.baseline.nrmse,
                        rep.final_model.nrmse,
                        floor,
                        rep.final_model.nrmse / floor,
                        t.elapsed().as_secs_f64()
                    );
                    for st in &rep.steps {
                        println!(
                            "      it{} {:12} sel {:+.3} [{:+.3},{:+.3}] rep {:+.3} {} {}",
                            st.iteration,
                            st.cause,
                            st.gain_select,
                            st.gain_ci[0],
                            st.gain_ci[1],
                            st.gain,
                            st.gain_metric,
                            if st.accepted { "ACCEPT" } else { "" }
                        );
                    }
                    println!(
                        "      mem F {:.1} p {:.1e}; static F {:.1}",
                        rep.evidence.memory.0,
                        rep.evidence.memory.1,
                        rep.evidence.static_nonlinearity.0
                    );
                }
                Err(e) => println!("{s} seed {seed}: error {e}"),
            }
        }
    }
}
