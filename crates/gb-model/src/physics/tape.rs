//! Expressions compiled to a tape: exmex parses, we trace.
//!
//! exmex (`FlatEx::parse`) parses every expression — its grammar, operators,
//! precedence and constant folding are exmex's. The tape is recorded by
//! evaluating exmex's parsed expression **once** with a recording number
//! type ([`Rec`]) whose operators append a node instead of computing
//! (tracing, as JAX or an operator-overloading AD tool records a program).
//! The operator table ([`TraceOps`]) mirrors exmex's `FloatOpsFactory`:
//! the same names and priorities, so the parse is the same as for `f64`
//! (tested against `FlatEx::<f64>::eval` on every operator).
//!
//! Why a tape of our own: exmex evaluates the mass–spring–damper
//! acceleration `(F - c*v - k*x)/m` in about 135 ns (`benches/physics.rs`,
//! `exmex_eval`); RK4 needs four right-hand sides per sub-step, which caps
//! a simulation below 1 M samples/s. The tape evaluates the same expression
//! in a few ns, shares common sub-expressions between the equations
//! (hash-consing), evaluates parameter-only sub-expressions (`c/m`, `k/m`)
//! once per simulation and input-only ones (`F/m`) once per sample instead
//! of once per stage, fuses a product into the sum that reads it
//! (`p + a·b`: one dispatch, the sum reading the previous result from a
//! register; bit-identical, no FMA), and gives exact
//! derivatives by forward mode: each node's partial derivatives
//! `(∂out/∂a, ∂out/∂b)` are closed-form (chain rule), so one pass gives
//! the directional derivatives `f_x·s + f_θ·e` of all outputs along any
//! number of directions (lanes). exmex's own symbolic `partial` has no rule
//! for `abs`, `signum`, `min` and `max` (it returns "operator abs needed for
//! outer partial derivative"; nor for `cbrt`), which the Bouc–Wen law
//! `|v|`, `|z|` needs;
//! it is used in the tests as an independent check of the tape's
//! derivatives for every operator it can differentiate.
use exmex::prelude::*;
use exmex::{BinOp, MakeOperators, Operator};
use std::cell::RefCell;
use std::collections::HashMap;
use std::str::FromStr;

/// A tape operation. Binary operations read slots `a` and `b`; unary ones
/// read `a`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[allow(missing_docs)]
pub(crate) enum Op {
    Add,
    Sub,
    Mul,
    Div,
    Neg,
    /// `a^n` for a constant integer exponent.
    Powi(i32),
    /// `a^b` for a constant exponent `b`.
    PowC,
    /// `a^b` with a variable exponent.
    Pow,
    Atan2,
    Min,
    Max,
    Abs,
    Signum,
    Sin,
    Cos,
    Tan,
    Asin,
    Acos,
    Atan,
    Sinh,
    Cosh,
    Tanh,
    Asinh,
    Acosh,
    Atanh,
    Floor,
    Round,
    Ceil,
    Trunc,
    Fract,
    Exp,
    Sqrt,
    Cbrt,
    Ln,
    Log2,
    Log10,
    /// `a·b + c` (fused from a product read once by a sum; value program only).
    MulAdd,
    /// `a·b − c` (fused, value program only).
    MulSub,
    /// `c − a·b` (fused, value program only).
    SubMul,
    /// `MulAdd` with `c` the previous node's result (kept in a register).
    MulAddPrev,
    /// `MulSub` with `c` the previous node's result.
    MulSubPrev,
    /// `SubMul` with `c` the previous node's result.
    SubMulPrev,
}

/// The value of `op` (exmex's float semantics).
#[inline(always)]
fn apply(op: Op, a: f64, b: f64) -> f64 {
    match op {
        Op::Add => a + b,
        Op::Sub => a - b,
        Op::Mul => a * b,
        Op::Div => a / b,
        Op::Neg => -a,
        Op::Powi(n) => a.powi(n),
        Op::PowC | Op::Pow => a.powf(b),
        Op::Atan2 => a.atan2(b),
        Op::Min => a.min(b),
        Op::Max => a.max(b),
        Op::Abs => a.abs(),
        Op::Signum => a.signum(),
        Op::Sin => a.sin(),
        Op::Cos => a.cos(),
        Op::Tan => a.tan(),
        Op::Asin => a.asin(),
        Op::Acos => a.acos(),
        Op::Atan => a.atan(),
        Op::Sinh => a.sinh(),
        Op::Cosh => a.cosh(),
        Op::Tanh => a.tanh(),
        Op::Asinh => a.asinh(),
        Op::Acosh => a.acosh(),
        Op::Atanh => a.atanh(),
        Op::Floor => a.floor(),
        Op::Round => a.round(),
        Op::Ceil => a.ceil(),
        Op::Trunc => a.trunc(),
        Op::Fract => a.fract(),
        Op::Exp => a.exp(),
        Op::Sqrt => a.sqrt(),
        Op::Cbrt => a.cbrt(),
        Op::Ln => a.ln(),
        Op::Log2 => a.log2(),
        Op::Log10 => a.log10(),
        Op::MulAdd | Op::MulSub | Op::SubMul | Op::MulAddPrev | Op::MulSubPrev | Op::SubMulPrev => {
            unreachable!("fused operations have three operands")
        }
    }
}

