//! The recurrent cells: hand-computed steps, agreement of the sequence and step paths and with
//! candle-nn's LSTM, finite-difference checks of backpropagation through time (inputs, initial
//! state, every weight), typed errors, and a short training run.

use candle_core::{DType, Tensor};
use candle_nn::rnn::{LSTMConfig, LSTMState, RNN};
use candle_nn::{VarBuilder, VarMap};
use pbdl_core::tolerance::{F32_AGREEMENT, F64_AGREEMENT, GRAD_CHECK_F64};
use pbdl_core::{check_grad, GradCheckOptions, GradCheckReport};
use pbdl_nets::recurrent::{ConvLstmCell, ConvLstmConfig, Lstm, LstmCell, LstmConfig, LstmState};
use pbdl_nets::{Error, Linear, Padding};
use std::collections::HashMap;

mod common;
use common::{first_last_mean, randn, train, CPU};

const NAMES: [&str; 4] = ["weight_ih_l0", "weight_hh_l0", "bias_ih_l0", "bias_hh_l0"];

/// PyTorch-scaled LSTM variables `weight_ih_l0` `[4h, input]`, `weight_hh_l0`, `bias_ih_l0`,
/// `bias_hh_l0`, uniform in `±1/sqrt(h)` from `seed`, for `VarBuilder::from_tensors`.
fn lstm_vars(input: usize, hidden: usize, dtype: DType, seed: u64) -> HashMap<String, Tensor> {
    let k = 1.0 / (hidden as f64).sqrt();
    let shapes = [vec![4 * hidden, input], vec![4 * hidden, hidden], vec![4 * hidden], vec![4 * hidden]];
    NAMES
        .iter()
        .zip(shapes)
        .enumerate()
        .map(|(i, (n, s))| {
            (n.to_string(), pbdl_core::seed::rand_uniform(s, -k, k, dtype, &CPU, seed + i as u64).unwrap())
        })
        .collect()
}

fn max_rel_diff(a: &Tensor, b: &Tensor) -> f64 {
    let a: Vec<f64> = a.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1().unwrap();
    let b: Vec<f64> = b.to_dtype(DType::F64).unwrap().flatten_all().unwrap().to_vec1().unwrap();
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter().zip(&b).fold(0.0f64, |m, (x, y)| m.max((x - y).abs())) / scale
}

fn print_report(name: &str, inputs: &str, r: &GradCheckReport) {
    println!(
        "{name}: max rel error {:.2e} over {} probes; per input ({inputs}): {:?}",
        r.max_rel_error,
        r.probes,
        r.per_input.iter().map(|e| format!("{e:.1e}")).collect::<Vec<_>>()
    );
}

fn msg(e: impl std::fmt::Display) -> candle_core::Error {
    candle_core::Error::Msg(e.to_string())
}

fn to_scalar(t: &Tensor) -> f64 {
    t.flatten_all().unwrap().to_vec1::<f64>().unwrap()[0]
}

// ---------------------------------------------------------------------------------------------
// Hand-computed steps

/// Weights zero, biases chosen so the gates are round numbers: z_i = 0 (i = 1/2),
/// z_f = ln 3 (f = 3/4), z_g = ln(3)/2 (g = tanh = 1/2), z_o = -ln 3 (o = 1/4); from c = 2:
/// c' = 3/4 * 2 + 1/2 * 1/2 = 1.75 and h' = tanh(1.75) / 4 = 0.23534388462432185 (Python's
/// `0.25 * math.tanh(1.75)`). The biases are split between b_ih and b_hh to check both count.
#[test]
fn bias_only_step_gives_hand_computed_gates() {
    let l3 = 3f64.ln();
    let mut vars = HashMap::new();
    vars.insert("weight_ih".into(), Tensor::zeros((4, 2), DType::F64, &CPU).unwrap());
    vars.insert("weight_hh".into(), Tensor::zeros((4, 1), DType::F64, &CPU).unwrap());
    vars.insert("bias_ih".into(), Tensor::new(&[0.0, l3, 0.0, -l3], &CPU).unwrap());
    vars.insert("bias_hh".into(), Tensor::new(&[0.0, 0.0, l3 / 2.0, 0.0], &CPU).unwrap());
    let cell = LstmCell::new(2, 1, VarBuilder::from_tensors(vars, DType::F64, &CPU)).unwrap();
    let state = LstmState::new(Tensor::new(&[[0.7]], &CPU).unwrap(), Tensor::new(&[[2.0]], &CPU).unwrap());
    let x = Tensor::new(&[[5.0, -3.0]], &CPU).unwrap();
    let next = cell.forward_step(&x, &state).unwrap();
    assert!((to_scalar(&next.c) - 1.75).abs() < 1e-15);
    assert!((to_scalar(&next.h) - 0.23534388462432185).abs() < 1e-15);
}

