//! Candidate extensions: each a type that says which cause it tests, when it
//! applies to the current model, how it fits the extended model, and what
//! evidence it shows. The diagnosis loops over [`EXTENSIONS`].
//!
//! Adding an extension (or a cause, with its variant in [`Cause`]) is one
//! file in `extensions/` and one line in [`EXTENSIONS`].
use crate::evaluate::{Evaluated, Lineage, Residuals};
use crate::extensions::{
    Backlash, Capacity, FeedbackMap, Hammerstein, HiddenState, HiddenStateDetail, LinearOrder,
    Lolimot, MechanicalHysteresis, MechanicalNonlinearity, OperatorPoly, PhysicsHysteresis,
    PhysicsInputDelay, PhysicsTerms, PolyNoe, PolySimpler, PreisachColumns, ProcessNoise,
    StateNetwork, StudentTNoise, TreeLmn, Wiener, WienerHammerstein,
};
use crate::plan::Chosen;
use crate::{Cause, DecisionPolicy, DiagnoseData, DiagnoseError, DiagnoseOptions, Evidence};
use gb_core::{FittedModel, ModelView, Observer, Record};

/// What a candidate does for the diagnosis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Tests a cause (named when it pays).
    NewCause,
    /// More capacity for a cause already named: a new cause must beat it.
    Refinement,
    /// The last resort when a named cause stays unexplained and no new cause
    /// pays: tried at most once, must beat the simple choice too.
    Escalation,
    /// A model with fewer parameters for a cause already named: it replaces
    /// the current model when no new cause or refinement is chosen, the
    /// decision data cannot tell the two apart (gain above `−min_gain`,
    /// 95 % interval reaching 0) and its extension admits it.
    Simplification,
}

/// How a candidate's gain is measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GainMetric {
    /// Relative NRMSE reduction of the free-run simulation.
    Nrmse,
    /// Reduction of the negative log-likelihood per sample (nats).
    Nll,
}

impl GainMetric {
    /// Name in reports.
    pub fn name(self) -> &'static str {
        match self {
            GainMetric::Nrmse => "nrmse",
            GainMetric::Nll => "nll",
        }
    }
}

/// One candidate an extension proposes for the current model.
#[derive(Debug, Clone)]
pub struct Proposal {
    /// The cause it tests (an escalation tests the cause it escalates).
    pub cause: Cause,
    /// The structure to fit.
    pub lineage: Lineage,
    /// What the extension does, in words.
    pub text: String,
}

/// What an extension sees of the diagnosis.
#[derive(Clone, Copy)]
pub struct Context<'a> {
    /// The data.
    pub data: &'a DiagnoseData,
    /// The fit block. With several training records: the longest fit part,
    /// for the model classes identified on one record (block-oriented,
    /// polynomial NOE, Wiener–Hammerstein, state-space and physics models);
    /// the select decisions use all records.
    pub fit: &'a Record,
    /// The fit parts of all training records, one experiment each (`[fit]`
    /// with one record): the input–output models (linear, with hysteresis
    /// columns or Student-t noise, and LOLIMOT networks: the `order`,
    /// `lolimot`, `capacity`, Preisach and Student-t extensions) are fitted
    /// on all of them.
    pub fits: &'a [Record],
    /// The current model.
    pub current: &'a Evaluated,
    /// Causes named so far, in order.
    pub causes: &'a [Cause],
    /// Residual evidence of the current model (select block).
    pub evidence: &'a Evidence,
    /// The options (policy and fit settings).
    pub options: &'a DiagnoseOptions,
    /// Free-run simulation of the current model on the fit block.
    pub simulated_fit: Option<&'a [f64]>,
    /// With several training records: free-run simulations of the current
    /// model on every record of `fits`, each from its own start.
    pub simulated_fits: Option<&'a [Vec<f64>]>,
    /// Progress of long fits.
    pub observer: &'a dyn Observer,
    /// How models are fitted and judged.
    pub(crate) plan: &'a crate::plan::Plan,
    /// Free-run simulations of the current model's fold refits on their fit
    /// records (cross-validation).
    pub(crate) fold_sims: &'a [Option<Vec<f64>>],
    /// Free-run simulations of the fold refits on every record of their
    /// `fits` (several records).
    pub(crate) fold_sims_all: &'a [Option<Vec<Vec<f64>>>],
    /// In a fold's fit (cross-validation): the start a multi-start fit of
    /// the same candidate chose on the whole fit block
    /// ([`Extension::fit_choosing`]).
    pub(crate) start_choice: Option<usize>,
    /// In a fold's fit (cross-validation): the same candidate fitted on the
    /// whole fit block, a start for the fits whose own start leads astray
    /// on a shorter record ([`Extension::fit_choosing`]); in the refit on
    /// the whole training record (`refit.rs`): the step's fit-block model.
    pub(crate) whole_fit: Option<&'a FittedModel>,
    /// In the whole fit of a delay rival ([`Extension::delay_rivals_key`]:
    /// the same structure at another input delay, under cross-validation)
    /// of an extension that [`starts_from_rival`](Extension::starts_from_rival):
    /// the fit at the current delay and the start it chose, which the
    /// rival's search starts from (a backlash's half-width) instead of
    /// searching the whole grid again.
    pub(crate) rival_of: Option<(&'a FittedModel, Option<usize>)>,
    /// The linear mechanical templates fitted so far in this step, shared
    /// by its mechanical candidates (`None`: not shared).
    pub(crate) templates: Option<&'a crate::extensions::TemplateCache>,
    /// In a step's fit on the whole fit block: the RMSE gain a costly fit
    /// (the mechanical template's extensions) must show after a few
    /// iterations to be fitted on (the policy's `futile_gain`); `None` in
    /// a fold's fit and in a refit, which are fitted in full.
    pub(crate) futile_gain: Option<f64>,
}