/// `(∂out/∂a, ∂out/∂b)` at `(a, b)` with `out = op(a, b)`. Non-smooth
/// operators take the one-sided convention of their subgradient:
/// `∂|a|/∂a = sign(a)` with 0 at 0, `signum`/`floor`/… have derivative 0,
/// `min`/`max` follow the chosen argument; `√a`, `∛a` and `a^b` (b < 1)
/// have derivative 0 at `a = 0` (a state resting on its bound 0, such as
/// an empty tank, keeps finite sensitivities).
#[inline(always)]
fn partials(op: Op, a: f64, b: f64, out: f64) -> (f64, f64) {
    let sign0 = |x: f64| {
        if x > 0.0 {
            1.0
        } else if x < 0.0 {
            -1.0
        } else {
            0.0
        }
    };
    match op {
        Op::Add => (1.0, 1.0),
        Op::Sub => (1.0, -1.0),
        Op::Mul => (b, a),
        Op::Div => (1.0 / b, -out / b),
        Op::Neg => (-1.0, 0.0),
        Op::Powi(n) => (n as f64 * a.powi(n - 1), 0.0),
        Op::PowC if a == 0.0 && b < 1.0 => (0.0, 0.0),
        Op::PowC => (b * a.powf(b - 1.0), 0.0),
        Op::Pow => (
            b * a.powf(b - 1.0),
            if a > 0.0 { out * a.ln() } else { 0.0 },
        ),
        Op::Atan2 => {
            let r = a * a + b * b;
            (b / r, -a / r)
        }
        Op::Min => {
            if a <= b {
                (1.0, 0.0)
            } else {
                (0.0, 1.0)
            }
        }
        Op::Max => {
            if a >= b {
                (1.0, 0.0)
            } else {
                (0.0, 1.0)
            }
        }
        Op::Abs => (sign0(a), 0.0),
        Op::Signum | Op::Floor | Op::Round | Op::Ceil | Op::Trunc => (0.0, 0.0),
        Op::Fract => (1.0, 0.0),
        Op::Sin => (a.cos(), 0.0),
        Op::Cos => (-a.sin(), 0.0),
        Op::Tan => (1.0 + out * out, 0.0),
        Op::Asin => (1.0 / (1.0 - a * a).sqrt(), 0.0),
        Op::Acos => (-1.0 / (1.0 - a * a).sqrt(), 0.0),
        Op::Atan => (1.0 / (1.0 + a * a), 0.0),
        Op::Sinh => (a.cosh(), 0.0),
        Op::Cosh => (a.sinh(), 0.0),
        Op::Tanh => (1.0 - out * out, 0.0),
        Op::Asinh => (1.0 / (a * a + 1.0).sqrt(), 0.0),
        Op::Acosh => (1.0 / (a * a - 1.0).sqrt(), 0.0),
        Op::Atanh => (1.0 / (1.0 - a * a), 0.0),
        Op::Exp => (out, 0.0),
        Op::Sqrt | Op::Cbrt if a == 0.0 => (0.0, 0.0),
        Op::Sqrt => (0.5 / out, 0.0),
        Op::Cbrt => (1.0 / (3.0 * out * out), 0.0),
        Op::Ln => (1.0 / a, 0.0),
        Op::Log2 => (1.0 / (a * std::f64::consts::LN_2), 0.0),
        Op::Log10 => (1.0 / (a * std::f64::consts::LN_10), 0.0),
        Op::MulAdd | Op::MulSub | Op::SubMul | Op::MulAddPrev | Op::MulSubPrev | Op::SubMulPrev => {
            unreachable!("fused operations have no lanes")
        }
    }
}

fn is_binary(op: Op) -> bool {
    matches!(
        op,
        Op::Add | Op::Sub | Op::Mul | Op::Div | Op::Pow | Op::PowC | Op::Atan2 | Op::Min | Op::Max
    )
}

/// The recording number: a folded constant or a traced value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Rec {
    /// A constant (folded: operations on constants compute at once).
    C(f64),
    /// The traced value of this id.
    V(u32),
}

impl Default for Rec {
    fn default() -> Self {
        Rec::C(0.0)
    }
}