/// A 1-unit cell with every weight non-zero. Expected numbers from
/// ```python
/// import math
/// s = lambda z: 1 / (1 + math.exp(-z))
/// x, h, c = 0.5, -1.0, 0.3
/// Wi = [1, -1, 2, 0.5]; Wh = [0.5, 1, -1, 2]; bi = [0.1, -0.2, 0.3, 0.0]; bh = [0.0, 0.4, -0.1, 0.2]
/// z = [Wi[k] * x + Wh[k] * h + bi[k] + bh[k] for k in range(4)]
/// i, f, g, o = s(z[0]), s(z[1]), math.tanh(z[2]), s(z[3])
/// c2 = f * c + i * g; print(repr(o * math.tanh(c2)), repr(c2))
/// # 0.09106460509118307 0.5764943406793015
/// ```
#[test]
fn one_unit_step_matches_hand_computation() {
    let t = |v: &[f64], shape: &[usize]| Tensor::from_slice(v, shape, &CPU).unwrap();
    let mut vars = HashMap::new();
    vars.insert("weight_ih".into(), t(&[1.0, -1.0, 2.0, 0.5], &[4, 1]));
    vars.insert("weight_hh".into(), t(&[0.5, 1.0, -1.0, 2.0], &[4, 1]));
    vars.insert("bias_ih".into(), t(&[0.1, -0.2, 0.3, 0.0], &[4]));
    vars.insert("bias_hh".into(), t(&[0.0, 0.4, -0.1, 0.2], &[4]));
    let cell = LstmCell::new(1, 1, VarBuilder::from_tensors(vars, DType::F64, &CPU)).unwrap();
    let state = LstmState::new(t(&[-1.0], &[1, 1]), t(&[0.3], &[1, 1]));
    let next = cell.forward_step(&t(&[0.5], &[1, 1]), &state).unwrap();
    assert!((to_scalar(&next.h) - 0.09106460509118307).abs() < 1e-15, "h' = {}", to_scalar(&next.h));
    assert!((to_scalar(&next.c) - 0.5764943406793015).abs() < 1e-15, "c' = {}", to_scalar(&next.c));
}

// ---------------------------------------------------------------------------------------------
// Paths agree

/// `Lstm` (one matmul for the input projection of the whole sequence) equals the cell's step
/// loop, and candle-nn's LSTM on the same variables (their names are PyTorch's in both).
#[test]
fn sequence_path_equals_step_loop_and_candle_nn() {
    let (b, t, i, h) = (2, 5, 3, 4);
    let vars = lstm_vars(i, h, DType::F64, 1);
    let vb = VarBuilder::from_tensors(vars.clone(), DType::F64, &CPU);
    let lstm = Lstm::new(LstmConfig::new(i, h), vb.clone()).unwrap();
    let x = randn(&[b, t, i], DType::F64, 2);
    let init = LstmState::new(randn(&[b, h], DType::F64, 3), randn(&[b, h], DType::F64, 4));
    let out = lstm.forward(&x, Some(std::slice::from_ref(&init))).unwrap();
    assert_eq!(out.output.dims(), &[b, t, h]);

    let cell = &lstm.cells()[0];
    let mut s = init.clone();
    let mut hs = vec![];
    for k in 0..t {
        s = cell.forward_step(&x.narrow(1, k, 1).unwrap().squeeze(1).unwrap(), &s).unwrap();
        hs.push(s.h.clone());
    }
    assert!(max_rel_diff(&out.output, &Tensor::stack(&hs, 1).unwrap()) < F64_AGREEMENT);
    assert!(max_rel_diff(&out.states[0].c, &s.c) < F64_AGREEMENT);

    let theirs = candle_nn::rnn::lstm(i, h, LSTMConfig::default(), vb).unwrap();
    let states = theirs.seq_init(&x, &LSTMState::new(init.h.clone(), init.c.clone())).unwrap();
    let d = max_rel_diff(&out.output, &theirs.states_to_tensor(&states).unwrap());
    println!("ours vs candle-nn LSTM output: max rel diff {d:.1e}");
    assert!(d < F64_AGREEMENT);
}