impl<'a> Context<'a> {
    /// The context of a fit for fold `t` (`None`: this context): the fold's
    /// fit record and the current structure refitted on it.
    pub(crate) fn at(&self, t: Option<usize>) -> Context<'a> {
        match t {
            Some(k) => self.fold(k, None, None),
            None => *self,
        }
    }

    /// [`Context::at`] for fold `k`, with the candidate's fit on the whole
    /// fit block and the start it chose, when it had several.
    pub(crate) fn at_fold<'b>(&self, t: Option<(usize, &'b Chosen)>) -> Context<'b>
    where
        'a: 'b,
    {
        match t {
            Some((k, (whole, start))) => self.fold(k, *start, Some(whole)),
            None => *self,
        }
    }

    /// The context of fold `k` (this context when there is no such fold).
    fn fold<'b>(
        &self,
        k: usize,
        start_choice: Option<usize>,
        whole_fit: Option<&'b FittedModel>,
    ) -> Context<'b>
    where
        'a: 'b,
    {
        if k >= self.current.folds.len() {
            return *self;
        }
        Context {
            start_choice,
            whole_fit,
            rival_of: None,
            futile_gain: None,
            fit: self.plan.fit_of(Some(k)),
            fits: self.plan.fits_of(Some(k)),
            current: &self.current.folds[k],
            simulated_fit: self.fold_sims.get(k).and_then(|s| s.as_deref()),
            simulated_fits: self.fold_sims_all.get(k).and_then(|s| s.as_deref()),
            ..*self
        }
    }
}

impl Context<'_> {
    /// The decision policy.
    pub fn policy(&self) -> &DecisionPolicy {
        &self.options.policy
    }
    /// Whether `c` has been named.
    pub fn named(&self, c: Cause) -> bool {
        self.causes.contains(&c)
    }
}