impl FromStr for Rec {
    type Err = std::num::ParseFloatError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        s.parse::<f64>().map(Rec::C)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Def {
    Var(u32),
    Const(u64),
    Node(Op, u32, u32),
}

#[derive(Debug, Default)]
struct Tracer {
    defs: Vec<Def>,
    index: HashMap<Def, u32>,
}

thread_local! {
    static TRACER: RefCell<Tracer> = RefCell::new(Tracer::default());
}

fn intern(def: Def) -> u32 {
    TRACER.with(|t| {
        let mut t = t.borrow_mut();
        if let Some(&i) = t.index.get(&def) {
            return i;
        }
        let i = t.defs.len() as u32;
        t.defs.push(def);
        t.index.insert(def, i);
        i
    })
}

fn id(r: Rec) -> u32 {
    match r {
        Rec::V(i) => i,
        Rec::C(c) => intern(Def::Const(c.to_bits())),
    }
}

fn bin(op: Op, a: Rec, b: Rec) -> Rec {
    if let (Rec::C(x), Rec::C(y)) = (a, b) {
        return Rec::C(apply(op, x, y));
    }
    if op == Op::Pow {
        if let Rec::C(c) = b {
            if c == 1.0 {
                return a;
            }
            if c == 2.0 {
                let ia = id(a);
                return Rec::V(intern(Def::Node(Op::Mul, ia, ia)));
            }
            if c == 0.5 {
                return un(Op::Sqrt, a);
            }
            if c.fract() == 0.0 && c.abs() <= 16.0 {
                let ia = id(a);
                return Rec::V(intern(Def::Node(Op::Powi(c as i32), ia, ia)));
            }
            return Rec::V(intern(Def::Node(Op::PowC, id(a), id(b))));
        }
    }
    Rec::V(intern(Def::Node(op, id(a), id(b))))
}

fn un(op: Op, a: Rec) -> Rec {
    match a {
        Rec::C(x) => Rec::C(apply(op, x, 0.0)),
        Rec::V(i) => Rec::V(intern(Def::Node(op, i, i))),
    }
}

/// Run `f` with `tracer` installed as the thread's tracer.
fn with_tracer<R>(tracer: &mut Tracer, f: impl FnOnce() -> R) -> R {
    TRACER.with(|t| std::mem::swap(&mut *t.borrow_mut(), tracer));
    let r = f();
    TRACER.with(|t| std::mem::swap(&mut *t.borrow_mut(), tracer));
    r
}

/// exmex's float operators (`FloatOpsFactory`: the same names and
/// priorities) on the recording type.
#[derive(Clone, Debug)]
pub(crate) struct TraceOps;

macro_rules! unary {
    ($name:expr, $op:expr) => {
        Operator::make_unary($name, |a| un($op, a))
    };
}

macro_rules! binary {
    ($name:expr, $op:expr, $prio:expr, $comm:expr) => {
        Operator::make_bin(
            $name,
            BinOp {
                apply: |a, b| bin($op, a, b),
                prio: $prio,
                is_commutative: $comm,
            },
        )
    };
}

impl MakeOperators<Rec> for TraceOps {
    fn make<'a>() -> Vec<Operator<'a, Rec>> {
        use std::f64::consts::{E, PI, TAU};
        vec![
            binary!("^", Op::Pow, 4, false),
            binary!("*", Op::Mul, 2, true),
            binary!("/", Op::Div, 3, false),
            Operator::make_bin_unary(
                "+",
                BinOp {
                    apply: |a, b| bin(Op::Add, a, b),
                    prio: 0,
                    is_commutative: true,
                },
                |a| a,
            ),
            Operator::make_bin_unary(
                "-",
                BinOp {
                    apply: |a, b| bin(Op::Sub, a, b),
                    prio: 1,
                    is_commutative: false,
                },
                |a| un(Op::Neg, a),
            ),
            binary!("atan2", Op::Atan2, 0, false),
            binary!("min", Op::Min, 0, false),
            binary!("max", Op::Max, 0, false),
            unary!("abs", Op::Abs),
            unary!("signum", Op::Signum),
            unary!("sin", Op::Sin),
            unary!("cos", Op::Cos),
            unary!("tan", Op::Tan),
            unary!("asin", Op::Asin),
            unary!("acos", Op::Acos),
            unary!("atan", Op::Atan),
            unary!("sinh", Op::Sinh),
            unary!("cosh", Op::Cosh),
            unary!("tanh", Op::Tanh),
            unary!("asinh", Op::Asinh),
            unary!("acosh", Op::Acosh),
            unary!("atanh", Op::Atanh),
            unary!("floor", Op::Floor),
            unary!("round", Op::Round),
            unary!("ceil", Op::Ceil),
            unary!("trunc", Op::Trunc),
            unary!("fract", Op::Fract),
            unary!("exp", Op::Exp),
            unary!("sqrt", Op::Sqrt),
            unary!("cbrt", Op::Cbrt),
            unary!("ln", Op::Ln),
            unary!("log2", Op::Log2),
            unary!("log10", Op::Log10),
            unary!("log", Op::Ln),
            Operator::make_constant("PI", Rec::C(PI)),
            Operator::make_constant("π", Rec::C(PI)),
            Operator::make_constant("E", Rec::C(E)),
            Operator::make_constant("e", Rec::C(E)),
            Operator::make_constant("TAU", Rec::C(TAU)),
            Operator::make_constant("τ", Rec::C(TAU)),
        ]
    }
}

/// Names exmex reads as operators or constants: never a symbol's name.
pub(crate) const RESERVED: &[&str] = &[
    "atan2", "min", "max", "abs", "signum", "sin", "cos", "tan", "asin", "acos", "atan", "sinh",
    "cosh", "tanh", "asinh", "acosh", "atanh", "floor", "round", "ceil", "trunc", "fract", "exp",
    "sqrt", "cbrt", "ln", "log2", "log10", "log", "PI", "π", "E", "e", "TAU", "τ",
];

/// Why an expression did not compile.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum ExprError {
    /// exmex could not parse or evaluate it (its message).
    Syntax(String),
    /// It names a symbol that is not a variable.
    Unknown(String),
}

/// Records expressions over named variables into one [`Tape`].
#[derive(Debug)]
pub(crate) struct TapeBuilder {
    names: HashMap<String, u32>,
    n_vars: usize,
    /// Variables from this index on are inputs (held over a sample).
    input_start: usize,
    /// Variables from this index on are parameters (hoisted sub-expressions).
    param_start: usize,
    tracer: Tracer,
}

impl TapeBuilder {
    /// A builder over `names` (the variable slots, in order); variables
    /// `..input_start` are states, `input_start..param_start` inputs and
    /// `param_start..` parameters.
    pub(crate) fn new(names: &[String], input_start: usize, param_start: usize) -> Self {
        let mut b = Self {
            names: names
                .iter()
                .enumerate()
                .map(|(i, n)| (n.clone(), i as u32))
                .collect(),
            n_vars: names.len(),
            input_start,
            param_start,
            tracer: Tracer::default(),
        };
        with_tracer(&mut b.tracer, || {
            for i in 0..names.len() {
                intern(Def::Var(i as u32));
            }
        });
        b
    }

    /// Record one expression; the symbols it uses, in exmex's order.
    pub(crate) fn expr(&mut self, text: &str) -> Result<(Rec, Vec<String>), ExprError> {
        let names = &self.names;
        let run = || -> Result<(Rec, Vec<String>), ExprError> {
            let e = FlatEx::<Rec, TraceOps>::parse(text)
                .map_err(|e| ExprError::Syntax(e.msg().to_string()))?;
            let mut vars = Vec::with_capacity(e.var_names().len());
            for n in e.var_names() {
                let i = names
                    .get(n.as_str())
                    .ok_or_else(|| ExprError::Unknown(n.clone()))?;
                vars.push(Rec::V(*i));
            }
            let r = e
                .eval(&vars)
                .map_err(|e| ExprError::Syntax(e.msg().to_string()))?;
            Ok((r, e.var_names().to_vec()))
        };
        // parse and evaluate inside the tracer: every recorded node lands here
        with_tracer(&mut self.tracer, run)
    }