/// Two stacked layers equal two one-layer LSTMs, the second reading the first's outputs.
#[test]
fn stacked_layers_chain_cells() {
    let (b, t, i, h) = (2, 3, 3, 4);
    let mut vars = lstm_vars(i, h, DType::F64, 10);
    for (n, v) in lstm_vars(h, h, DType::F64, 20) {
        vars.insert(n.replace("_l0", "_l1"), v);
    }
    let stacked =
        Lstm::new(LstmConfig::new(i, h).num_layers(2), VarBuilder::from_tensors(vars.clone(), DType::F64, &CPU))
            .unwrap();
    let x = randn(&[b, t, i], DType::F64, 5);
    let out = stacked.forward(&x, None).unwrap();
    assert_eq!(out.states.len(), 2);
    let first = stacked.cells()[0].forward_sequence(&x, None).unwrap().0;
    let (second, last) = stacked.cells()[1].forward_sequence(&first, None).unwrap();
    assert!(max_rel_diff(&out.output, &second) < F64_AGREEMENT);
    assert!(max_rel_diff(&out.states[1].h, &last.h) < F64_AGREEMENT);
    assert_eq!(stacked.cells()[1].input_size(), h);
}

/// f32 and f64 runs of the same 6-step LSTM agree.
#[test]
fn lstm_f32_agrees_with_f64() {
    let (b, t, i, h) = (3, 6, 5, 8);
    let run = |dtype: DType| {
        let lstm = Lstm::new(LstmConfig::new(i, h), VarBuilder::from_tensors(lstm_vars(i, h, dtype, 30), dtype, &CPU))
            .unwrap();
        lstm.forward(&randn(&[b, t, i], dtype, 6), None).unwrap().output
    };
    let d = max_rel_diff(&run(DType::F32), &run(DType::F64));
    println!("LSTM f32 vs f64: max rel diff {d:.1e}");
    assert!(d < F32_AGREEMENT);
}

/// The fused sequence op (hand-written backward through time) equals the composed candle ops
/// in f32: hidden states, last cell state and the gradients of every variable and of (h0, c0),
/// for a loss that reads the outputs and the last cell state.
#[test]
fn fused_sequence_equals_composed_ops_in_f32() {
    let (b, t, i, h) = (4, 6, 5, 16);
    let vars: HashMap<String, candle_core::Var> = lstm_vars(i, h, DType::F32, 80)
        .into_iter()
        .map(|(k, v)| (k, candle_core::Var::from_tensor(&v).unwrap()))
        .collect();
    let x = randn(&[b, t, i], DType::F32, 81);
    let h0 = candle_core::Var::from_tensor(&randn(&[b, h], DType::F32, 82)).unwrap();
    let c0 = candle_core::Var::from_tensor(&randn(&[b, h], DType::F32, 83)).unwrap();
    let proj = randn(&[b, t, h], DType::F32, 84);
    let run = || {
        let map: HashMap<String, Tensor> = vars.iter().map(|(k, v)| (k.clone(), v.as_tensor().clone())).collect();
        let lstm = Lstm::new(LstmConfig::new(i, h), VarBuilder::from_tensors(map, DType::F32, &CPU)).unwrap();
        let init = [LstmState::new(h0.as_tensor().clone(), c0.as_tensor().clone())];
        let out = lstm.forward(&x, Some(&init)).unwrap();
        let (hs, last) = (out.output, out.states[0].clone());
        let loss = (hs.mul(&proj).unwrap().sum_all().unwrap() + last.c.sqr().unwrap().sum_all().unwrap()).unwrap();
        let grads = loss.backward().unwrap();
        let mut gs: Vec<(String, Tensor)> =
            vars.iter().map(|(k, v)| (k.clone(), grads.get(v.as_tensor()).unwrap().clone())).collect();
        gs.sort_by(|a, b| a.0.cmp(&b.0));
        gs.push(("h0".into(), grads.get(h0.as_tensor()).unwrap().clone()));
        gs.push(("c0".into(), grads.get(c0.as_tensor()).unwrap().clone()));
        (hs, last.c, gs)
    };
    let (hs_f, c_f, g_f) = run();
    let (hs_c, c_c, g_c) = pbdl_core::nn::with_composed(run);
    assert!(max_rel_diff(&hs_f, &hs_c) < F32_AGREEMENT, "hidden states");
    assert!(max_rel_diff(&c_f, &c_c) < F32_AGREEMENT, "last cell state");
    for ((name, a), (_, b)) in g_f.iter().zip(&g_c) {
        let d = max_rel_diff(a, b);
        println!("gradient of {name}: fused vs composed {d:.1e}");
        assert!(d < F32_AGREEMENT, "gradient of {name}: {d:.1e}");
    }
}

