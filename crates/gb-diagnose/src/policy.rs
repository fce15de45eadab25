//! Every threshold the diagnosis decides with, in one place.
use crate::DiagnoseError;

/// The decision policy of a diagnosis: when a candidate extension "pays",
/// when noise is heavy-tailed, when residuals count as unexplained, how
/// data are split. Validate with [`check`](Self::check).
///
/// | field | default | rationale |
/// |---|---|---|
/// | `min_gain` | 0.05 | a structural extension must lower the select-block NRMSE by ≥ 5 % (an effect size, on top of significance) |
/// | `evidenced_dynamics_gain` | 0.01 | a `dynamics` candidate (an order increase) with a significant gain below `min_gain` still pays when it lowers the select-block NRMSE by ≥ 1 % and answers the evidence of missing dynamics: the current model's input–residual cross-correlation test rejects at `verdict_level`, the candidate's passes on every input; from a fresh start of the select block it must then gain this much too, not `min_gain` |
/// | `information_order_margin` | 10 | under cross-validation forced by a select block unlike the training record (a sweep's last stretch), an order increase of a plain linear model with a positive gain on the folds whose interval reaches below 0 still pays when Schwarz's criterion `N ln σ̂² + p ln N` of the free-run residuals on the whole training record falls by at least this much (strong evidence on the Kass–Raftery scale): a fold then holds out a frequency band the rest of the record never excites, and a mode there cannot be refitted from the rest |
/// | `min_nll_gain` | 0.02 | a noise model must lower the select-block negative log-likelihood by ≥ 0.02 nats/sample |
/// | `bootstrap` | 400 | moving-block bootstrap replicates of every gain interval (95 %) |
/// | `seed` | 1 | seed of the bootstrap streams (a diagnosis is reproducible) |
/// | `block_divisor`, `block_min`, `block_max` | 40, 25, 200 | bootstrap block length `clamp(n/40, 25, 200)`, raised to the dependence range of the current model's residuals on the decision data (`stats::dependence_range`, Politis & White's `m̂`) when that is longer, but to no more than `n / block_count_min`: blocks must keep the residuals' correlation, else a coloured residual (process noise, a lightly damped misfit) gives intervals that are too narrow |
/// | `block_count_min` | 8 | fewest blocks of the select data a bootstrap resamples |
/// | `auto_orders` | 1..=6 | orders tried by `--order auto` |
/// | `auto_order_tolerance` | 1.02 | `--order auto` takes the lowest order within 2 % of the best select-block NRMSE (parsimony) |
/// | `heavy_tail_p` | 1e-3 | noise is heavy-tailed when the Jarque–Bera p-value is below this … |
/// | `heavy_tail_kurtosis` | 0.5 | … and the excess kurtosis above this (skewed but light tails are not "noise"); the fitted Student-t must be as heavy: `6/(ν − 4)` above this, ν < 16 (the pooled residuals of cross-validation folds can be heavy-tailed where the noise is not; the fit on the training record then ends at a Gaussian-like ν = 100) |
/// | `noise_nrmse_tolerance` | 1.02 | a noise model may not worsen the select-block NRMSE by more than 2 % |
/// | `tie_bootstrap`, `tie_seed` | 50, 0 | replicates and seed of the unique-contribution comparison when nonlinearity and hysteresis tie |
/// | `unexplained_p` | 1e-3 | residuals are still unexplained when Ljung–Box or the memory test reject at this level; then the hidden-state model is tried |
/// | `memory_priority_p` | 0.01 | when the best new cause is a plain order increase and a paying hysteresis candidate's gain interval overlaps its interval, the hysteresis candidate is chosen if the direction-of-motion memory test rejects at this level on the current residual and on the order increase's own — only one at the increased linear order or above (its model nests the order increase, and the residual's loop is evidence an order increase cannot explain; a missing pole's lagging residual also reads as a loop, and a candidate at the current order does not nest the pole) |
/// | `hidden_state_fit_samples` | 4000 | most fit-block samples the hidden-state model is fitted on (its fit is the costliest) |
/// | `template_fit_samples`, `template_fit_max` | 4000, 20000 | leading fit-block samples the blind mechanical template and its physics extensions are fitted on: 4000, doubled while the rest of the fit block is not represented by them (the level or pace test of `block_shift_ratio`: a sweep, a changing amplitude), up to 20000 (their RK4 fits cost linear in the samples) |
/// | `nonlinear_fit_samples` | 20000 | most fit-block samples the polynomial, block-oriented (Hammerstein, Wiener) and Preisach-column candidates are fitted on (their cost is linear in the samples) |
/// | `expensive_fit_samples` | 8000 | most fit-block samples the tree network and the Wiener–Hammerstein network are fitted on (their fits cost seconds per thousand samples) |
/// | `init_window_max`, `init_window_min`, `init_window_divisor` | 50, 10, 8 | leading samples of every evaluated record (report block, cross-validation fold) that set the initial state and are not scored: `clamp(shortest such block / 8, 10, 50)`, the benchmark's 50 on long records, 12 of a 100-sample block |
/// | `min_block` | 40 | fewest samples of the select and report blocks |
/// | `min_fit` | 60 | fewest samples of the fit block |
/// | `max_order` | 30 | highest linear order the dynamics extension and `--order auto` reach (in the ladder 1…6, 8, 10, 12, 16, 20, 24, 30, and by doubling: n → n+1, n+2, 2n) |
/// | `max_delay`, `max_delay_divisor` | 20, 6 | input delays scanned for the baseline: 0 ..= min(20, fit samples / 6) |
/// | `delay_tolerance` | 1.01 | among the delay candidates confirmed by the output-error fit, the one with fewer parameters (strictly proper rather than feedthrough) is kept when within 1 % of the best decision NRMSE |
/// | `feedthrough_gain` | 0.1 | a delay candidate with a direct feedthrough behind its dead time (n + 1 numerator terms) replaces the strictly proper choice only when it lowers the decision NRMSE by ≥ 10 % (smaller gains of an extra numerator term are as often a nonlinearity partly absorbed) |
/// | `structure_scan_samples` | 50 000 | most fit samples of the ARX delay / integrator scan |
/// | `delay_scan_samples` | 4000 | most fit samples of the output-error delay scan (one fit per delay and input at the reference order) |
/// | `integrator_pole` | 0.02 | an integrator is suspected when the ARX model has a real pole within 0.02 of 1 … |
/// | `integrator_gain` | 0.05 | … and kept when the increments model lowers the decision NRMSE of the baseline by ≥ 5 % (both models simulated from a fresh start on the select block) … |
/// | `integrator_beyond_unit` | true | … or whatever the linear fits say when the ARX pole lies at or beyond 1: a stable model cannot place it there, and with dry friction neither linear model fits, so their comparison says nothing (the generator's `integrator` family, seeds 3 and 8: a plain model of NRMSE 23× and 96× the floor on the validation record; with the increments 2.1× and 1.1×) |
/// | `integrated_criterion` | true | an integrator's increments models are trained for the error of their running sum (the output), the mean projected out, after a first training for the increments' error: the maximum-likelihood criterion for white noise on the output, where the increments' error weights the low frequencies, where the output's error accumulates, as little as the high ones (the generator's `integrator` family, seeds 1 and 5, linear: 1.93× and 2.83× the floor → 1.08× and 1.10×; EMPS' friction-map step: the pulses test 1.94 → 1.64 mm); the blind template's laws are proposed fitted both ways (integrator 9: 2.90× → 1.30×) |
/// | `repeat_correlation` | 0.99 | three 256-sample windows of the select block's every input each matched by a window of the fit block at this correlation: the record repeats its excitation, and the decisions line says that the held-out gains then show how a model reproduces this input, not how it carries over to others (EMPS: four runs of one trajectory, correlation 0.99996 at 6240 samples; Bouc–Wen's training multisine: five periods) |
/// | `repeat_shift_ratio` | 3 | when the select block repeats the fit block's input (`repeat_correlation`), a chosen step must carry over: simulated on the fit block's input time-reversed (an input that is the rate of another negated) and on it scaled by 0.8 about its mean (the same amplitudes and spectrum, not the trajectory), it may differ from the current model at most this many times more (rms) than on the input itself, unless a paying rival of another class agrees with it there within its difference on the input itself (the current model is what the trajectory tuned: duffing 5 at 635 samples); else it no longer pays and the step chooses again among the rest, and the decisions line says so. A model that learns the trajectory pays on a held-out repeat as much as one that carries over (EMPS, four runs of one trajectory: the 10-leaf network after the friction law 8.5× scaled, and it takes the pulses test from 1.63 to 16.4 mm; Bouc–Wen's five multisine periods: the hidden-state steps after the Preisach component 1.01× and 0.95× reversed, and they take the multisine test from 8.9e-5 to 5.3e-6 m) |
/// | `bootstrap_min_samples` | 300 | with fewer select samples the bootstrap of the select block is not trusted (fewer than 12 blocks of 25): decisions use blocked cross-validation over the training record instead |
/// | `block_shift_ratio` | 1.5 | decisions also use blocked cross-validation when the select block is not representative of the fit block: the level (rms about the fit block's mean) or the pace (rms increment over rms) of the output or an input differs by more than this factor either way (a sweep, a changing amplitude) … |
/// | `block_shift_outside` | 0.05 | … or more than this share of the select block's samples of a signal lie outside the fit block's range widened by a tenth (a drifting level): a gain measured there would not speak for the record |
/// | `cv_whole_short_record`, `cv_whole_min_samples` | true, 800 | one training record of at least 800 samples without a validation record, too short for the bootstrap (select block below `bootstrap_min_samples`: under about 1200 samples): the cross-validation spans the whole record, the report block included, instead of holding a quarter out of every decision (on the cascaded tanks' 1024 samples the folds over 768 samples could not tell the tanks' state-space network from the linear model, +0.12 [−0.37, +0.52]; over all 1024 they could, +0.69 [+0.52, +0.83]). The report then says its figures on the report block are in-sample and gives the cross-validated NRMSE as the held-out figure. Not for the engineer's equations (`--model-file`): their folds score every held-out sample, extrapolation included, and a record's tail that leaves the training range judges extrapolation only (on the tanks' file the report block's input falls to 0.41 V, the rest spans 1.21–6.47 V: the cubic law on x1 that paid over 768 samples, +0.22 [+0.07, +0.43], lost over 1024, −1.44). Not below 800 samples (folds of fewer than 200 held-out samples): on the project's generator at 400 training samples (18 cases) it named `nonlinearity` on a clean linear record at 34× the floor (the linear baseline's own fold refits scored NRMSE 5.6 / 1.3 / 2.5 / 0.31) and took a Wiener case from 3.1× to 153×, where at 1000 samples it named the right cause in 18 of 18 (17 before) and came within 1.5× the floor in 17 (16) |
/// | `cv_folds` | 4 | contiguous folds of the cross-validation; each fold is scored by the structure refitted on the longer contiguous rest of the record (no regressor spans a gap), the pooled held-out residuals take the select block's place in every decision rule |
/// | `cv_cover_pad`, `cv_cover_min` | 0.1, 0.2 | a fold scores only the held-out samples whose output and inputs lie in the range of the fold's fit record widened by a tenth of it (a fold fitted on one side of a drifting record extrapolates where the model fitted on the whole record does not); a fold with less than a fifth of its samples covered is scored whole |
/// | `cv_fold_wins` | 0.5 | under cross-validation a paying candidate must also beat the current model on at least this share of the folds (2 of 4): a pooled gain can come from one fold where the current structure's refit failed (3 of 4 is too strict for sweeps, whose folds are different frequency bands and an effect shows on some of them) |
/// | `cv_refit_gain` | 0.01 | under cross-validation a candidate that pays on the folds must also be realised by its refit on the whole training record: that model must lower the training record's in-sample RMSE by ≥ 1 % against the current model (a structure chosen inside the fit — LOLIMOT's leaves by AICc — can come out as the current model on the whole record, and then the folds' gain is not the final model's) |
/// | `cv_dynamics_realised` | true | under cross-validation a `dynamics` candidate (an order increase) must realise on the whole training record the gain it needs to pay — `min_gain`, or `evidenced_dynamics_gain` where it answers the residual evidence — not only `cv_refit_gain`: the pooled fold gain of a nested model can come from the current structure's fold refits extrapolating badly (a sweep's held-out band) while on the whole record the extra order gains next to nothing (backlash 4 of the sweep at its own length: +0.50 on the folds, 2.4 % in-sample, 2.6 % on the report block at the noise floor) |
/// | `long_record` | 100 000 | training records this long are searched on a subsample … |
/// | `search_samples` | 20 000 | … of this many training samples (the first ones; fit/select 75/25), and the chosen baseline and final structures are then refitted on the whole fit block |
/// | `search_budget_s` | 300 | no new extension step starts after this many seconds of search, on every record (`greybox diagnose --budget`); on a long record the structure found so far is refitted and reported |
/// | `refit_iterations` | 10 | Levenberg–Marquardt iterations of the refit on the whole record (started from the subsample's model) |
/// | `verdict_level` | 0.01 | overall level of the final residual tests (Bonferroni over the tests): "adequate" only when none rejects; also the level at which the process-noise candidate is proposed (only when these tests say "coloured noise": whiteness rejects, no input test does) |
/// | `process_noise_rival_gain` | 0.05 | the process-noise candidate is chosen only when no structural candidate of its iteration gains this much on the select block, significant or not: the colour must be explained better by a noise model than by any deterministic extension (a missed hysteresis leaves input-driven colour the correlation tests do not see) |
/// | `process_noise_smc_samples` | 2000 | most fit samples of the particle (PMMH) fit of the process-noise model with Student-t measurement noise (heavy-tailed residual; the Gaussian levels come from the exact Kalman likelihood on at most `nonlinear_fit_samples`) |
/// | `process_noise_particles`, `process_noise_iterations` | 100, 100 | particles and PMMH iterations (a quarter burn-in) of that fit: two noise levels started at their Gaussian estimate need few |
/// | `process_noise_filter_particles` | 1000 | particles of the filter that scores a non-Gaussian process-noise model's predictive likelihood on held-out data |
/// | `prediction_horizon` | 10 | the k of the k-step prediction RMSE reported (with 1-step) for a process-noise model |
/// | `retry_after_noise_step` | false | after a step that changed only the noise model (a heavy-tailed or process-noise model), the candidates that did not pay at that step are not proposed again: their deterministic part was judged against the same deterministic model, and the select gain is the same squared simulation error (on the sweep, no case named a second cause after `noise`; student-t cases spent half their time refitting every candidate robustly) |
/// | `stop_when_adequate`, `search_stop_level` | true, 0.05 | before each step the current model's residuals on the decision data get the verdict's tests (under cross-validation read as the verdict reads them), each at 5 % without the Bonferroni correction (a lenient reading: any hint of structure counts), and the Jarque–Bera normality test (heavy tails: the `noise` cause); when none rejects and the residual is within `verdict_noise_ratio` × the white-noise level, no extension is searched — the search runs where the residual shows a cause (clean data: the baseline alone). After an accepted step the search also stops at the screen's reading (`screen_level`, Bonferroni-corrected, within `screen_noise_ratio` × the white-noise level: what already decides that the costly candidates are not needed; friction 1 of the sweep, at the floor after its first step, searched twelve physics terms because one test rejected at 5 %) |
/// | `refit_on_training` | true | once the search has chosen the structure on the fit block, the chain (baseline, then every accepted extension in turn) is refitted on the whole training record (fit and select blocks) when decisions used the select block; a refitted model replaces its fit-block fit only when its free-run squared error over the whole training record is not larger (a refit that lands in a worse local minimum is dropped). The decisions and the verdict keep the fit-block fits' held-out residuals |
/// | `refit_on_all_samples` | true | with one training file and no validation record, the report block is the last quarter of that file: the scores are measured there, and then the model a user saves is the chosen chain refitted on all of the file (fit, select and report blocks), kept only when its free-run squared error over the file is not larger than the scored model's. With several training records, the chain refitted on every record whole (without a validation record the held-out last record too), kept by the same rule summed over the records. The report states both RMSEs; its scores, decisions and verdict stay those of the model fitted without the report block |
/// | `retry_after_refinement` | false | after a step that only added capacity to a named cause (more local models, more Preisach cells: a refinement), an extension whose every candidate lost decisively at that step (the whole 95 % interval of its select gain below zero) is not proposed again: the refinement gave it no structure it lacked (Silverbox: five Preisach-column variants on the local model network lost −0.12 to −1.5 at step 2 and took 90 of the 180 CPU seconds of step 3) |
/// | `linear_before_nonlinear` | true | a new `nonlinearity` or `hysteresis` cause is chosen over a paying higher linear order (`dynamics`) only when it also pays against that order's residuals on the decision data; else the order increase, the smaller change, is chosen (a third pole that the engineer's order-2 model absorbed as a dead time read as a Wiener–Hammerstein network at the same select gain, +0.397 against +0.392) |
/// | `futile_gain` | 0.025 | a fit of the mechanical template's extensions and of its static laws (the law from 0 on the fitted linear template; not on an integrating plan) on the whole fit block (not a fold's, not a refit) stops after 4 Levenberg–Marquardt iterations when its training RMSE has not fallen by this fraction (half of `min_gain`): such a candidate would be dropped by the in-sample screen anyway; a fit that passes goes on unchanged (0: never stop early) |
/// | `cv_in_sample_screen` | true | under cross-validation a `nonlinearity` or `hysteresis` candidate is first fitted on the whole training range; when its free-run residual over the folds' samples is not `min_gain` below the current model's (fitted the same way), its four fold fits are skipped and it does not pay (a held-out gain rarely exceeds the in-sample one; the row says so) |
/// | `rival_screen_ratio` | 1.0 | under cross-validation, the in-sample screen's second test: of the candidates that differ only in their input delay (the Hammerstein, Wiener and backlash structures at the current model's delay and its neighbours, `Extension::delay_rivals_key`), the one at the current delay and the one with the smallest in-sample RMS residual over the folds' samples are cross-validated; another whose in-sample residual exceeds the smallest times this factor is scored in-sample and does not pay (the same structure and number of parameters, so the in-sample error compares them; its row says so). At 1 only those two: the delays of an oversampled record fit alike (hammerstein-odd 4 of the 8000 + 4000 sweep: the three within 0.1 %, held-out gains +0.176, +0.175, +0.175), and their folds were a third of a case's time; 0 turns it off |
/// | `cv_bound_ratio` | 1.5 | under cross-validation, the in-sample screen's third test: a `nonlinearity` or `hysteresis` candidate whose in-sample RMS residual over the folds' samples exceeds this factor times the smallest cross-validated RMS residual of the step's candidates (nonlinearity, hysteresis, dynamics) is scored in-sample and does not pay (its row says so): the cross-validated error of a structure is not below its in-sample error, so it could not have come near the best. The candidates within the factor of the tier's best in-sample error are cross-validated first, the bound is read from them, then the rest; 0 turns it off |
/// | `screen_costly`, `screen_level`, `screen_bonferroni`, `screen_noise_ratio` | true, 0.01, true, 1.1 | the candidates of a step are fitted in tiers ([`crate::Extension::screen_tier`]: the cheap ones; the static laws of the mechanical template; the hysteretic template, the Wiener–Hammerstein network and the hidden-state model), a tier only when the paying candidate with the largest gain so far — or, when none paid, the current model — does not leave a quiet residual on the decision data: the verdict's tests pass at 1 % Bonferroni-corrected over the tests, as the final verdict reads them (uncorrected, at 5 % one of six or nine tests rejects by chance in a third of the cases at the floor, and at 1 % a Duffing case whose spring law reached the floor, input cross-correlation p = 0.0019, still fitted the hysteretic template and a second step: 32 → 10 s), the Jarque–Bera test at 1 %, and the residual is within 1.1× the white-noise level; under cross-validation the tests read as the final verdict reads them (each p-value the smaller of the model's own over the folds' samples and the lower median of the folds', [`crate::verdict`]) and the Jarque–Bera test reads the model's own residual (the pooled held-out residuals of four fold refits mix four error levels and failed it at p ≈ 0 for a model at the floor). A structure that the cheap candidates already explain to the noise level, or a residual none of them improves that is quiet already, leaves nothing a costly one could gain significantly (a wiener case: 4.3 → 1.7 s; a Duffing case whose spring law reaches the floor: 82 → 43 s without the hysteretic template; a clean linear record of 8000 samples whose residual failed one test at the search stop's 5 %: the whole diagnosis 4.5 → 3.0 s). When only noise models pay (gain in nll) and no structural candidate reaches `min_gain` at its point estimate (a short friction record: a process-noise model absorbed the friction, a network gained 22 % without paying, and the template's dry friction in the next tier reached the floor), the best one's residual is read on the input tests alone (cross-correlation, higher-order, static nonlinearity, memory): its noise model explains the colour, tails and size, and the structural tiers have nothing to gain; the proposals so held back stay out of the next step after a noise-only step (a process-noise case 6.9 → 4.0 s, a Student-t case 6.1 → 1.6 s, the same models) |
/// | `diverged_ratio`, `diverged_nrmse` | 10, 1 | a candidate whose RMS error on the decision data exceeds 10× the current model's and the spread of the measured output there (NRMSE above 1: worse than its mean) diverged; it is left out of the report's table and the decisions line names it by what it adds (on the sweep such fits reached select NRMSE up to 1e50: a hidden-state model, play operators on the simulated output) |
/// | `verdict_noise_ratio` | 3 | "adequate" or "coloured noise" only while the residual RMS is at most this many times the white-noise level of the measured output (its finest db4 wavelet scale); above, the misfit is unexplained |
/// | `report_carry_ratio` | 1.5 | "adequate" or "coloured noise" only while the final model's residual RMS on the report block (held out, scored once, used for no decision) is at most 1.5× its RMS on the decision data; above, the verdict says the model does not carry over to the report block (and names an input that leaves the fit record's range there) and the misfit is unexplained. A verdict reads the decision data's residual, which a model that extrapolates can pass (a saturation case at 8000 + 4000 samples: "adequate" at 1.0× the noise level on the folds, 68× the noise floor on the validation record, whose input went 30 % beyond the training range) |
/// | `coloured_noise_ratio` | 1.5 | "coloured noise" (only whiteness rejects) only while the residual RMS is at most 1.5× that white-noise level, unless a noise model paid: a coloured residual further above it is a misfit the tests cannot place (on the sweep of session 26 the two cases called coloured noise above 1.5× the noise floor, preisach 1 and 7, were at 2.8 and 2.4× the white-noise level; every case at the floor called coloured noise without a noise model was within 1.41×) |
#[derive(Debug, Clone, PartialEq)]
pub struct DecisionPolicy {
    /// Smallest relative NRMSE gain on the select block that counts.
    pub min_gain: f64,
    /// Smallest select-block gain of a `dynamics` candidate that turns a
    /// rejecting input cross-correlation test into a passing one.
    pub evidenced_dynamics_gain: f64,
    /// Under cross-validation forced by an unrepresentative select block:
    /// the fall of Schwarz's criterion on the whole training record that
    /// lets an order increase of a plain linear model pay when its folds
    /// cannot agree.
    pub information_order_margin: f64,
    /// Smallest nll gain per sample (nats) that counts for `noise`.
    pub min_nll_gain: f64,
    /// Bootstrap replicates.
    pub bootstrap: usize,
    /// Seed of the bootstrap.
    pub seed: u64,
    /// Bootstrap block length divisor: `n / block_divisor`.
    pub block_divisor: usize,
    /// Fewest blocks a bootstrap resamples (caps the block length raised
    /// to the residuals' dependence range).
    pub block_count_min: usize,
    /// Shortest bootstrap block.
    pub block_min: usize,
    /// Longest bootstrap block.
    pub block_max: usize,
    /// Orders tried by `--order auto`.
    pub auto_orders: std::ops::RangeInclusive<usize>,
    /// Relative tolerance of the parsimonious order choice.
    pub auto_order_tolerance: f64,
    /// Jarque–Bera p-value below which the residual is non-Gaussian.
    pub heavy_tail_p: f64,
    /// Excess kurtosis above which a non-Gaussian residual is heavy-tailed.
    pub heavy_tail_kurtosis: f64,
    /// Most relative NRMSE loss a noise model may cause.
    pub noise_nrmse_tolerance: f64,
    /// Replicates of the tie-break comparison.
    pub tie_bootstrap: usize,
    /// Seed of the tie-break comparison.
    pub tie_seed: u64,
    /// p-value below which residual evidence counts as unexplained.
    pub unexplained_p: f64,
    /// Memory-test p-value below which an overlapping hysteresis candidate
    /// is preferred to a plain order increase.
    pub memory_priority_p: f64,
    /// Most fit samples of the hidden-state model.
    pub hidden_state_fit_samples: usize,
    /// Leading fit samples of the blind mechanical template and its physics
    /// extensions when they represent the fit block.
    pub template_fit_samples: usize,
    /// Most fit samples of the blind mechanical template when the leading
    /// ones do not represent the fit block.
    pub template_fit_max: usize,
    /// Most fit samples of the polynomial, block-oriented and Preisach-column
    /// candidates.
    pub nonlinear_fit_samples: usize,
    /// Most fit samples of the tree and Wiener–Hammerstein networks.
    pub expensive_fit_samples: usize,
    /// Longest init window of an evaluated record (not scored).
    pub init_window_max: usize,
    /// Shortest init window.
    pub init_window_min: usize,
    /// Init window = shortest evaluated block / this (clamped).
    pub init_window_divisor: usize,
    /// Fewest samples of the select and report blocks.
    pub min_block: usize,
    /// Fewest samples of the fit block.
    pub min_fit: usize,
    /// Highest linear order proposed.
    pub max_order: usize,
    /// Longest input delay scanned.
    pub max_delay: usize,
    /// Delays scanned up to fit samples / this.
    pub max_delay_divisor: usize,
    /// Parsimony tolerance of the delay choice.
    pub delay_tolerance: f64,
    /// Smallest relative decision-NRMSE gain of a feedthrough behind the
    /// dead time.
    pub feedthrough_gain: f64,
    /// Most fit samples of the ARX structure scan.
    pub structure_scan_samples: usize,
    /// Most fit samples of the output-error delay scan.
    pub delay_scan_samples: usize,
    /// Distance of a real ARX pole from 1 that suggests an integrator.
    pub integrator_pole: f64,
    /// Smallest relative decision-NRMSE gain of the increments model.
    pub integrator_gain: f64,
    /// An ARX pole at or beyond 1 is an integrator whatever the linear
    /// fits' comparison says.
    pub integrator_beyond_unit: bool,
    /// Models of an integrator's increments are trained for the error of
    /// the summed output, not of the increments.
    pub integrated_criterion: bool,
    /// Correlation at which a window of the select block's input counts as
    /// a repeat of the fit block's (a note on the decisions line).
    pub repeat_correlation: f64,
    /// On a repeated excitation, the largest ratio of a chosen step's
    /// disagreement with the current model on shifted inputs to that on
    /// the training input.
    pub repeat_shift_ratio: f64,
    /// Fewest select samples for the bootstrap (else cross-validation).
    pub bootstrap_min_samples: usize,
    /// Level/pace ratio of the select to the fit block beyond which
    /// decisions use cross-validation.
    pub block_shift_ratio: f64,
    /// Share of select samples outside the fit block's range beyond which
    /// decisions use cross-validation.
    pub block_shift_outside: f64,
    /// Under cross-validation of one short training record without a
    /// validation record, the folds span the report block too …
    pub cv_whole_short_record: bool,
    /// … when the record has at least this many samples.
    pub cv_whole_min_samples: usize,
    /// Folds of the blocked cross-validation.
    pub cv_folds: usize,
    /// Smallest in-sample RMSE gain of a candidate's whole-record refit
    /// under cross-validation.
    pub cv_refit_gain: f64,
    /// Under cross-validation a `dynamics` candidate's whole-record refit
    /// must realise the gain it needs (`min_gain`, or the evidenced
    /// dynamics gain), not only `cv_refit_gain`.
    pub cv_dynamics_realised: bool,
    /// Share of the folds a paying candidate must win.
    pub cv_fold_wins: f64,
    /// Widening of a fold fit's signal range that its scored samples must
    /// lie in (fraction of the range).
    pub cv_cover_pad: f64,
    /// Least covered share of a fold below which it is scored whole.
    pub cv_cover_min: f64,
    /// Training samples from which the structure is searched on a subsample.
    pub long_record: usize,
    /// Training samples of that subsample.
    pub search_samples: usize,
    /// Seconds of search after which no new step starts.
    pub search_budget_s: f64,
    /// LM iterations of the refit on the whole record.
    pub refit_iterations: usize,
    /// Overall level of the final residual tests.
    pub verdict_level: f64,
    /// Largest select-block gain of a structural candidate that still
    /// lets the process-noise candidate be chosen.
    pub process_noise_rival_gain: f64,
    /// Most fit samples of the particle fit of the process-noise model.
    pub process_noise_smc_samples: usize,
    /// Particles of that fit.
    pub process_noise_particles: usize,
    /// PMMH iterations of that fit.
    pub process_noise_iterations: usize,
    /// Particles of the filter scoring a non-Gaussian process-noise model.
    pub process_noise_filter_particles: usize,
    /// Horizon of the k-step prediction RMSE in the report.
    pub prediction_horizon: usize,
    /// Largest residual RMS, in units of the output's white-noise level,
    /// that "adequate" or "coloured noise" may leave.
    pub verdict_noise_ratio: f64,
    /// Largest residual RMS, in units of the output's white-noise level,
    /// that "coloured noise" (only whiteness rejects) may leave, unless a
    /// noise model paid.
    pub coloured_noise_ratio: f64,
    /// Largest ratio of the final model's residual RMS on the report block
    /// to its RMS on the decision data that "adequate" or "coloured noise"
    /// may leave.
    pub report_carry_ratio: f64,
    /// Search no extension while the current model's residuals pass the
    /// verdict's tests.
    pub stop_when_adequate: bool,
    /// Level of each residual test (uncorrected) below which the search
    /// goes on.
    pub search_stop_level: f64,
    /// After a step that changed only the noise model, propose again the
    /// candidates that did not pay at that step (`false`: only those that
    /// paid, and new ones).
    pub retry_after_noise_step: bool,
    /// After a step that only added capacity to a named cause, propose
    /// again the extensions whose every candidate lost decisively at that
    /// step (`false`: not).
    pub retry_after_refinement: bool,
    /// A new nonlinearity or hysteresis cause must also pay against the
    /// best paying higher linear order (`false`: the largest gain wins).
    pub linear_before_nonlinear: bool,
    /// See the table: the in-sample screen of cross-validated candidates.
    pub cv_in_sample_screen: bool,
    /// See the table: the in-sample screen among the delays of one
    /// structure (0: off).
    pub rival_screen_ratio: f64,
    /// See the table: the in-sample screen against the step's best
    /// cross-validated error (0: off).
    pub cv_bound_ratio: f64,
    /// See the table: the RMSE gain the template's extension fits must show
    /// after a few iterations (0: never stop early).
    pub futile_gain: f64,
    /// Fit the costly candidates only when no cheap one that pays leaves
    /// a quiet residual.
    pub screen_costly: bool,
    /// Level of the tests of that quiet residual (Bonferroni over the
    /// verdict's tests when `screen_bonferroni`, else each test).
    pub screen_level: f64,
    /// Whether `screen_level` is Bonferroni-corrected over the verdict's
    /// tests (`false`: each test at `screen_level`).
    pub screen_bonferroni: bool,
    /// Largest residual RMS of that quiet residual, in units of the
    /// output's white-noise level.
    pub screen_noise_ratio: f64,
    /// A candidate whose decision-data RMS error exceeds this many times
    /// the current model's (and `diverged_nrmse`) diverged.
    pub diverged_ratio: f64,
    /// Smallest decision-data NRMSE of a diverged candidate.
    pub diverged_nrmse: f64,
    /// Refit the chosen chain on the whole training record (fit and
    /// select blocks) for the final model.
    pub refit_on_training: bool,
    /// For the model a user saves from one training file without a
    /// validation record: refit the chosen chain on all of the record,
    /// its report block included.
    pub refit_on_all_samples: bool,
}

