//! The backward pass of the paper's networks: the weighted normalised MSE with its output
//! gradient, and the gradients of every trainable layer (GEMMs shared with the forward pass).
use abvs_fk::batch::{gemm_ab, gemm_atb, layer, Plan};
use abvs_fk::net::Net;

/// Weighted normalised MSE of the outputs against `y` (`m x 6`); with `grads`, writes
/// d(loss)/d(output) into the output layers' gradient buffers.
pub(super) fn loss(
    plan: &Plan,
    outs: &[(usize, usize)],
    acts: &[Vec<f32>],
    y: &[f32],
    m: usize,
    wts: &[f32; 6],
    mut grads: Option<&mut [Vec<f32>]>,
) -> f64 {
    let wsum: f32 = wts.iter().sum();
    let scale = 2.0 / (m as f32 * wsum);
    let mut total = 0.0f64;
    for &(l, col) in outs {
        let k = plan.layers[l].n_out;
        let a = &acts[l][..m * k];
        let mut g = grads.as_mut().map(|g| &mut g[l][..m * k]);
        for i in 0..m {
            let mut row = 0.0f32;
            for j in 0..k {
                let c = col + j;
                let d = a[i * k + j] - y[i * 6 + c];
                row += wts[c] * d * d;
                if let Some(g) = g.as_mut() {
                    g[i * k + j] = scale * wts[c] * d;
                }
            }
            total += row as f64;
        }
    }
    total / (m as f64 * wsum as f64)
}

/// Gradient buffers: w.r.t. each layer's output (`da`, `rows x n_out`), weights and biases.
pub(super) struct Grads {
    pub(super) da: Vec<Vec<f32>>,
    pub(super) dw: Vec<Vec<f32>>,
    pub(super) db: Vec<Vec<f32>>,
    /// Whether `da[l]` already holds a contribution in this pass (the trunk's last layer
    /// collects one from every head).
    set: Vec<bool>,
}

impl Grads {
    pub(super) fn new(plan: &Plan, rows: usize) -> Grads {
        let ls = &plan.layers;
        Grads {
            da: plan.buffers(rows),
            dw: ls.iter().map(|p| vec![0f32; p.n_in * p.n_out]).collect(),
            db: ls.iter().map(|p| vec![0f32; p.n_out]).collect(),
            set: vec![false; ls.len()],
        }
    }
}

/// Backward pass for the trainable layers, given the loss gradient of the output layers in
/// `g.da` and the forward activations: fills `g.dw`/`g.db` (and clobbers `g.da`).
pub(super) fn backward(
    net: &Net,
    plan: &Plan,
    x: &[f32],
    m: usize,
    acts: &[Vec<f32>],
    g: &mut Grads,
    trainable: &[bool],
) {
    g.set.iter_mut().for_each(|s| *s = false);
    // Heads come after the trunk in the flat order, so walking it backwards reaches every
    // consumer of a layer before the layer itself. Freezing is a prefix by depth, so once a
    // layer is frozen nothing before it on its path needs gradients.
    for (l, p) in plan.layers.iter().enumerate().rev() {
        if !trainable[l] {
            continue;
        }
        let mut da = std::mem::take(&mut g.da[l]);
        let gz = &mut da[..m * p.n_out];
        if p.relu {
            // relu'(z) = [a > 0] with a = relu(z).
            for (v, a) in gz.iter_mut().zip(&acts[l]) {
                if *a <= 0.0 {
                    *v = 0.0;
                }
            }
        }
        let d = layer(net, p);
        // The input gradient only matters when the layer feeding this one is trained.
        if let Some(s) = p.src.filter(|s| trainable[*s]) {
            let beta = if g.set[s] { 1.0 } else { 0.0 };
            gemm_ab(m, p.n_out, p.n_in, gz, &d.w, beta, &mut g.da[s]);
            g.set[s] = true;
        }
        let inp: &[f32] = match p.src {
            None => &x[..m * p.n_in],
            Some(s) => &acts[s][..m * p.n_in],
        };
        gemm_atb(p.n_out, m, p.n_in, gz, inp, &mut g.dw[l]);
        let db = &mut g.db[l];
        db.iter_mut().for_each(|v| *v = 0.0);
        for row in gz.chunks_exact(p.n_out) {
            for (a, b) in db.iter_mut().zip(row) {
                *a += b;
            }
        }
        g.da[l] = da;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mlp::normalise_set;
    use abvs_fk::batch::{forward, layer_mut};
    use abvs_fk::net::Affine;

    fn toy() -> Net {
        Net::m2(16, 2, 3, Affine::identity(3), Affine::identity(6), 1)
    }

    #[test]
    fn gradients_match_finite_differences() {
        let mut net = toy();
        let x: Vec<[f64; 3]> = (0..5).map(|i| [i as f64 * 0.3 - 0.5, 0.2 + 0.1 * i as f64, -0.1 * i as f64]).collect();
        let y: Vec<[f64; 6]> = (0..5).map(|i| [0.1 * i as f64, 0.2, -0.3, 0.4, 0.0, 1.0]).collect();
        let plan = Plan::new(&net);
        let outs = plan.outputs();
        let wts = [2.0f32, 2.0, 2.0, 1.0, 1.0, 1.0];
        let xn = normalise_set(&x, &net.input_norm);
        let yn = normalise_set(&y, &net.output_norm);
        let mut acts = plan.buffers(5);
        let mut lossf = |net: &Net, g: Option<&mut Grads>| {
            forward(net, &plan, &xn, 5, &mut acts);
            let l = loss(&plan, &outs, &acts, &yn, 5, &wts, g.map(|g| &mut g.da[..]));
            (l, acts.clone())
        };
        let mut g = Grads::new(&plan, 5);
        let (_, a) = lossf(&net, Some(&mut g));
        let all = vec![true; plan.layers.len()];
        backward(&net, &plan, &xn, 5, &a, &mut g, &all);
        let h = 1e-2f32;
        for (l, p) in plan.layers.iter().enumerate() {
            for k in [0, p.n_in * p.n_out / 2 + 1] {
                let w0 = layer(&net, p).w[k];
                layer_mut(&mut net, p).w[k] = w0 + h;
                let up = lossf(&net, None).0;
                layer_mut(&mut net, p).w[k] = w0 - h;
                let down = lossf(&net, None).0;
                layer_mut(&mut net, p).w[k] = w0;
                let numeric = (up - down) / (2.0 * h as f64);
                let analytic = g.dw[l][k] as f64;
                assert!(
                    (numeric - analytic).abs() < 2e-3 * (1.0 + numeric.abs()),
                    "layer {l} w[{k}]: {numeric} vs {analytic}"
                );
            }
        }
    }
}