/// Seeded ConvLSTM variables `weight` `[4 hc, ci + hc, k, k]` and `bias` (PyTorch conv scale).
fn conv_lstm(cfg: ConvLstmConfig, dtype: DType, seed: u64) -> (HashMap<String, Tensor>, ConvLstmCell) {
    let varmap = VarMap::new();
    let cell = ConvLstmCell::new(cfg, VarBuilder::from_varmap(&varmap, dtype, &CPU)).unwrap();
    pbdl_nets::seeded_init(&varmap, seed).unwrap();
    let vars = varmap.data().lock().unwrap().iter().map(|(k, v)| (k.clone(), v.as_tensor().clone())).collect();
    (vars, cell)
}

/// The split sequence path (one conv of x over all steps, one conv of h per step) equals the
/// concat-then-convolve step for every padding.
#[test]
fn conv_lstm_sequence_path_equals_step_loop() {
    for padding in [Padding::Zeros, Padding::Periodic, Padding::PeriodicX] {
        let (_, cell) = conv_lstm(ConvLstmConfig::new(2, 3).padding(padding), DType::F64, 7);
        let x = randn(&[2, 4, 2, 5, 6], DType::F64, 8);
        let init = LstmState::new(randn(&[2, 3, 5, 6], DType::F64, 9), randn(&[2, 3, 5, 6], DType::F64, 10));
        let (hs, last) = cell.forward_sequence(&x, Some(&init)).unwrap();
        let mut s = init;
        for k in 0..4 {
            s = cell.forward_step(&x.narrow(1, k, 1).unwrap().squeeze(1).unwrap(), &s).unwrap();
            let hk = hs.narrow(1, k, 1).unwrap().squeeze(1).unwrap();
            assert!(max_rel_diff(&hk, &s.h) < F64_AGREEMENT, "{padding:?} step {k}");
        }
        assert!(max_rel_diff(&last.c, &s.c) < F64_AGREEMENT);
    }
}

/// With a 1x1 kernel the ConvLSTM is an LSTM cell at every pixel, with `W_ih` and `W_hh` the
/// input and hidden columns of the conv weight, `b_ih` its bias and `b_hh = 0`.
#[test]
fn conv_lstm_with_1x1_kernel_is_a_pixelwise_lstm() {
    let (ci, hc, b, y, x) = (2, 3, 2, 3, 4);
    let (vars, cell) = conv_lstm(ConvLstmConfig::new(ci, hc).kernel_size(1), DType::F64, 11);
    let w = vars["weight"].squeeze(3).unwrap().squeeze(2).unwrap(); // [4hc, ci + hc]
    let mut lv = HashMap::new();
    lv.insert("weight_ih".to_string(), w.narrow(1, 0, ci).unwrap());
    lv.insert("weight_hh".to_string(), w.narrow(1, ci, hc).unwrap());
    lv.insert("bias_ih".to_string(), vars["bias"].clone());
    lv.insert("bias_hh".to_string(), Tensor::zeros(4 * hc, DType::F64, &CPU).unwrap());
    let lstm = LstmCell::new(ci, hc, VarBuilder::from_tensors(lv, DType::F64, &CPU)).unwrap();
    // [b, c, y, x] <-> [b * y * x, c]
    let to_rows = |t: &Tensor| {
        let c = t.dim(1).unwrap();
        t.permute((0, 2, 3, 1)).unwrap().reshape((b * y * x, c)).unwrap()
    };
    let xs = randn(&[b, ci, y, x], DType::F64, 12);
    let s = LstmState::new(randn(&[b, hc, y, x], DType::F64, 13), randn(&[b, hc, y, x], DType::F64, 14));
    let conv_next = cell.forward_step(&xs, &s).unwrap();
    let rows_next = lstm.forward_step(&to_rows(&xs), &LstmState::new(to_rows(&s.h), to_rows(&s.c))).unwrap();
    assert!(max_rel_diff(&to_rows(&conv_next.h), &rows_next.h) < F64_AGREEMENT);
    assert!(max_rel_diff(&to_rows(&conv_next.c), &rows_next.c) < F64_AGREEMENT);
}