impl Default for DecisionPolicy {
    fn default() -> Self {
        Self {
            min_gain: 0.05,
            evidenced_dynamics_gain: 0.01,
            information_order_margin: 10.0,
            min_nll_gain: 0.02,
            bootstrap: 400,
            seed: 1,
            block_divisor: 40,
            block_count_min: 8,
            block_min: 25,
            block_max: 200,
            auto_orders: 1..=6,
            auto_order_tolerance: 1.02,
            heavy_tail_p: 1e-3,
            heavy_tail_kurtosis: 0.5,
            noise_nrmse_tolerance: 1.02,
            tie_bootstrap: 50,
            tie_seed: 0,
            unexplained_p: 1e-3,
            memory_priority_p: 0.01,
            hidden_state_fit_samples: 4000,
            template_fit_samples: 4000,
            template_fit_max: 20_000,
            nonlinear_fit_samples: 20_000,
            expensive_fit_samples: 8000,
            init_window_max: 50,
            init_window_min: 10,
            init_window_divisor: 8,
            min_block: 40,
            min_fit: 60,
            max_order: 30,
            max_delay: 20,
            max_delay_divisor: 6,
            delay_tolerance: 1.01,
            feedthrough_gain: 0.1,
            structure_scan_samples: 50_000,
            delay_scan_samples: 4000,
            integrator_pole: 0.02,
            integrator_gain: 0.05,
            integrator_beyond_unit: true,
            integrated_criterion: true,
            repeat_correlation: 0.99,
            repeat_shift_ratio: 3.0,
            bootstrap_min_samples: 300,
            block_shift_ratio: 1.5,
            block_shift_outside: 0.05,
            cv_folds: 4,
            cv_refit_gain: 0.01,
            cv_dynamics_realised: true,
            cv_whole_short_record: true,
            cv_whole_min_samples: 800,
            cv_fold_wins: 0.5,
            cv_cover_pad: 0.1,
            cv_cover_min: 0.2,
            long_record: 100_000,
            search_samples: 20_000,
            search_budget_s: 300.0,
            refit_iterations: 10,
            verdict_level: 0.01,
            process_noise_rival_gain: 0.05,
            process_noise_smc_samples: 2000,
            process_noise_particles: 100,
            process_noise_iterations: 100,
            process_noise_filter_particles: 1000,
            prediction_horizon: 10,
            verdict_noise_ratio: 3.0,
            coloured_noise_ratio: 1.5,
            report_carry_ratio: 1.5,
            stop_when_adequate: true,
            search_stop_level: 0.05,
            retry_after_noise_step: false,
            retry_after_refinement: false,
            linear_before_nonlinear: true,
            cv_in_sample_screen: true,
            rival_screen_ratio: 1.0,
            cv_bound_ratio: 1.5,
            futile_gain: 0.025,
            screen_costly: true,
            screen_level: 0.01,
            screen_bonferroni: true,
            screen_noise_ratio: 1.1,
            diverged_ratio: 10.0,
            diverged_nrmse: 1.0,
            refit_on_training: true,
            refit_on_all_samples: true,
        }
    }
}