/// A candidate extension of the current model.
pub trait Extension: Sync {
    /// Short name (unique).
    fn name(&self) -> &'static str;
    /// The cause it tests.
    fn cause(&self) -> Cause;
    /// Its role.
    fn role(&self) -> Role {
        Role::NewCause
    }
    /// How its gain is measured.
    fn metric(&self) -> GainMetric {
        GainMetric::Nrmse
    }
    /// Its tier in the screening of a step (the policy's `screen_costly`):
    /// 0 for the cheap candidates; the costly ones, whose fits cost seconds
    /// (continuous-time templates, networks between filters, hidden
    /// states), 1 or 2 — a tier is fitted only when no candidate of the
    /// tiers before that pays leaves a quiet residual.
    fn screen_tier(&self) -> u8 {
        0
    }
    /// Work its proposals of a step share, done once before the step's
    /// tier fits them side by side (the decisions never depend on it): a
    /// shared fit that the first proposal would otherwise make while the
    /// others wait for it on their threads, its own parallel paths left on
    /// one core. Nothing by default.
    fn prepare(&self, _ctx: &Context) {}
    /// A rough class of what one candidate's fit costs, for scheduling a
    /// step's fits longest first (the decisions never depend on it): 0 a
    /// few linear fits, 1 (the default) one nonlinear fit, 2 several, 3 a
    /// search over structures or starts, each a nonlinear fit.
    fn fit_cost(&self) -> u8 {
        1
    }
    /// Tried at most once per diagnosis.
    fn once(&self) -> bool {
        false
    }
    /// The candidates for the current model (none when it does not apply).
    fn propose(&self, ctx: &Context) -> Vec<Proposal>;
    /// Fit a proposal on the fit block. An extension implements this or
    /// [`fit_choosing`](Self::fit_choosing) (each defaults to the other).
    /// Default: `fit_choosing`'s model.
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        self.fit_choosing(p, ctx).map(|(m, _)| m)
    }
    /// [`fit`](Self::fit), saying which of several starts won (a
    /// multi-start fit): under cross-validation the folds then refit only
    /// that start ([`Context::start_choice`]). Default: `fit`, no choice.
    fn fit_choosing(
        &self,
        p: &Proposal,
        ctx: &Context,
    ) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
        self.fit(p, ctx).map(|m| (m, None))
    }
    /// An acceptance condition beyond a significant gain.
    fn admits(&self, ctx: &Context, candidate: &Evaluated) -> bool {
        let _ = (ctx, candidate);
        true
    }
    /// Re-score a fitted candidate whose likelihood is not its noise
    /// model's density of the simulation residual (a model with process
    /// noise: the filter's predictive densities, `Residuals::nll`), and say
    /// which noise it found (`Evaluated::finding`). Default: nothing.
    fn rescore(&self, ctx: &Context, candidate: &mut Evaluated) -> Result<(), DiagnoseError> {
        let _ = (ctx, candidate);
        Ok(())
    }
    /// Chosen only when no structural candidate of the iteration gains the
    /// policy's `process_noise_rival_gain` on the select block, paying or
    /// not (a noise model must explain the colour better than any
    /// deterministic extension). Default: no.
    fn yields_to_structure(&self) -> bool {
        false
    }
    /// The evidence sentence of its row.
    fn evidence(&self, p: &Proposal, ctx: &Context) -> String;
    /// The extension text of its row, once fitted.
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        let _ = fitted;
        p.text.clone()
    }
    /// Its structure without the input delay: proposals of one extension
    /// with the same key are the same structure at different dead times,
    /// rivals of the in-sample screen under cross-validation (policy
    /// `rival_screen_ratio`), the first of them at the current model's
    /// delay. Default: none.
    fn delay_rivals_key(&self, p: &Proposal) -> Option<String> {
        let _ = p;
        None
    }
    /// Whether its delay rivals (the proposals after the first of a
    /// [`delay_rivals_key`](Self::delay_rivals_key)) are fitted once the
    /// first is, starting from its fit ([`Context::rival_of`]). Default:
    /// no, every proposal is fitted from its own start at once.
    fn starts_from_rival(&self) -> bool {
        false
    }
    /// The input a candidate makes nonlinear alone (reports say which input
    /// the nonlinearity lives on).
    fn input(&self, p: &Proposal, ctx: &Context) -> Option<String> {
        let _ = (p, ctx);
        None
    }
    /// The evidence plot of its cause from the residuals before and after
    /// (report block), for [`Role::NewCause`] extensions.
    fn evidence_view(
        &self,
        before: &Residuals,
        after: &Residuals,
        output: &str,
    ) -> Option<ModelView> {
        let _ = (before, after, output);
        None
    }
}

/// Every extension, in the order candidates are fitted and listed.
pub static EXTENSIONS: &[&dyn Extension] = &[
    &Capacity,
    &Lolimot,
    &TreeLmn,
    &PolyNoe,
    &Hammerstein,
    &Wiener,
    &WienerHammerstein,
    &StateNetwork,
    &PreisachColumns,
    &Backlash,
    &MechanicalHysteresis,
    &MechanicalNonlinearity,
    &LinearOrder,
    &StudentTNoise,
    &ProcessNoise,
    &PhysicsTerms,
    &PhysicsInputDelay,
    &PhysicsHysteresis,
    &HiddenState,
    &HiddenStateDetail,
    &FeedbackMap,
    // last: its place in the list sets the bootstrap seeds of the others
    &PolySimpler,
    // after the seeds of the others
    &OperatorPoly,
];

/// The extension that introduces `cause` as a new cause (for its evidence
/// text and plot).
pub fn introducing(cause: Cause) -> Option<&'static dyn Extension> {
    EXTENSIONS
        .iter()
        .copied()
        .find(|e| e.cause() == cause && e.role() == Role::NewCause)
}

/// The fitted model of an input–output network, named like `data`.
pub(crate) fn io_model(
    net: gb_lmn::LocalModelNetwork,
    data: &Record,
) -> Result<FittedModel, DiagnoseError> {
    let noise = net.noise.clone();
    Ok(FittedModel::new(
        data.input_names.clone(),
        vec![data.output_name.clone()],
        Box::new(net),
        noise,
    )?)
}