/// f32 and f64 runs of the same ConvLSTM agree.
#[test]
fn conv_lstm_f32_agrees_with_f64() {
    let run = |dtype: DType| {
        let (_, cell) = conv_lstm(ConvLstmConfig::new(2, 4).padding(Padding::PeriodicX), dtype, 15);
        cell.forward_sequence(&randn(&[2, 4, 2, 8, 8], dtype, 16), None).unwrap().0
    };
    let d = max_rel_diff(&run(DType::F32), &run(DType::F64));
    println!("ConvLSTM f32 vs f64: max rel diff {d:.1e}");
    assert!(d < F32_AGREEMENT);
}

// ---------------------------------------------------------------------------------------------
// Finite-difference checks of backpropagation through time

/// candle-nn's own LSTM (`candle_nn::rnn::lstm`, `seq_init`): its gradients through a 4-step
/// unroll with respect to the inputs, the initial state and all four weights, in f64.
#[test]
fn candle_nn_lstm_gradients_match_finite_differences() {
    let (b, t, i, h) = (2, 4, 3, 4);
    let vars = lstm_vars(i, h, DType::F64, 40);
    let mut inputs = vec![
        randn(&[b, t, i], DType::F64, 41),
        randn(&[b, h], DType::F64, 42),
        (randn(&[b, h], DType::F64, 43) * 0.5).unwrap(),
    ];
    inputs.extend(NAMES.iter().map(|n| vars[*n].clone()));
    let f = |xs: &[Tensor]| {
        let map: HashMap<String, Tensor> =
            NAMES.iter().zip(&xs[3..]).map(|(n, v)| (n.to_string(), v.clone())).collect();
        let lstm = candle_nn::rnn::lstm(i, h, LSTMConfig::default(), VarBuilder::from_tensors(map, DType::F64, &CPU))?;
        let states = lstm.seq_init(&xs[0], &LSTMState::new(xs[1].clone(), xs[2].clone()))?;
        let last = states.last().unwrap();
        Tensor::cat(&[&lstm.states_to_tensor(&states)?.flatten_all()?, &last.c.flatten_all()?], 0)
    };
    let r = check_grad(f, &inputs, &GradCheckOptions::default()).unwrap();
    print_report("candle-nn LSTM (4 steps)", "x, h0, c0, W_ih, W_hh, b_ih, b_hh", &r);
    r.ensure(GRAD_CHECK_F64).unwrap();
}

/// Our `Lstm`: all hidden states and the last c, differentiated with respect to the input
/// sequence, (h0, c0) and every weight, over 4 steps; one and two layers.
#[test]
fn lstm_gradients_match_finite_differences() {
    let (b, t, i, h) = (2, 4, 3, 4);
    for layers in [1usize, 2] {
        let mut vars = lstm_vars(i, h, DType::F64, 50);
        if layers == 2 {
            for (n, v) in lstm_vars(h, h, DType::F64, 60) {
                vars.insert(n.replace("_l0", "_l1"), v);
            }
        }
        let mut names: Vec<String> = vars.keys().cloned().collect();
        names.sort();
        let mut inputs = vec![randn(&[b, t, i], DType::F64, 51)];
        for l in 0..layers {
            inputs.push(randn(&[b, h], DType::F64, 52 + l as u64));
            inputs.push((randn(&[b, h], DType::F64, 54 + l as u64) * 0.5).unwrap());
        }
        let n_state = 2 * layers;
        inputs.extend(names.iter().map(|n| vars[n].clone()));
        let f = |xs: &[Tensor]| {
            let map: HashMap<String, Tensor> =
                names.iter().zip(&xs[1 + n_state..]).map(|(n, v)| (n.clone(), v.clone())).collect();
            let lstm =
                Lstm::new(LstmConfig::new(i, h).num_layers(layers), VarBuilder::from_tensors(map, DType::F64, &CPU))
                    .map_err(msg)?;
            let init: Vec<LstmState> =
                (0..layers).map(|l| LstmState::new(xs[1 + 2 * l].clone(), xs[2 + 2 * l].clone())).collect();
            let out = lstm.forward(&xs[0], Some(&init)).map_err(msg)?;
            let mut parts = vec![out.output.flatten_all()?];
            parts.extend(out.states.iter().map(|s| s.c.flatten_all().unwrap()));
            Tensor::cat(&parts, 0)
        };
        let r = check_grad(f, &inputs, &GradCheckOptions::default()).unwrap();
        print_report(&format!("Lstm, {layers} layer(s), 4 steps"), &format!("x, (h0, c0) per layer, {names:?}"), &r);
        r.ensure(GRAD_CHECK_F64).unwrap();
    }
}