    /// The sum of recorded values (additive terms).
    pub(crate) fn sum(&mut self, terms: &[Rec]) -> Rec {
        with_tracer(&mut self.tracer, || {
            let mut acc = Rec::C(0.0);
            for (i, t) in terms.iter().enumerate() {
                acc = if i == 0 { *t } else { bin(Op::Add, acc, *t) };
            }
            acc
        })
    }

    /// The tape computing `outputs` (dead nodes dropped; parameter-only
    /// nodes hoisted into the prologue, input-only ones into the per-sample
    /// part; the state-dependent rest also fused, see [`fuse`]).
    pub(crate) fn finish(mut self, outputs: &[Rec]) -> Tape {
        let out_ids: Vec<u32> = with_tracer(&mut self.tracer, || {
            outputs.iter().map(|r| id(*r)).collect()
        });
        let defs = &self.tracer.defs;
        // reachability from the outputs (ids are topological: operands first)
        let mut live = vec![false; defs.len()];
        for &o in &out_ids {
            live[o as usize] = true;
        }
        for i in (0..defs.len()).rev() {
            if let (true, Def::Node(_, a, b)) = (live[i], defs[i]) {
                live[a as usize] = true;
                live[b as usize] = true;
            }
        }
        // the level of each value: 0 parameters, constants and nodes of
        // them; 1 also inputs; 2 also states
        let mut level = vec![0u8; defs.len()];
        for (i, d) in defs.iter().enumerate() {
            level[i] = match *d {
                Def::Var(v) if (v as usize) < self.input_start => 2,
                Def::Var(v) if (v as usize) < self.param_start => 1,
                Def::Var(_) | Def::Const(_) => 0,
                Def::Node(_, a, b) => level[a as usize].max(level[b as usize]),
            };
        }
        let mut slot = vec![u32::MAX; defs.len()];
        let mut next = self.n_vars as u32;
        let mut consts = Vec::new();
        for (i, d) in defs.iter().enumerate() {
            match *d {
                Def::Var(v) => slot[i] = v,
                Def::Const(bits) if live[i] => {
                    slot[i] = next;
                    consts.push((next, f64::from_bits(bits)));
                    next += 1;
                }
                _ => {}
            }
        }
        let mut parts: [Vec<Node>; 3] = Default::default();
        for (lv, part) in parts.iter_mut().enumerate() {
            for (i, d) in defs.iter().enumerate() {
                if let Def::Node(op, a, b) = *d {
                    if live[i] && level[i] as usize == lv {
                        slot[i] = next;
                        part.push(Node::new(op, slot[a as usize], slot[b as usize], next));
                        next += 1;
                    }
                }
            }
        }
        let outputs: Vec<u32> = out_ids.iter().map(|&o| slot[o as usize]).collect();
        let [pre, input, main] = parts;
        let tape = Tape {
            n_slots: next as usize,
            consts,
            pre,
            input,
            fused: fuse(&main, &outputs, next as usize),
            main,
            outputs,
        };
        tape.check_slots();
        tape
    }
}

/// The state-dependent nodes with every product that only one sum reads
/// folded into it: `p + a·b`, `a·b + p` → `MulAdd`, `a·b − p` → `MulSub`,
/// `p − a·b` → `SubMul`, written to the sum's slot. `a·b` is rounded before
/// the sum as before (no FMA), so the values are bit-identical.
fn fuse(main: &[Node], outputs: &[u32], n_slots: usize) -> Vec<Node> {
    let mut reads = vec![0u32; n_slots];
    for n in main {
        reads[n.a as usize] += 1;
        if is_binary(n.op) {
            reads[n.b as usize] += 1;
        }
    }
    for &o in outputs {
        reads[o as usize] += 1;
    }
    // the index in `main` of the product writing each slot, read once
    let mut product = vec![usize::MAX; n_slots];
    for (i, n) in main.iter().enumerate() {
        if n.op == Op::Mul && reads[n.out as usize] == 1 {
            product[n.out as usize] = i;
        }
    }
    let mut absorbed = vec![false; main.len()];
    let mut fused: Vec<Node> = main.to_vec();
    for (i, n) in main.iter().enumerate() {
        let (pa, pb) = (product[n.a as usize], product[n.b as usize]);
        let (op, m, other) = match n.op {
            Op::Add if pb != usize::MAX => (Op::MulAdd, pb, n.a),
            Op::Add if pa != usize::MAX => (Op::MulAdd, pa, n.b),
            Op::Sub if pb != usize::MAX => (Op::SubMul, pb, n.a),
            Op::Sub if pa != usize::MAX => (Op::MulSub, pa, n.b),
            _ => continue,
        };
        absorbed[m] = true;
        fused[i] = Node {
            op,
            a: main[m].a,
            b: main[m].b,
            c: other,
            out: n.out,
        };
    }
    fused
        .into_iter()
        .zip(absorbed)
        .filter_map(|(n, gone)| (!gone).then_some(n))
        .fold(
            Vec::with_capacity(main.len()),
            |mut prog: Vec<Node>, mut n| {
                // a sum of the result just computed reads it from a register
                if prog.last().is_some_and(|p| p.out == n.c) {
                    n.op = match n.op {
                        Op::MulAdd => Op::MulAddPrev,
                        Op::MulSub => Op::MulSubPrev,
                        Op::SubMul => Op::SubMulPrev,
                        op => op,
                    };
                }
                prog.push(n);
                prog
            },
        )
}

/// One tape operation: `slot[out] = op(slot[a], slot[b])`; the fused
/// operations also read `slot[c]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Node {
    op: Op,
    a: u32,
    b: u32,
    c: u32,
    out: u32,
}