impl DecisionPolicy {
    /// Validate.
    pub fn check(&self) -> Result<(), DiagnoseError> {
        let bad = |m: &str| {
            Err(DiagnoseError::InvalidArgument(format!(
                "decision policy: {m}"
            )))
        };
        if !(0.0..1.0).contains(&self.min_gain)
            || !(0.0..1.0).contains(&self.evidenced_dynamics_gain)
            || !(0.0..1.0).contains(&self.futile_gain)
            || self.bootstrap < 50
        {
            return bad(
                "min_gain, evidenced_dynamics_gain and futile_gain in [0,1), bootstrap >= 50",
            );
        }
        if self.information_order_margin.is_nan() || self.information_order_margin < 0.0 {
            return bad("information_order_margin >= 0 (not NaN)");
        }
        if !(self.min_nll_gain >= 0.0 && self.min_nll_gain.is_finite()) {
            return bad("min_nll_gain >= 0");
        }
        if !(self.repeat_correlation > 0.0 && self.repeat_correlation <= 1.0) {
            return bad("repeat_correlation in (0, 1]");
        }
        if !(self.rival_screen_ratio == 0.0
            || (self.rival_screen_ratio >= 1.0 && self.rival_screen_ratio.is_finite()))
        {
            return bad("rival_screen_ratio 0 (off) or in [1, inf)");
        }
        if !(self.cv_bound_ratio == 0.0
            || (self.cv_bound_ratio >= 1.0 && self.cv_bound_ratio.is_finite()))
        {
            return bad("cv_bound_ratio 0 (off) or in [1, inf)");
        }
        if self.repeat_shift_ratio.is_nan() || self.repeat_shift_ratio < 1.0 {
            return bad("repeat_shift_ratio >= 1 (infinity: no check)");
        }
        if self.block_divisor == 0
            || self.block_min == 0
            || self.block_min > self.block_max
            || self.block_count_min == 0
        {
            return bad("block_divisor >= 1, 1 <= block_min <= block_max, block_count_min >= 1");
        }
        if self.template_fit_samples == 0 || self.template_fit_max < self.template_fit_samples {
            return bad("1 <= template_fit_samples <= template_fit_max");
        }
        if self.auto_orders.is_empty() || *self.auto_orders.start() == 0 {
            return bad("auto_orders must be a non-empty range of orders >= 1");
        }
        if self.auto_order_tolerance < 1.0
            || self.noise_nrmse_tolerance < 1.0
            || self.verdict_noise_ratio.is_nan()
            || self.verdict_noise_ratio < 1.0
            || self.coloured_noise_ratio.is_nan()
            || self.coloured_noise_ratio < 1.0
            || self.report_carry_ratio.is_nan()
            || self.report_carry_ratio < 1.0
            || self.screen_noise_ratio.is_nan()
            || self.screen_noise_ratio < 1.0
            || self.diverged_ratio.is_nan()
            || self.diverged_ratio < 1.0
            || self.diverged_nrmse.is_nan()
            || self.diverged_nrmse < 0.0
        {
            return bad("tolerances, verdict_noise_ratio, coloured_noise_ratio, report_carry_ratio, screen_noise_ratio and diverged_ratio >= 1, diverged_nrmse >= 0");
        }
        let p_ok = |p: f64| p > 0.0 && p < 1.0;
        if !p_ok(self.heavy_tail_p)
            || !p_ok(self.unexplained_p)
            || !p_ok(self.verdict_level)
            || !p_ok(self.search_stop_level)
            || !p_ok(self.screen_level)
            || !p_ok(self.memory_priority_p)
        {
            return bad("p-value levels in (0,1)");
        }
        if self.tie_bootstrap < 10 || self.min_block < 10 || self.min_fit < 10 {
            return bad("tie_bootstrap, min_block and min_fit >= 10");
        }
        if self.nonlinear_fit_samples < 100 || self.expensive_fit_samples < 100 {
            return bad("nonlinear_fit_samples and expensive_fit_samples >= 100");
        }
        if self.max_order == 0 || self.max_order > gb_lmn::MAX_IO_ORDER {
            return bad("max_order in 1..=30");
        }
        if self.init_window_min == 0
            || self.init_window_min > self.init_window_max
            || self.init_window_divisor == 0
        {
            return bad("1 <= init_window_min <= init_window_max, init_window_divisor >= 1");
        }
        if self.max_delay > 64 || self.max_delay_divisor == 0 || self.delay_tolerance < 1.0 {
            return bad("max_delay <= 64, max_delay_divisor >= 1, delay_tolerance >= 1");
        }
        let open_unit = |x: f64| x > 0.0 && x < 1.0;
        if !open_unit(self.integrator_pole) || !(0.0..1.0).contains(&self.integrator_gain) {
            return bad("integrator_pole in (0,1), integrator_gain in [0,1)");
        }
        if !(0.0..1.0).contains(&self.feedthrough_gain) {
            return bad("feedthrough_gain in [0,1)");
        }
        if self.block_shift_ratio.is_nan()
            || self.block_shift_ratio <= 1.0
            || !(0.0..=1.0).contains(&self.block_shift_outside)
        {
            return bad("block_shift_ratio > 1, block_shift_outside in [0,1]");
        }
        if !(2..=20).contains(&self.cv_folds) || self.structure_scan_samples < 100 {
            return bad("cv_folds in 2..=20, structure_scan_samples >= 100");
        }
        let cv_ok = (0.0..1.0).contains(&self.cv_refit_gain)
            && (0.0..f64::INFINITY).contains(&self.cv_cover_pad)
            && (0.0..=1.0).contains(&self.cv_cover_min)
            && (0.0..=1.0).contains(&self.cv_fold_wins);
        if !cv_ok {
            return bad(
                "cv_refit_gain in [0,1), cv_cover_pad >= 0, cv_cover_min and cv_fold_wins in [0,1]",
            );
        }
        if self.search_samples < 1000
            || self.long_record < self.search_samples
            || self.search_budget_s.is_nan()
            || self.search_budget_s <= 0.0
        {
            return bad(
                "search_samples >= 1000, long_record >= search_samples, search_budget_s > 0",
            );
        }
        if !(0.0..1.0).contains(&self.process_noise_rival_gain) {
            return bad("process_noise_rival_gain in [0,1)");
        }
        if self.process_noise_smc_samples < 100
            || self.process_noise_particles == 0
            || self.process_noise_iterations < 8
            || self.process_noise_filter_particles == 0
            || self.prediction_horizon == 0
        {
            return bad("process_noise_smc_samples >= 100, process_noise_iterations >= 8, particles and prediction_horizon >= 1");
        }
        Ok(())
    }