/// The ConvLSTM over 3 steps (2 input and 2 hidden channels on 5x4 fields), with respect to the
/// inputs, (h0, c0), the weight and the bias, for every padding.
#[test]
fn conv_lstm_gradients_match_finite_differences() {
    for padding in [Padding::Zeros, Padding::Periodic, Padding::PeriodicX] {
        let cfg = ConvLstmConfig::new(2, 2).padding(padding);
        let (vars, _) = conv_lstm(cfg, DType::F64, 70);
        let inputs = vec![
            randn(&[2, 3, 2, 5, 4], DType::F64, 71),
            randn(&[2, 2, 5, 4], DType::F64, 72),
            randn(&[2, 2, 5, 4], DType::F64, 73),
            vars["weight"].clone(),
            vars["bias"].clone(),
        ];
        let f = |xs: &[Tensor]| {
            let map: HashMap<String, Tensor> =
                [("weight".to_string(), xs[3].clone()), ("bias".to_string(), xs[4].clone())].into();
            let cell = ConvLstmCell::new(cfg, VarBuilder::from_tensors(map, DType::F64, &CPU)).map_err(msg)?;
            let (hs, last) =
                cell.forward_sequence(&xs[0], Some(&LstmState::new(xs[1].clone(), xs[2].clone()))).map_err(msg)?;
            Tensor::cat(&[&hs.flatten_all()?, &last.c.flatten_all()?], 0)
        };
        let r = check_grad(f, &inputs, &GradCheckOptions::default()).unwrap();
        print_report(&format!("ConvLSTM {padding:?}, 3 steps"), "x, h0, c0, weight, bias", &r);
        r.ensure(GRAD_CHECK_F64).unwrap();
    }
}

// ---------------------------------------------------------------------------------------------
// Errors

#[test]
fn wrong_shapes_and_configs_are_typed_errors() {
    let vb = VarBuilder::zeros(DType::F32, &CPU);
    let shape_err = |r: pbdl_nets::Result<_>| matches!(r, Err(Error::ShapeMismatch { .. }));
    let cfg_err = |r: pbdl_nets::Result<_>| matches!(r, Err(Error::InvalidConfig { .. }));
    assert!(cfg_err(LstmCell::new(0, 4, vb.clone()).map(|_| ())));
    assert!(cfg_err(Lstm::new(LstmConfig::new(3, 4).num_layers(0), vb.clone()).map(|_| ())));
    assert!(cfg_err(ConvLstmCell::new(ConvLstmConfig::new(2, 0), vb.clone()).map(|_| ())));
    assert!(cfg_err(ConvLstmCell::new(ConvLstmConfig::new(2, 3).kernel_size(4), vb.clone()).map(|_| ())));

    let z = |s: &[usize]| Tensor::zeros(s, DType::F32, &CPU).unwrap();
    let lstm = Lstm::new(LstmConfig::new(3, 4).num_layers(2), vb.clone()).unwrap();
    assert!(shape_err(lstm.forward(&z(&[2, 5, 2]), None).map(|_| ()))); // wrong features
    assert!(shape_err(lstm.forward(&z(&[2, 0, 3]), None).map(|_| ()))); // empty sequence
    assert!(shape_err(lstm.forward(&z(&[2, 3]), None).map(|_| ()))); // no time axis
    let one = lstm.zero_states(2).unwrap()[..1].to_vec();
    assert!(shape_err(lstm.forward(&z(&[2, 5, 3]), Some(&one)).map(|_| ()))); // one state, two layers
    let cell = &lstm.cells()[0];
    let bad = LstmState::new(z(&[2, 4]), z(&[3, 4]));
    assert!(shape_err(cell.forward_step(&z(&[2, 3]), &bad).map(|_| ())));
    assert!(shape_err(cell.forward_step(&z(&[2, 4]), &cell.zero_state(2).unwrap()).map(|_| ())));

    let conv = ConvLstmCell::new(ConvLstmConfig::new(2, 3).kernel_size(5).padding(Padding::PeriodicX), vb).unwrap();
    assert!(shape_err(conv.forward_sequence(&z(&[1, 2, 3, 4, 4]), None).map(|_| ()))); // 3 channels
                                                                                       // A periodic axis narrower than the padding wraps around more than once (as the step path).
    assert_eq!(conv.forward_sequence(&z(&[1, 2, 2, 4, 1]), None).unwrap().0.dims(), &[1, 2, 3, 4, 1]);
    assert!(shape_err(conv.forward_step(&z(&[1, 2, 4, 4]), &conv.zero_state(1, 4, 5).unwrap()).map(|_| ())));
    assert_eq!(conv.forward_sequence(&z(&[1, 2, 2, 4, 4]), None).unwrap().0.dims(), &[1, 2, 3, 4, 4]);
}