impl Node {
    fn new(op: Op, a: u32, b: u32, out: u32) -> Self {
        Self {
            op,
            a,
            b,
            c: a,
            out,
        }
    }
}

/// A compiled set of expressions over variable slots `0..n_vars`
/// (the caller's layout), constants, a prologue of parameter-only nodes,
/// the input-only nodes (once per sample) and the main nodes (once per
/// evaluation; `fused` is the same for values only). Every node writes a
/// slot of its own, after the slots of its operands.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Tape {
    n_slots: usize,
    consts: Vec<(u32, f64)>,
    pre: Vec<Node>,
    input: Vec<Node>,
    main: Vec<Node>,
    fused: Vec<Node>,
    outputs: Vec<u32>,
}

/// Slot values (and derivative lanes) of one tape evaluation.
#[derive(Clone, Debug)]
pub(crate) struct Slots {
    /// Values.
    pub(crate) v: Vec<f64>,
    /// Derivative lanes, `lanes` per slot.
    pub(crate) d: Vec<f64>,
    /// Lanes per slot.
    pub(crate) lanes: usize,
}

impl Tape {
    /// Slots with the constants set and `lanes` zero derivative lanes.
    pub(crate) fn slots(&self, lanes: usize) -> Slots {
        let mut v = vec![0.0; self.n_slots];
        for &(s, c) in &self.consts {
            v[s as usize] = c;
        }
        Slots {
            v,
            d: vec![0.0; self.n_slots * lanes],
            lanes,
        }
    }

    /// Every slot a node reads or writes, every output and every constant
    /// lies below `n_slots` (what the unchecked loop of [`run`] relies
    /// on); a tape that breaks this is a bug of [`TapeBuilder::finish`].
    fn check_slots(&self) {
        let n = self.n_slots as u32;
        let nodes_ok = self
            .pre
            .iter()
            .chain(&self.input)
            .chain(&self.main)
            .chain(&self.fused)
            .all(|d| d.a < n && d.b < n && d.c < n && d.out < n);
        let rest_ok =
            self.outputs.iter().all(|&o| o < n) && self.consts.iter().all(|&(c, _)| c < n);
        assert!(nodes_ok && rest_ok, "tape slot out of range");
    }

    /// Operations (prologue, per input, main, main fused).
    #[cfg(test)]
    pub(crate) fn len(&self) -> (usize, usize, usize, usize) {
        let (p, i, m, f) = (&self.pre, &self.input, &self.main, &self.fused);
        (p.len(), i.len(), m.len(), f.len())
    }

    /// Evaluate the prologue (after the parameter slots were set).
    pub(crate) fn run_pre(&self, s: &mut Slots) {
        run(&self.pre, self.n_slots, &mut s.v);
    }

    /// Evaluate the input-only nodes (after the input slots were set).
    #[inline]
    pub(crate) fn run_input(&self, s: &mut Slots) {
        run(&self.input, self.n_slots, &mut s.v);
    }

    /// Evaluate the main nodes, fused (after the state slots were set,
    /// and [`run_input`](Self::run_input) since the inputs changed).
    #[inline(always)]
    pub(crate) fn run(&self, s: &mut Slots) {
        self.run_values(&mut s.v);
    }

    /// [`run`](Self::run) on the values of [`Slots`]; the last node's
    /// result (also in its slot, [`last_slot`](Self::last_slot)).
    #[inline(always)]
    pub(crate) fn run_values(&self, v: &mut [f64]) -> f64 {
        run(&self.fused, self.n_slots, v)
    }

    /// The slot the last main node writes (`None`: no main nodes).
    pub(crate) fn last_slot(&self) -> Option<usize> {
        self.fused.last().map(|n| n.out as usize)
    }

    /// The prologue with derivative lanes.
    pub(crate) fn run_pre_dual(&self, s: &mut Slots, plan: &DualPlan) {
        run_dual(&self.pre, &plan.pre, &plan.lanes, s);
    }

    /// The input-only nodes with derivative lanes (after the input slots
    /// were set; their lanes only hold parameter derivatives).
    #[inline]
    pub(crate) fn run_input_dual(&self, s: &mut Slots, plan: &DualPlan) {
        run_dual(&self.input, &plan.input, &plan.lanes, s);
    }

    /// The main nodes unfused, values only (what [`run_dual`](Self::run_dual)
    /// computes without lanes; the same bits as [`run`](Self::run)).
    pub(crate) fn run_unfused(&self, s: &mut Slots) {
        run(&self.main, self.n_slots, &mut s.v);
    }

    /// The main nodes with derivative lanes (after
    /// [`run_input_dual`](Self::run_input_dual) since the inputs changed).
    #[inline]
    pub(crate) fn run_dual(&self, s: &mut Slots, plan: &DualPlan) {
        run_dual(&self.main, &plan.main, &plan.lanes, s);
    }

    /// The lane work of every node for variable slots laid out as
    /// `n` states (every lane may be non-zero), `nu` inputs (none) and the
    /// parameters, `param_lane[p]` the one lane of parameter `p` (`None`:
    /// fixed, none), `lanes` lanes per slot.
    pub(crate) fn dual_plan(
        &self,
        n: usize,
        nu: usize,
        param_lane: &[Option<usize>],
        lanes: usize,
    ) -> DualPlan {
        let mut vars = vec![LaneSet::Zero; (n + nu + param_lane.len()).min(self.n_slots)];
        if lanes > 0 {
            vars[..n.min(self.n_slots)].fill(LaneSet::All);
        }
        for (p, lane) in param_lane.iter().enumerate() {
            if let (Some(k), Some(m)) = (lane, vars.get_mut(n + nu + p)) {
                *m = LaneSet::Some(vec![*k as u32]);
            }
        }
        self.plan_from(vars, lanes)
    }