    /// Init window of evaluated records whose shortest block has `block`
    /// samples.
    pub fn init_window_for(&self, block: usize) -> usize {
        (block / self.init_window_divisor).clamp(self.init_window_min, self.init_window_max)
    }

    /// Longest input delay scanned for a fit block of `fit` samples.
    pub fn delay_bound(&self, fit: usize) -> usize {
        self.max_delay.min(fit / self.max_delay_divisor)
    }

    /// Bootstrap block length for `n` samples.
    pub fn block(&self, n: usize) -> usize {
        (n / self.block_divisor).clamp(self.block_min, self.block_max)
    }

    /// Bootstrap block length for decisions on residuals `e` (the current
    /// model's): `max(block(n), m̂(e))`, capped at `n / block_count_min`
    /// (and never below `block(n)`).
    pub fn block_for(&self, e: &[f64]) -> usize {
        let n = e.len();
        let base = self.block(n);
        let cap = (n / self.block_count_min.max(1)).max(base);
        crate::stats::dependence_range(e).clamp(base, cap)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_bad_values_are_refused() {
        let p = DecisionPolicy::default();
        assert!(p.check().is_ok());
        assert_eq!(p.block(8000), 200);
        assert_eq!(p.block(2000), 50);
        assert_eq!(p.block(100), 25);
        assert_eq!(p.init_window_for(4000), 50);
        assert_eq!(p.init_window_for(100), 12);
        assert_eq!(p.init_window_for(40), 10);
        assert_eq!(p.delay_bound(300), 20);
        assert_eq!(p.delay_bound(90), 15);
        for bad in [
            DecisionPolicy {
                min_gain: 1.5,
                ..p.clone()
            },
            DecisionPolicy {
                bootstrap: 10,
                ..p.clone()
            },
            DecisionPolicy {
                auto_orders: 0..=3,
                ..p.clone()
            },
            DecisionPolicy {
                heavy_tail_p: 0.0,
                ..p.clone()
            },
            DecisionPolicy {
                memory_priority_p: 1.0,
                ..p.clone()
            },
            DecisionPolicy {
                block_min: 300,
                ..p.clone()
            },
            DecisionPolicy {
                init_window_min: 60,
                ..p.clone()
            },
            DecisionPolicy {
                cv_folds: 1,
                ..p.clone()
            },
            DecisionPolicy {
                cv_refit_gain: 1.0,
                ..p.clone()
            },
            DecisionPolicy {
                max_order: 31,
                ..p.clone()
            },
            DecisionPolicy {
                feedthrough_gain: 1.0,
                ..p.clone()
            },
            DecisionPolicy {
                block_shift_ratio: 1.0,
                ..p.clone()
            },
            DecisionPolicy {
                block_shift_ratio: f64::NAN,
                ..p.clone()
            },
            DecisionPolicy {
                block_shift_outside: 1.5,
                ..p.clone()
            },
        ] {
            assert!(bad.check().is_err(), "{bad:?}");
        }
    }
}