// ---------------------------------------------------------------------------------------------
// Training

/// An LSTM(1 -> 8) with a linear head learns the sign of the running sum of a ±1 sequence
/// (8 steps, 64 sequences): the loss falls by a clear factor within 300 Adam steps.
#[test]
fn lstm_learns_the_sign_of_a_running_sum() {
    let (n, t, h) = (64, 8, 8);
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &CPU);
    let lstm = Lstm::new(LstmConfig::new(1, h), vb.pp("lstm")).unwrap();
    let head = Linear::new(h, 1, vb.pp("head")).unwrap();
    // Seeded PyTorch-scaled init: every variable uniform in ±1/sqrt(8) (the head's fan-in is 8).
    {
        let data = varmap.data().lock().unwrap();
        let mut names: Vec<_> = data.keys().cloned().collect();
        names.sort();
        let k = 1.0 / (h as f64).sqrt();
        for (i, name) in names.iter().enumerate() {
            let v = &data[name];
            v.set(&pbdl_core::seed::rand_uniform(v.dims(), -k, k, DType::F32, &CPU, 100 + i as u64).unwrap()).unwrap();
        }
    }
    let signs: Vec<f32> = pbdl_core::seed::rand_uniform(&[n, t], 0.0, 1.0, DType::F64, &CPU, 101)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f64>()
        .unwrap()
        .iter()
        .map(|&u| if u < 0.5 { -1.0 } else { 1.0 })
        .collect();
    // Target +1 / -1 / 0 for a positive / negative / zero running sum.
    let mut target = vec![0f32; n * t];
    for s in 0..n {
        let mut sum = 0.0;
        for k in 0..t {
            sum += signs[s * t + k];
            target[s * t + k] = if sum > 0.0 {
                1.0
            } else if sum < 0.0 {
                -1.0
            } else {
                0.0
            };
        }
    }
    let x = Tensor::from_vec(signs, (n, t, 1), &CPU).unwrap();
    let y = Tensor::from_vec(target, (n, t, 1), &CPU).unwrap();
    let start = std::time::Instant::now();
    let losses = train(&varmap, 2e-2, 300, |_| {
        let hs = lstm.forward(&x, None)?.output.reshape((n * t, h))?;
        let pred = head.forward(&hs)?.reshape((n, t, 1))?;
        Ok((pred - &y)?.sqr()?.mean_all()?)
    });
    let (first, last) = first_last_mean(&losses, 10);
    println!(
        "running-sum sign: loss {first:.3e} -> {last:.3e} ({:.0}x) in 300 steps, {:.2} s",
        first / last,
        start.elapsed().as_secs_f64()
    );
    assert!(losses.iter().all(|l| l.is_finite()));
    assert!(last * 10.0 < first, "loss fell only {first:.3e} -> {last:.3e}");
}