    /// The plan for variable slots carrying the lanes `vars` (the other
    /// slots: constants and nodes).
    fn plan_from(&self, vars: Vec<LaneSet>, lanes: usize) -> DualPlan {
        let mut mask = vars;
        mask.resize(self.n_slots, LaneSet::Zero);
        let mut list = Vec::new();
        let mut plan = |nodes: &[Node], mask: &mut Vec<LaneSet>| {
            nodes
                .iter()
                .map(|nd| {
                    let (ma, mb) = (&mask[nd.a as usize], &mask[nd.b as usize]);
                    let (work, out) = lane_work(is_binary(nd.op), ma, mb, lanes, &mut list);
                    mask[nd.out as usize] = out;
                    work
                })
                .collect::<Vec<_>>()
        };
        let pre = plan(&self.pre, &mut mask);
        let input = plan(&self.input, &mut mask);
        let main = plan(&self.main, &mut mask);
        DualPlan {
            pre,
            input,
            main,
            lanes: list,
        }
    }

    /// The slot of output `i` (below the length of the tape's slots).
    #[inline(always)]
    pub(crate) fn output_slot(&self, i: usize) -> usize {
        self.outputs[i] as usize
    }

    /// Value of output `i` after a run.
    #[inline(always)]
    pub(crate) fn out(&self, s: &Slots, i: usize) -> f64 {
        s.v[self.outputs[i] as usize]
    }

    /// Derivative lanes of output `i` after a dual run.
    #[inline(always)]
    pub(crate) fn out_lanes<'s>(&self, s: &'s Slots, i: usize) -> &'s [f64] {
        let o = self.outputs[i] as usize * s.lanes;
        &s.d[o..o + s.lanes]
    }

    /// Number of outputs.
    pub(crate) fn n_outputs(&self) -> usize {
        self.outputs.len()
    }
}

/// `v[out] = op(v[a], v[b])` for every node, in order (the `…Prev`
/// operations take `c` from `r`, the previous result, instead of from its
/// slot: no store-to-load wait). The hot loop of every simulation: the
/// slot indices are checked once, when the tape is built
/// ([`Tape::check_slots`]), and the length of `v` once per call.
#[inline(always)]
fn run(nodes: &[Node], n_slots: usize, v: &mut [f64]) -> f64 {
    assert!(v.len() >= n_slots, "slots of another tape");
    let mut r = 0.0;
    for n in nodes {
        // SAFETY: `Tape::finish` checks that every node's operands and
        // output are below `n_slots` (`check_slots`), and `v` holds at
        // least `n_slots` values (asserted above).
        unsafe {
            let (a, b) = (
                *v.get_unchecked(n.a as usize),
                *v.get_unchecked(n.b as usize),
            );
            r = match n.op {
                Op::MulAdd => a * b + *v.get_unchecked(n.c as usize),
                Op::MulSub => a * b - *v.get_unchecked(n.c as usize),
                Op::SubMul => *v.get_unchecked(n.c as usize) - a * b,
                Op::MulAddPrev => a * b + r,
                Op::MulSubPrev => a * b - r,
                Op::SubMulPrev => r - a * b,
                op => apply(op, a, b),
            };
            *v.get_unchecked_mut(n.out as usize) = r;
        }
    }
    r
}

/// Which derivative lanes of a slot can be non-zero.
#[derive(Clone, Debug, PartialEq)]
enum LaneSet {
    /// None (constants, inputs, fixed parameters and nodes of them).
    Zero,
    /// These lanes (sorted): free parameters and nodes of them only.
    Some(Vec<u32>),
    /// Any (the states and nodes of them).
    All,
}

/// The derivative work of one node `out = op(a, b)`, `∂out = c_a ∂a + c_b ∂b`,
/// from the lanes its operands can carry. Lanes a node never writes stay
/// at their initial 0, which is what the full formula gives there (a
/// product with a zero lane), so every variant computes the same numbers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum LaneWork {
    /// No operand carries a lane.
    Skip,
    /// Every lane from operand a (`from_a`) or b alone: `∂out = c ∂x`.
    Scale { from_a: bool },
    /// Every lane from one operand, then the few lanes `lanes[start..end]`
    /// of the other added: `∂out = c_x ∂x`, `∂out_k += c_y ∂y_k`.
    ScaleAdd { from_a: bool, start: u32, end: u32 },
    /// The few lanes `lanes[start..end]` of both operands.
    Few { start: u32, end: u32 },
    /// Every lane of both operands.
    Full,
}

/// The lane work of every node of a [`Tape`] for one layout of the
/// derivative lanes ([`Tape::dual_plan`]).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct DualPlan {
    pre: Vec<LaneWork>,
    input: Vec<LaneWork>,
    main: Vec<LaneWork>,
    /// The lane lists the `ScaleAdd` and `Few` entries point into.
    lanes: Vec<u32>,
}

/// The work of a node whose operands carry the lanes `ma`, `mb` (`mb`
/// unused by a unary operation), and the lanes its result carries.
fn lane_work(
    binary: bool,
    ma: &LaneSet,
    mb: &LaneSet,
    lanes: usize,
    list: &mut Vec<u32>,
) -> (LaneWork, LaneSet) {
    let mut push = |ks: &[u32]| {
        let start = list.len() as u32;
        list.extend_from_slice(ks);
        (start, list.len() as u32)
    };
    let mb = if binary { mb } else { &LaneSet::Zero };
    match (ma, mb) {
        (LaneSet::Zero, LaneSet::Zero) => (LaneWork::Skip, LaneSet::Zero),
        (LaneSet::All, LaneSet::Zero) => (LaneWork::Scale { from_a: true }, LaneSet::All),
        (LaneSet::Zero, LaneSet::All) => (LaneWork::Scale { from_a: false }, LaneSet::All),
        (LaneSet::All, LaneSet::All) => (LaneWork::Full, LaneSet::All),
        (LaneSet::All, LaneSet::Some(ks)) | (LaneSet::Some(ks), LaneSet::All) => {
            let from_a = matches!(ma, LaneSet::All);
            let (start, end) = push(ks);
            (LaneWork::ScaleAdd { from_a, start, end }, LaneSet::All)
        }
        (LaneSet::Some(x), LaneSet::Some(y)) => {
            let mut ks: Vec<u32> = x.iter().chain(y).copied().collect();
            ks.sort_unstable();
            ks.dedup();
            if 2 * ks.len() > lanes {
                (LaneWork::Full, LaneSet::All)
            } else {
                let (start, end) = push(&ks);
                (LaneWork::Few { start, end }, LaneSet::Some(ks))
            }
        }
        (LaneSet::Some(ks), LaneSet::Zero) | (LaneSet::Zero, LaneSet::Some(ks)) => {
            let (start, end) = push(ks);
            (LaneWork::Few { start, end }, LaneSet::Some(ks.clone()))
        }
    }
}