/// The step paths (`LstmCell::forward_step`, `ConvLstmCell::forward_step` with its concat
/// convolution) chained over 3 steps, with respect to the inputs, the initial state and the
/// weights.
#[test]
fn step_paths_gradients_match_finite_differences() {
    let (b, i, h) = (2, 3, 4);
    let vars = lstm_vars(i, h, DType::F64, 80);
    let names = ["weight_ih", "weight_hh", "bias_ih", "bias_hh"];
    let mut inputs =
        vec![randn(&[3, b, i], DType::F64, 81), randn(&[b, h], DType::F64, 82), randn(&[b, h], DType::F64, 83)];
    inputs.extend(NAMES.iter().map(|n| vars[*n].clone()));
    let f = |xs: &[Tensor]| {
        let map: HashMap<String, Tensor> =
            names.iter().zip(&xs[3..]).map(|(n, v)| (n.to_string(), v.clone())).collect();
        let cell = LstmCell::new(i, h, VarBuilder::from_tensors(map, DType::F64, &CPU)).map_err(msg)?;
        let mut s = LstmState::new(xs[1].clone(), xs[2].clone());
        for k in 0..3 {
            s = cell.forward_step(&xs[0].get(k)?, &s).map_err(msg)?;
        }
        Tensor::cat(&[&s.h, &s.c], 1)
    };
    let r = check_grad(f, &inputs, &GradCheckOptions::default()).unwrap();
    print_report("LstmCell::forward_step x3", "x, h0, c0, W_ih, W_hh, b_ih, b_hh", &r);
    r.ensure(GRAD_CHECK_F64).unwrap();

    let cfg = ConvLstmConfig::new(2, 2).padding(Padding::PeriodicX);
    let (vars, _) = conv_lstm(cfg, DType::F64, 84);
    let inputs = vec![
        randn(&[3, 2, 2, 5, 4], DType::F64, 85),
        randn(&[2, 2, 5, 4], DType::F64, 86),
        randn(&[2, 2, 5, 4], DType::F64, 87),
        vars["weight"].clone(),
        vars["bias"].clone(),
    ];
    let f = |xs: &[Tensor]| {
        let map: HashMap<String, Tensor> =
            [("weight".to_string(), xs[3].clone()), ("bias".to_string(), xs[4].clone())].into();
        let cell = ConvLstmCell::new(cfg, VarBuilder::from_tensors(map, DType::F64, &CPU)).map_err(msg)?;
        let mut s = LstmState::new(xs[1].clone(), xs[2].clone());
        for k in 0..3 {
            s = cell.forward_step(&xs[0].get(k)?, &s).map_err(msg)?;
        }
        Tensor::cat(&[&s.h, &s.c], 1)
    };
    let r = check_grad(f, &inputs, &GradCheckOptions::default()).unwrap();
    print_report("ConvLstmCell::forward_step x3 (PeriodicX)", "x, h0, c0, weight, bias", &r);
    r.ensure(GRAD_CHECK_F64).unwrap();
}

/// Forward + backward time of a 6-step LSTM at the latent-space sizes, ours against
/// candle-nn's (`cargo test -p pbdl-nets --test recurrent -- --ignored --nocapture`).
#[test]
#[ignore = "timing, prints numbers"]
fn lstm_timing_against_candle_nn() {
    for (b, h) in [(16usize, 256usize), (16, 1024)] {
        let t = 6;
        let vars = lstm_vars(h, h, DType::F32, 90);
        let vb = VarBuilder::from_tensors(vars.clone(), DType::F32, &CPU);
        let ours = Lstm::new(LstmConfig::new(h, h), vb.clone()).unwrap();
        let theirs = candle_nn::rnn::lstm(h, h, LSTMConfig::default(), vb).unwrap();
        let x = candle_core::Var::from_tensor(&randn(&[b, t, h], DType::F32, 91)).unwrap();
        let time = |f: &dyn Fn() -> Tensor| {
            let _ = f().sum_all().unwrap().backward().unwrap();
            let start = std::time::Instant::now();
            for _ in 0..10 {
                let _ = f().sum_all().unwrap().backward().unwrap();
            }
            start.elapsed().as_secs_f64() / 10.0 * 1e3
        };
        let a = time(&|| ours.forward(&x, None).unwrap().output);
        let c = time(&|| theirs.states_to_tensor(&theirs.seq(&x).unwrap()).unwrap());
        println!("batch {b}, hidden = input = {h}, 6 steps, fwd+bwd: ours {a:.2} ms, candle-nn {c:.2} ms");
    }
}