/// The nodes with derivative lanes: each value as [`run`] computes it
/// unfused, each node's lanes `∂out = c_a ∂a + c_b ∂b` (`c` from
/// [`partials`]; a binary node whose `c_b` is 0 takes `c_a ∂a` alone) as
/// `work` says.
fn run_dual(nodes: &[Node], work: &[LaneWork], list: &[u32], s: &mut Slots) {
    let l = s.lanes;
    for (n, w) in nodes.iter().zip(work) {
        let (a, b, o) = (n.a as usize, n.b as usize, n.out as usize);
        let (va, vb) = (s.v[a], s.v[b]);
        let out = apply(n.op, va, vb);
        s.v[o] = out;
        if l == 0 || *w == LaneWork::Skip {
            continue;
        }
        let (ca, cb) = partials(n.op, va, vb, out);
        let cb = if is_binary(n.op) { cb } else { 0.0 };
        // every node writes a slot after its operands' slots
        let (lo, hi) = s.d.split_at_mut(o * l);
        let dout = &mut hi[..l];
        let da = &lo[a * l..a * l + l];
        let db = &lo[b * l..b * l + l];
        match *w {
            // handled above
            LaneWork::Skip => {}
            LaneWork::Full if cb != 0.0 => {
                for k in 0..l {
                    dout[k] = ca * da[k] + cb * db[k];
                }
            }
            LaneWork::Full => {
                for k in 0..l {
                    dout[k] = ca * da[k];
                }
            }
            LaneWork::Scale { from_a } => {
                let (c, dx) = if from_a { (ca, da) } else { (cb, db) };
                for k in 0..l {
                    dout[k] = c * dx[k];
                }
            }
            LaneWork::ScaleAdd { from_a, start, end } => {
                let ((cx, dx), (cy, dy)) = if from_a {
                    ((ca, da), (cb, db))
                } else {
                    ((cb, db), (ca, da))
                };
                for k in 0..l {
                    dout[k] = cx * dx[k];
                }
                for &k in &list[start as usize..end as usize] {
                    dout[k as usize] += cy * dy[k as usize];
                }
            }
            LaneWork::Few { start, end } if cb != 0.0 => {
                for &k in &list[start as usize..end as usize] {
                    let k = k as usize;
                    dout[k] = ca * da[k] + cb * db[k];
                }
            }
            LaneWork::Few { start, end } => {
                for &k in &list[start as usize..end as usize] {
                    dout[k as usize] = ca * da[k as usize];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use exmex::Differentiate;

    const CASES: &[&str] = &[
        "(F - c*v - k*x)/m",
        "-k1*sqrt(x) + k2*F",
        "alpha*v - beta*(gamma*abs(v)*x + delta*v*abs(x))",
        "x^2 + x^3 - x^-1 + x^0.5 + x^2.5 + 2^x",
        "exp(-x)*sin(v) + cos(x*v) - tan(0.1*x)",
        "tanh(v/0.01) + atan(x) + sinh(0.3*v) + cosh(0.2*x)",
        "ln(x) + log(x) + log2(x) + log10(x) + cbrt(x)",
        "min(x, v) + max(x, v) + atan2(v, x)",
        "signum(v) + abs(-v) - -x + +x",
        "2*3*x + PI*v - E + TAU*c",
        "x^v",
        "asin(0.1*x) + acos(0.1*v) + asinh(x) + acosh(1+x) + atanh(0.1*v)",
    ];
    const NAMES: [&str; 7] = ["x", "v", "F", "c", "k", "m", "k1"];

    fn names() -> Vec<String> {
        let mut n: Vec<String> = NAMES.iter().map(|s| s.to_string()).collect();
        for s in ["k2", "alpha", "beta", "gamma", "delta"] {
            n.push(s.into());
        }
        n
    }

    fn point(seed: usize) -> Vec<f64> {
        (0..12)
            .map(|i| 0.3 + 1.7 * (((seed * 31 + i * 17) % 23) as f64 / 23.0))
            .collect()
    }

    fn compile(text: &str) -> (Tape, Vec<String>) {
        let n = names();
        let mut b = TapeBuilder::new(&n, 2, 3);
        let (r, used) = b.expr(text).unwrap();
        (b.finish(&[r]), used)
    }

    fn eval_tape(t: &Tape, p: &[f64]) -> f64 {
        let mut s = t.slots(0);
        s.v[..p.len()].copy_from_slice(p);
        t.run_pre(&mut s);
        t.run_input(&mut s);
        t.run(&mut s);
        t.out(&s, 0)
    }

    fn exmex_args(used: &[String], p: &[f64]) -> Vec<f64> {
        let n = names();
        used.iter()
            .map(|u| p[n.iter().position(|x| x == u).unwrap()])
            .collect()
    }

    #[test]
    fn the_tape_evaluates_as_exmex_does() {
        for text in CASES {
            let (t, used) = compile(text);
            let ex = FlatEx::<f64>::parse(text).unwrap();
            assert_eq!(ex.var_names(), used.as_slice());
            for seed in 0..5 {
                let p = point(seed);
                let want = ex.eval(&exmex_args(&used, &p)).unwrap();
                let got = eval_tape(&t, &p);
                assert!(
                    (got - want).abs() <= 1e-12 * want.abs().max(1.0),
                    "{text}: tape {got} exmex {want}"
                );
            }
        }
    }

    #[test]
    fn derivatives_match_exmex_partial_and_finite_differences() {
        let n = names();
        for text in CASES {
            let (t, used) = compile(text);
            let ex = FlatEx::<f64>::parse(text).unwrap();
            let p = point(3);
            // all variables as lanes, each one's lane its own: a plan that
            // knows it, one that takes the states' lanes (x, v) as any
            // (as the integrator does), and one that takes every lane as
            // possibly set (the dense computation)
            let unit: Vec<LaneSet> = (0..n.len())
                .map(|i| LaneSet::Some(vec![i as u32]))
                .collect();
            let mut states = unit.clone();
            states[..2].fill(LaneSet::All);
            let every = vec![LaneSet::All; n.len()];
            let mut both = [unit, states, every].map(|vars| {
                let plan = t.plan_from(vars, n.len());
                let mut s = t.slots(n.len());
                s.v[..p.len()].copy_from_slice(&p);
                for i in 0..n.len() {
                    s.d[i * n.len() + i] = 1.0;
                }
                t.run_pre_dual(&mut s, &plan);
                t.run_input_dual(&mut s, &plan);
                t.run_dual(&mut s, &plan);
                t.out_lanes(&s, 0).to_vec()
            });
            let lanes = std::mem::take(&mut both[0]);
            assert_eq!(lanes, both[2], "{text}: the sparse plan differs");
            assert_eq!(both[1], both[2], "{text}: the states-dense plan differs");
            for (k, name) in used.iter().enumerate() {
                let i = n.iter().position(|x| x == name).unwrap();
                // central difference of the expression
                let h = 1e-6 * p[i].abs().max(1.0);
                let (mut a, mut b) = (p.clone(), p.clone());
                a[i] += h;
                b[i] -= h;
                let fd = (eval_tape(&t, &a) - eval_tape(&t, &b)) / (2.0 * h);
                assert!(
                    (lanes[i] - fd).abs() <= 1e-6 * fd.abs().max(1.0),
                    "{text}: d/d{name} tape {} fd {fd}",
                    lanes[i]
                );
                // exmex's symbolic derivative, where exmex has the rules
                if let Ok(d) = ex.clone().partial(k) {
                    let want = d.eval(&exmex_args(&used, &p)).unwrap();
                    assert!(
                        (lanes[i] - want).abs() <= 1e-9 * want.abs().max(1.0),
                        "{text}: d/d{name} tape {} exmex {want}",
                        lanes[i]
                    );
                } else {
                    assert!(
                        ["abs", "signum", "min", "max", "atan2", "cbrt"]
                            .iter()
                            .any(|o| text.contains(o)),
                        "{text}: exmex cannot differentiate"
                    );
                }
            }
        }
    }

    #[test]
    fn common_subexpressions_are_shared_and_parameters_hoisted() {
        let n = names();
        let mut b = TapeBuilder::new(&n, 2, 3);
        let (f1, _) = b.expr("-k1*sqrt(x) + c/m*F").unwrap();
        let (f2, _) = b.expr("k*sqrt(x) - c/m").unwrap();
        let t = b.finish(&[f1, f2]);
        // -k1 and c/m are parameter-only, c/m*F input-only; sqrt(x) is
        // computed once; both products are fused into their sums
        assert_eq!(t.len(), (2, 1, 5, 3), "{t:?}");
    }

    /// The fused value program gives the same bits as the plain nodes
    /// (which the dual path runs), at random points.
    #[test]
    fn fused_nodes_are_bit_identical_to_the_plain_ones() {
        let mut cases = CASES.to_vec();
        cases.push("x*v - c*x + k*v*x - (m - x*F) - F*(c*v + k1) + (k2 - alpha*x)*beta");
        cases.push("c*x + x*k - F*(x*x) + v*v*v");
        let mut rng = 0x9e37_79b9_7f4a_7c15_u64;
        let mut uniform = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut fused_any = false;
        for text in cases {
            let (t, _) = compile(text);
            let (_, _, main, fused) = t.len();
            fused_any |= fused < main;
            for _ in 0..50 {
                let p: Vec<f64> = (0..12).map(|_| 0.05 + 1.9 * uniform()).collect();
                let mut s = t.slots(0);
                s.v[..p.len()].copy_from_slice(&p);
                t.run_pre(&mut s);
                t.run_input(&mut s);
                t.run(&mut s);
                let fast = t.out(&s, 0);
                let plan = t.dual_plan(2, 1, &[None; 9], 0);
                t.run_dual(&mut s, &plan);
                let plain = t.out(&s, 0);
                assert_eq!(fast.to_bits(), plain.to_bits(), "{text} at {p:?}");
            }
        }
        assert!(fused_any, "no case was fused");
    }

    #[test]
    fn unknown_symbols_and_syntax_errors() {
        let n = names();
        let mut b = TapeBuilder::new(&n, 2, 3);
        assert_eq!(
            b.expr("x + kk*v").unwrap_err(),
            ExprError::Unknown("kk".into())
        );
        assert!(matches!(b.expr("x + (v"), Err(ExprError::Syntax(_))));
        assert!(matches!(b.expr("x +* v"), Err(ExprError::Syntax(_))));
    }
}
